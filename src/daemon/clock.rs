//! Time for the fixed-rate loop and the sources: a [`Clock`] trait with the system clock
//! and a manual one that tests advance by hand (no sleeps in tests).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Seconds on the daemon's clock (zero when the daemon started), and waiting on it.
pub trait Clock: Send + Sync {
    /// Seconds since the clock's start.
    fn now_s(&self) -> f64;
    /// Returns once `now_s() >= t_s` (at once if it already is).
    fn sleep_until(&self, t_s: f64);
    /// Seconds since the Unix epoch at `t_s` on this clock (for publish times).
    fn unix_s(&self, t_s: f64) -> f64;
}

/// The machine's monotonic clock.
#[derive(Clone, Debug)]
pub struct SystemClock {
    start: Instant,
    start_unix_s: f64,
}

impl SystemClock {
    pub fn new() -> Self {
        let start_unix_s = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        Self {
            start: Instant::now(),
            start_unix_s,
        }
    }

    /// The instant `t_s` seconds after the start (for solver deadlines).
    pub fn instant_at(&self, t_s: f64) -> Instant {
        self.start + Duration::from_secs_f64(t_s.max(0.0))
    }
}

impl Default for SystemClock {
    fn default() -> Self {
        Self::new()
    }
}

/// Below this much time left, `sleep_until` spins instead of sleeping (the OS may
/// oversleep by a scheduler tick), seconds.
const SPIN_BELOW_S: f64 = 0.0015;

impl Clock for SystemClock {
    fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    fn sleep_until(&self, t_s: f64) {
        loop {
            let left = t_s - self.now_s();
            if left <= 0.0 {
                return;
            }
            if left > SPIN_BELOW_S {
                std::thread::sleep(Duration::from_secs_f64(left - SPIN_BELOW_S));
            } else {
                std::hint::spin_loop();
            }
        }
    }

    fn unix_s(&self, t_s: f64) -> f64 {
        self.start_unix_s + t_s
    }
}

/// A clock that only moves when told: `sleep_until` jumps to the requested time, so a
/// loop driven by it runs as fast as it can and tests see exact times.
#[derive(Clone, Debug, Default)]
pub struct ManualClock {
    /// f64 bits of the current time.
    now_bits: Arc<AtomicU64>,
}

impl ManualClock {
    pub fn new(t_s: f64) -> Self {
        Self {
            now_bits: Arc::new(AtomicU64::new(t_s.to_bits())),
        }
    }

    /// Moves the clock to `t_s` (never backwards).
    pub fn advance_to(&self, t_s: f64) {
        let _ = self
            .now_bits
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |b| {
                (t_s > f64::from_bits(b)).then_some(t_s.to_bits())
            });
    }
}

impl Clock for ManualClock {
    fn now_s(&self) -> f64 {
        f64::from_bits(self.now_bits.load(Ordering::SeqCst))
    }

    fn sleep_until(&self, t_s: f64) {
        self.advance_to(t_s);
    }

    fn unix_s(&self, t_s: f64) -> f64 {
        t_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_clock_moves_only_forward() {
        let c = ManualClock::new(1.0);
        c.sleep_until(2.5);
        assert_eq!(c.now_s(), 2.5);
        c.advance_to(2.0);
        assert_eq!(c.now_s(), 2.5);
    }
}
