//! Sessions between two systems: the Noise KK handshake that makes one, and what a session
//! holds (a key per direction, the send counter, the replay window).
//!
//! Noise KK: both sides know each other's static public key (from the fleet file) in
//! advance; each handshake mixes in fresh ephemeral keys from both sides, so a session's keys
//! are new every time and a frame captured in one session means nothing in another (no replay
//! across restarts of either side). The initiation carries the initiator's timestamp, which
//! must grow from one initiation to the next (its own clock only: peers' clocks never meet).

use parking_lot::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use hetcomm_core::SystemId;
use rand::{RngCore, SeedableRng};
use snow::resolvers::{CryptoResolver, DefaultResolver, RingResolver};

use crate::envelope::{self, DirectionKey, Kind, NOISE_PARAMS};
use crate::keys::{Keypair, PublicKey};
use crate::replay::ReplayWindow;

/// An established session with one peer.
pub struct Session {
    /// Our index for it: the peer puts it in every data frame it sends us.
    pub my_index: u32,
    /// The peer's index for it: we put it in every data frame we send.
    pub peer_index: u32,
    send: DirectionKey,
    recv: DirectionKey,
    counter: AtomicU64,
    window: Mutex<ReplayWindow>,
}

impl Session {
    fn new(my_index: u32, peer_index: u32, send: &[u8; 32], recv: &[u8; 32]) -> Session {
        Session {
            my_index,
            peer_index,
            send: DirectionKey::new(send),
            recv: DirectionKey::new(recv),
            counter: AtomicU64::new(0),
            window: Mutex::new(ReplayWindow::default()),
        }
    }

    /// Seals `head` + `body` from `local` to `peer` into `out`.
    pub fn seal(
        &self,
        out: &mut Vec<u8>,
        local: SystemId,
        peer: SystemId,
        head: &[u8],
        body: &[u8],
    ) {
        let counter = self.counter.fetch_add(1, Ordering::Relaxed);
        self.send
            .seal(out, (local, peer), self.peer_index, counter, head, body);
    }

    /// Seals the data batch `records` from `local` to `peer` into `out`.
    pub fn seal_batch(&self, out: &mut Vec<u8>, local: SystemId, peer: SystemId, records: &[u8]) {
        let counter = self.counter.fetch_add(1, Ordering::Relaxed);
        self.send
            .seal_batch(out, (local, peer), self.peer_index, counter, records);
    }

    /// How many frames (data messages and batches) were sealed in this session so far.
    pub fn sealed(&self) -> u64 {
        self.counter.load(Ordering::Relaxed)
    }

    /// Decrypts a data frame in place. False if it does not authenticate.
    pub fn open(&self, frame: &mut [u8]) -> bool {
        self.recv.open(frame)
    }

    /// Decrypts a data frame into `out` (of the inner frame's length), leaving the frame as
    /// it is. False if it does not authenticate.
    pub fn open_into(&self, frame: &[u8], out: &mut [u8]) -> bool {
        self.recv.open_into(frame, out)
    }

    /// Records an authenticated frame's counter; false if it was seen before (a replay).
    pub fn accept_counter(&self, counter: u64) -> bool {
        self.window.lock().accept(counter)
    }
}

/// Where handshakes get their randomness: the operating system, or a simulation's seed.
#[derive(Clone, Copy, Debug)]
pub enum Entropy {
    /// The operating system's random source (real runs).
    Os,
    /// A seeded generator (simulation: the same seed gives the same sessions).
    Seeded(u64),
}

/// Where the handshake's cryptography comes from: AES-256-GCM and SHA-256 from ring (snow's
/// ring resolver; the same crate seals the data frames), X25519 from snow's own resolver
/// (curve25519-dalek: ring's X25519 takes no static key), and randomness from the
/// operating system (through ring) or, in a simulation, from the seed.
struct Resolver(Entropy);

struct SeededRandom(rand_chacha::ChaCha20Rng);

impl snow::types::Random for SeededRandom {
    fn try_fill_bytes(&mut self, dest: &mut [u8]) -> Result<(), snow::Error> {
        self.0.fill_bytes(dest);
        Ok(())
    }
}

impl CryptoResolver for Resolver {
    fn resolve_rng(&self) -> Option<Box<dyn snow::types::Random>> {
        match self.0 {
            Entropy::Os => RingResolver.resolve_rng(),
            Entropy::Seeded(seed) => Some(Box::new(SeededRandom(
                rand_chacha::ChaCha20Rng::seed_from_u64(seed),
            ))),
        }
    }
    fn resolve_dh(&self, choice: &snow::params::DHChoice) -> Option<Box<dyn snow::types::Dh>> {
        DefaultResolver.resolve_dh(choice)
    }
    fn resolve_hash(
        &self,
        choice: &snow::params::HashChoice,
    ) -> Option<Box<dyn snow::types::Hash>> {
        RingResolver.resolve_hash(choice)
    }
    fn resolve_cipher(
        &self,
        choice: &snow::params::CipherChoice,
    ) -> Option<Box<dyn snow::types::Cipher>> {
        RingResolver.resolve_cipher(choice)
    }
}

/// The prologue both sides mix in: the protocol, and who is initiator and responder, so a
/// handshake cannot be moved to another pair.
fn prologue(initiator: SystemId, responder: SystemId) -> Vec<u8> {
    let mut p = b"hetcomm-secure-v1".to_vec();
    p.extend_from_slice(&initiator.0.to_le_bytes());
    p.extend_from_slice(&responder.0.to_le_bytes());
    p
}

fn builder(entropy: Entropy) -> snow::Builder<'static> {
    let params = NOISE_PARAMS.parse().expect("a valid Noise protocol name");
    snow::Builder::with_resolver(params, Box::new(Resolver(entropy)))
}

/// A handshake we started and whose response we wait for.
pub struct Initiation {
    state: snow::HandshakeState,
    /// Our index for the session it will make.
    pub index: u32,
}

/// Starts a handshake from `local` to `peer`: the initiation to send, and what to keep for
/// the response. `timestamp` must exceed every earlier one from `local` to `peer`.
pub fn initiate(
    local: (SystemId, &Keypair),
    peer: (SystemId, &PublicKey),
    index: u32,
    timestamp: u64,
    entropy: Entropy,
) -> Result<(Vec<u8>, Initiation), snow::Error> {
    let prologue = prologue(local.0, peer.0);
    let mut state = builder(entropy)
        .local_private_key(&local.1.private.0)?
        .remote_public_key(&(peer.1).0)?
        .prologue(&prologue)?
        .build_initiator()?;
    let mut out = Vec::with_capacity(128);
    envelope::write_prefix(&mut out, Kind::Init, local.0, peer.0);
    out.extend_from_slice(&index.to_le_bytes());
    let start = out.len();
    out.resize(start + 96, 0);
    let n = state.write_message(&timestamp.to_le_bytes(), &mut out[start..])?;
    out.truncate(start + n);
    Ok((out, Initiation { state, index }))
}

/// What answering an initiation gives: the response to send, the session, and the
/// initiator's timestamp (for the caller's freshness check).
pub struct Answer {
    /// The response frame.
    pub response: Vec<u8>,
    /// The new session.
    pub session: Session,
    /// The initiator's timestamp.
    pub timestamp: u64,
}

/// Answers an initiation `frame` from `peer`. Fails if it does not authenticate (wrong keys,
/// changed bytes, not from `peer`).
pub fn respond(
    local: (SystemId, &Keypair),
    peer: (SystemId, &PublicKey),
    frame: &[u8],
    my_index: u32,
    entropy: Entropy,
) -> Result<Answer, snow::Error> {
    if frame.len() < envelope::INIT_HEADER_LEN {
        return Err(snow::Error::Input);
    }
    let peer_index = envelope::u32_at(frame, 8);
    let prologue = prologue(peer.0, local.0);
    let mut state = builder(entropy)
        .local_private_key(&local.1.private.0)?
        .remote_public_key(&(peer.1).0)?
        .prologue(&prologue)?
        .build_responder()?;
    let mut payload = [0u8; 64];
    let n = state.read_message(&frame[envelope::INIT_HEADER_LEN..], &mut payload)?;
    if n != 8 {
        return Err(snow::Error::Input);
    }
    let timestamp = u64::from_le_bytes(payload[..8].try_into().expect("8 bytes"));
    let mut response = Vec::with_capacity(96);
    envelope::write_prefix(&mut response, Kind::Response, local.0, peer.0);
    response.extend_from_slice(&my_index.to_le_bytes());
    response.extend_from_slice(&peer_index.to_le_bytes());
    let start = response.len();
    response.resize(start + 96, 0);
    let n = state.write_message(&[], &mut response[start..])?;
    response.truncate(start + n);
    // The initiator sends with the first key, the responder with the second.
    let (to_responder, to_initiator) = state.dangerously_get_raw_split();
    Ok(Answer {
        response,
        session: Session::new(my_index, peer_index, &to_initiator, &to_responder),
        timestamp,
    })
}

impl Initiation {
    /// Whether `frame` (a response) answers this initiation.
    pub fn answered_by(&self, frame: &[u8]) -> bool {
        frame.len() >= envelope::RESPONSE_HEADER_LEN && envelope::u32_at(frame, 12) == self.index
    }

    /// Completes the handshake with the response `frame`.
    pub fn complete(mut self, frame: &[u8]) -> Result<Session, snow::Error> {
        if !self.answered_by(frame) {
            return Err(snow::Error::Input);
        }
        let peer_index = envelope::u32_at(frame, 8);
        let mut payload = [0u8; 64];
        self.state
            .read_message(&frame[envelope::RESPONSE_HEADER_LEN..], &mut payload)?;
        let (to_responder, to_initiator) = self.state.dangerously_get_raw_split();
        Ok(Session::new(
            self.index,
            peer_index,
            &to_responder,
            &to_initiator,
        ))
    }
}

/// A whole handshake between two systems whose key pairs are both at hand (a simulation,
/// where every system lives in one process): both sessions, as the wire handshake would
/// make them, without frames. Deterministic for a given `seed`.
pub fn in_memory(
    initiator: (SystemId, &Keypair),
    responder: (SystemId, &Keypair),
    seed: u64,
) -> Result<(Session, Session), snow::Error> {
    let (init, pending) = initiate(
        initiator,
        (responder.0, &responder.1.public),
        1,
        1,
        Entropy::Seeded(seed),
    )?;
    let answer = respond(
        responder,
        (initiator.0, &initiator.1.public),
        &init,
        2,
        Entropy::Seeded(seed ^ 0x5eed),
    )?;
    let mine = pending.complete(&answer.response)?;
    Ok((mine, answer.session))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envelope::{DATA_HEADER_LEN, TAG_LEN};

    #[test]
    fn a_handshake_gives_both_sides_matching_keys() {
        let (a, b) = (Keypair::generate().unwrap(), Keypair::generate().unwrap());
        let (ia, ib) = (SystemId(1), SystemId(2));
        let (init, pending) = initiate((ia, &a), (ib, &b.public), 11, 5, Entropy::Os).unwrap();
        let answer = respond((ib, &b), (ia, &a.public), &init, 22, Entropy::Os).unwrap();
        assert_eq!(answer.timestamp, 5);
        let sa = pending.complete(&answer.response).unwrap();
        let sb = answer.session;
        assert_eq!(
            (sa.my_index, sa.peer_index, sb.my_index, sb.peer_index),
            (11, 22, 22, 11)
        );
        let mut f = Vec::new();
        sa.seal(&mut f, ia, ib, b"hello", b"");
        assert!(sb.open(&mut f));
        assert_eq!(&f[DATA_HEADER_LEN..f.len() - TAG_LEN], b"hello");
        sb.seal(&mut f, ib, ia, b"back", b"");
        assert!(sa.open(&mut f));
        // Each direction has its own key: a frame cannot be reflected to its sender.
        sa.seal(&mut f, ia, ib, b"x", b"");
        assert!(!sa.open(&mut f.clone()));
    }

    #[test]
    fn a_wrong_key_or_a_changed_byte_fails_the_handshake() {
        let (a, b, c) = (
            Keypair::generate().unwrap(),
            Keypair::generate().unwrap(),
            Keypair::generate().unwrap(),
        );
        let (ia, ib) = (SystemId(1), SystemId(2));
        // C pretends to be A: B expects A's key.
        let (init, _) = initiate((ia, &c), (ib, &b.public), 1, 1, Entropy::Os).unwrap();
        assert!(respond((ib, &b), (ia, &a.public), &init, 2, Entropy::Os).is_err());
        let (mut init, _) = initiate((ia, &a), (ib, &b.public), 1, 1, Entropy::Os).unwrap();
        let last = init.len() - 1;
        init[last] ^= 1;
        assert!(respond((ib, &b), (ia, &a.public), &init, 2, Entropy::Os).is_err());
        // Moved to another pair (the prologue binds the ids).
        let (init, _) = initiate((ia, &a), (ib, &b.public), 1, 1, Entropy::Os).unwrap();
        assert!(respond((SystemId(3), &b), (ia, &a.public), &init, 2, Entropy::Os).is_err());
    }

    #[test]
    fn in_memory_sessions_are_repeatable() {
        let a = Keypair::for_simulation(1, SystemId(1));
        let b = Keypair::for_simulation(1, SystemId(2));
        let run = || {
            let (sa, _) = in_memory((SystemId(1), &a), (SystemId(2), &b), 9).unwrap();
            let mut f = Vec::new();
            sa.seal(&mut f, SystemId(1), SystemId(2), b"same", b"");
            f
        };
        assert_eq!(run(), run());
    }
}
