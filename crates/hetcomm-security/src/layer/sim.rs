//! Sessions made in memory for a simulated fleet.

use parking_lot::Mutex;
use std::collections::HashMap;
use std::sync::Arc;

use hetcomm_core::SystemId;

use crate::keys::Keypair;
use crate::session::{self, Session};

/// Sessions of a simulated fleet, made in memory from the seed: the same seed gives the same
/// keys and sessions, and no handshake frame is drawn through the simulated network (so a
/// secured simulation loses, delays and orders frames exactly as an unsecured one with the
/// same seed).
pub struct SimSessions {
    seed: u64,
    keys: HashMap<SystemId, Keypair>,
    /// Per (transport, lower id, higher id): the two halves of the pair's session.
    pairs: Mutex<HashMap<PairKey, [Option<Arc<Session>>; 2]>>,
}

/// A pair of systems on a transport: (transport name, lower id, higher id).
type PairKey = (String, SystemId, SystemId);

impl SimSessions {
    /// Sessions for systems with these keys, from `seed`.
    pub fn new(seed: u64, keys: HashMap<SystemId, Keypair>) -> Arc<SimSessions> {
        Arc::new(SimSessions {
            seed,
            keys,
            pairs: Mutex::new(HashMap::new()),
        })
    }

    /// The key pair of `system`.
    pub fn keypair(&self, system: SystemId) -> Option<&Keypair> {
        self.keys.get(&system)
    }

    /// `me`'s half of the session with `peer` on `transport` (made on first use).
    pub(super) fn half(
        &self,
        transport: &str,
        me: SystemId,
        peer: SystemId,
    ) -> Option<Arc<Session>> {
        let (lo, hi) = if me < peer { (me, peer) } else { (peer, me) };
        let mut pairs = self.pairs.lock();
        let entry = pairs.entry((transport.to_string(), lo, hi)).or_default();
        if entry[0].is_none() && entry[1].is_none() {
            let seed = self.seed ^ ((lo.0 as u64) << 16) ^ ((hi.0 as u64) << 32);
            let (a, b) =
                session::in_memory((lo, self.keys.get(&lo)?), (hi, self.keys.get(&hi)?), seed)
                    .ok()?;
            *entry = [Some(Arc::new(a)), Some(Arc::new(b))];
        }
        entry[usize::from(me != lo)].clone()
    }
}
