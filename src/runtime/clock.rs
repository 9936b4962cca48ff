//! Time for the fixed-rate loop and the sources: a [`Clock`] trait with the system clock
//! and a manual one that only moves when every thread pacing itself on it is waiting,
//! so tests run a whole stage deterministically and as fast as it computes, with no
//! sleeps.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Seconds on the stage's clock (zero when it started), and waiting on it.
pub trait Clock: Send + Sync {
    /// Seconds since the clock's start.
    fn now_s(&self) -> f64;
    /// Returns once `now_s() >= t_s` (at once if it already is).
    fn sleep_until(&self, t_s: f64);
    /// Seconds since the Unix epoch at `t_s` on this clock (for publish times).
    fn unix_s(&self, t_s: f64) -> f64;
    /// The instant a solve due at `t_s` must stop by (real time: the solver reads
    /// `Instant::now()`). A manual clock gives no deadline that can pass.
    fn deadline_at(&self, t_s: f64) -> Instant;
    /// A thread is about to pace itself on this clock: call it for every such thread
    /// before starting any of them (a manual clock moves as soon as every attached thread
    /// waits), then [`Self::detach`] when each ends. The system clock ignores it.
    fn attach(&self) {}
    /// A thread that paced itself on this clock has ended.
    fn detach(&self) {}
}

/// Seconds since the Unix epoch now (0 if the system clock is before it): the receive
/// time every input stamps on what it reads.
pub fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The machine's monotonic clock.
#[derive(Clone, Debug)]
pub struct SystemClock {
    start: Instant,
    start_unix_s: f64,
}

impl SystemClock {
    pub fn new() -> Self {
        Self {
            start: Instant::now(),
            start_unix_s: unix_now(),
        }
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

    fn deadline_at(&self, t_s: f64) -> Instant {
        self.start + Duration::from_secs_f64(t_s.max(0.0))
    }
}

/// A discrete-event clock for tests and offline runs. Time moves only inside
/// [`Clock::sleep_until`]: when every attached thread is waiting (and the caller counts
/// as one), the clock jumps to the earliest time any of them waits for and wakes those
/// threads. A thread that never attached and calls `sleep_until` alone moves the clock
/// straight to the time it asks for. [`ManualClock::advance_to`] moves it by hand.
///
/// While threads are attached, every thread that waits on the clock must be one of them
/// (a waiter that is not counts towards "every attached thread is waiting" and could move
/// the clock while an attached one is still busy). A stage attaches all of its.
///
/// Ordering: threads due at different times run in time order, each to its next wait,
/// before the clock moves on; so a source due at `t` has sent before a loop due at
/// `t + ε` drains. Threads due at the same time run concurrently.
#[derive(Clone, Debug, Default)]
pub struct ManualClock {
    inner: Arc<(Mutex<ManualState>, Condvar)>,
}

#[derive(Debug, Default)]
struct ManualState {
    now_s: f64,
    /// Threads that pace themselves on the clock.
    attached: usize,
    /// Wake times of the threads waiting in `sleep_until`.
    waiting: Vec<f64>,
}

impl ManualState {
    /// Moves to the earliest wake time once every attached thread waits.
    fn advance_if_all_wait(&mut self) -> bool {
        if self.waiting.is_empty() || self.waiting.len() < self.attached {
            return false;
        }
        let earliest = self.waiting.iter().copied().fold(f64::INFINITY, f64::min);
        if earliest > self.now_s {
            self.now_s = earliest;
        }
        true
    }
}

impl ManualClock {
    pub fn new(t_s: f64) -> Self {
        let clock = Self::default();
        clock.lock().now_s = t_s;
        clock
    }

    fn lock(&self) -> MutexGuard<'_, ManualState> {
        // A panic while holding this lock leaves the state consistent (plain numbers).
        self.inner.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Moves the clock to `t_s` (never backwards) and wakes the threads due by then.
    pub fn advance_to(&self, t_s: f64) {
        let mut s = self.lock();
        if t_s > s.now_s {
            s.now_s = t_s;
        }
        self.inner.1.notify_all();
    }
}

impl Clock for ManualClock {
    fn now_s(&self) -> f64 {
        self.lock().now_s
    }

    fn sleep_until(&self, t_s: f64) {
        let mut s = self.lock();
        // A time that is never reached (NaN) returns at once, as a past one does.
        if s.now_s >= t_s || t_s.is_nan() {
            return;
        }
        s.waiting.push(t_s);
        if s.advance_if_all_wait() {
            self.inner.1.notify_all();
        }
        while s.now_s < t_s {
            s = self.inner.1.wait(s).unwrap_or_else(|e| e.into_inner());
        }
        if let Some(i) = s.waiting.iter().position(|w| *w == t_s) {
            s.waiting.swap_remove(i);
        }
    }

    fn unix_s(&self, t_s: f64) -> f64 {
        t_s
    }

    fn deadline_at(&self, _t_s: f64) -> Instant {
        // A day from now: a solve on a manual clock is never cut short.
        Instant::now() + Duration::from_secs(86_400)
    }

    fn attach(&self) {
        self.lock().attached += 1;
    }

    fn detach(&self) {
        let mut s = self.lock();
        s.attached = s.attached.saturating_sub(1);
        if s.advance_if_all_wait() {
            self.inner.1.notify_all();
        }
    }
}

/// A thread's place among those that pace themselves on a clock: taken before any of
/// them starts (so that a manual clock waits for all of them), given back when the thread
/// ends, even by a panic.
pub struct Attached(Arc<dyn Clock>);

impl Attached {
    pub fn new(clock: &Arc<dyn Clock>) -> Self {
        clock.attach();
        Self(Arc::clone(clock))
    }
}

impl Drop for Attached {
    fn drop(&mut self) {
        self.0.detach();
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

    #[test]
    fn attached_threads_run_in_time_order() {
        // Two threads pacing themselves at 3 and 2 ticks per second record when they
        // ran; the clock moves only when both wait, so the joint log is in time order
        // and every entry ran at exactly its due time.
        let clock = ManualClock::new(0.0);
        let log = Arc::new(Mutex::new(Vec::new()));
        // Both places are taken before either thread runs: a thread alone on the clock
        // would otherwise run its whole schedule before the other one joins.
        clock.attach();
        clock.attach();
        let spawn = |period: f64, name: &'static str| {
            let (clock, log) = (clock.clone(), Arc::clone(&log));
            std::thread::spawn(move || {
                for n in 1..=6 {
                    let due = n as f64 * period;
                    clock.sleep_until(due);
                    assert_eq!(clock.now_s(), due);
                    log.lock().unwrap().push((due, name));
                }
                clock.detach();
            })
        };
        let a = spawn(1.0 / 3.0, "a");
        let b = spawn(0.5, "b");
        a.join().unwrap();
        b.join().unwrap();
        let log = log.lock().unwrap();
        assert_eq!(log.len(), 12);
        assert!(log.windows(2).all(|w| w[0].0 <= w[1].0), "{log:?}");
        assert_eq!(clock.now_s(), 3.0);
    }
}
