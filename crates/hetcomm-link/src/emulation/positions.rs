//! Where the systems are: a shared table the virtual environment updates while the fleet runs,
//! and the emulated links read to compute distances for range and path loss.

use parking_lot::RwLock;
use std::collections::HashMap;
use std::sync::Arc;

use hetcomm_core::SystemId;

/// Positions of systems on a plane, in metres. Cloning gives another handle to the same table,
/// so a simulator can hold one handle and every [`super::EmulatedLink`] another.
///
/// A system with no recorded position is treated by the models as co-located with everyone
/// (distance 0: in range, strongest signal), so a fleet without a virtual environment is not
/// cut off by range settings.
///
/// ```
/// use hetcomm_core::SystemId;
/// use hetcomm_link::emulation::PositionTable;
///
/// let positions = PositionTable::new();
/// positions.set(SystemId(1), 0.0, 0.0);
/// positions.set(SystemId(2), 3.0, 4.0);
/// assert_eq!(positions.distance(SystemId(1), SystemId(2)), Some(5.0));
/// assert_eq!(positions.distance(SystemId(1), SystemId(9)), None);
/// ```
#[derive(Clone, Debug, Default)]
pub struct PositionTable {
    inner: Arc<RwLock<HashMap<SystemId, (f64, f64)>>>,
}

impl PositionTable {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records (or moves) `system` to `(x, y)` metres.
    pub fn set(&self, system: SystemId, x: f64, y: f64) {
        self.inner.write().insert(system, (x, y));
    }

    /// Forgets `system`'s position (it then counts as co-located with everyone).
    pub fn remove(&self, system: SystemId) {
        self.inner.write().remove(&system);
    }

    /// `system`'s position, if known.
    pub fn position(&self, system: SystemId) -> Option<(f64, f64)> {
        self.inner.read().get(&system).copied()
    }

    /// Euclidean distance between `a` and `b` in metres, or `None` if either position is
    /// unknown.
    pub fn distance(&self, a: SystemId, b: SystemId) -> Option<f64> {
        let table = self.inner.read();
        let (ax, ay) = *table.get(&a)?;
        let (bx, by) = *table.get(&b)?;
        Some((ax - bx).hypot(ay - by))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clones_share_the_table() {
        let t = PositionTable::new();
        let u = t.clone();
        t.set(SystemId(1), 1.0, 1.0);
        u.set(SystemId(2), 1.0, 11.0);
        assert_eq!(t.distance(SystemId(1), SystemId(2)), Some(10.0));
        assert_eq!(u.position(SystemId(1)), Some((1.0, 1.0)));
        u.remove(SystemId(1));
        assert_eq!(t.distance(SystemId(1), SystemId(2)), None);
    }
}
