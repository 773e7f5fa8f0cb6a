//! Round-trip time estimation and retransmission timeout (RFC 6298).

use std::time::Duration;

/// Smoothed RTT and its variation for one destination, giving the retransmission timeout.
#[derive(Clone, Debug)]
pub struct RttEstimator {
    srtt: Option<Duration>,
    rttvar: Duration,
    initial: Duration,
    min: Duration,
    max: Duration,
}

impl RttEstimator {
    /// A new estimator that answers `initial` until the first sample.
    pub fn new(initial: Duration, min: Duration, max: Duration) -> Self {
        RttEstimator {
            srtt: None,
            rttvar: Duration::ZERO,
            initial,
            min,
            max,
        }
    }

    /// Folds in one RTT sample (only from frames sent once: Karn's rule is the caller's job).
    pub fn sample(&mut self, rtt: Duration) {
        match self.srtt {
            None => {
                self.srtt = Some(rtt);
                self.rttvar = rtt / 2;
            }
            Some(srtt) => {
                let delta = srtt.abs_diff(rtt);
                self.rttvar = (self.rttvar * 3 + delta) / 4;
                self.srtt = Some((srtt * 7 + rtt) / 8);
            }
        }
    }

    /// The smoothed RTT, if measured.
    pub fn srtt(&self) -> Option<Duration> {
        self.srtt
    }

    /// The retransmission timeout: SRTT + 4·RTTVAR, clamped to [min, max].
    pub fn rto(&self) -> Duration {
        match self.srtt {
            None => self.initial,
            Some(srtt) => (srtt + self.rttvar * 4).clamp(self.min, self.max),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_and_clamps() {
        let ms = Duration::from_millis;
        let mut e = RttEstimator::new(ms(100), ms(2), ms(1000));
        assert_eq!(e.rto(), ms(100));
        for _ in 0..50 {
            e.sample(ms(10));
        }
        let rto = e.rto();
        assert!(rto >= ms(10) && rto < ms(12), "{rto:?}");
        for _ in 0..50 {
            e.sample(Duration::ZERO);
        }
        assert_eq!(e.rto(), ms(2));
    }
}
