//! The inputs' packet rate and longest gap, measured by the fixed-rate loop over windows
//! of the stage's clock (a quarter second each) from each input's counters, and kept for
//! the published frames ([`InputWindowPoint`]): a sink that skips frames (the Rerun sink
//! on a busy machine) still finds every window in a later frame. Time is passed in, so a
//! stage on a manual clock measures its inputs exactly.

use crate::input::SourceCounters;
use crate::output::frame::InputWindowPoint;
use std::collections::VecDeque;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// Seconds of the stage's clock per window.
pub const INPUT_WINDOW_S: f64 = 0.25;

/// Windows kept per input for the published frames: two seconds of them, so a sink loses
/// a window only if it takes no frame for that long.
pub const WINDOWS_KEPT_PER_INPUT: usize = 8;

/// Slack on a window's span, seconds: ticks at `start + k / rate` computed in floating
/// point can fall a rounding error short of a whole window.
const SPAN_SLACK_S: f64 = 1e-9;

/// One input's window being measured.
#[derive(Debug)]
struct Window {
    counters: Arc<SourceCounters>,
    /// Start of the window (stage clock, s) and the frame count then.
    start_s: Option<f64>,
    start_frames: u64,
    /// Frame count at the previous tick, and when it last changed (stage clock, s).
    seen_frames: u64,
    changed_s: f64,
}

impl Window {
    /// Looks at the input's counters at `t_s` (a tick, stage clock): once the window spans
    /// [`INPUT_WINDOW_S`], its frame rate (Hz) and longest gap (s), and a new window
    /// starts; `None` before.
    fn measure(&mut self, t_s: f64) -> Option<(f64, f64)> {
        let c = &self.counters;
        let n = c.frames.load(Ordering::Relaxed);
        let start_s = *self.start_s.get_or_insert_with(|| {
            self.start_frames = n;
            self.seen_frames = n;
            self.changed_s = t_s;
            t_s
        });
        if n != self.seen_frames {
            self.seen_frames = n;
            self.changed_s = t_s;
        }
        let span_s = t_s - start_s;
        if span_s + SPAN_SLACK_S < INPUT_WINDOW_S {
            return None;
        }
        let rate_hz = n.saturating_sub(self.start_frames) as f64 / span_s;
        // Between two frames (the source's own clock), or since the last frame (the
        // loop's view, to a tick) when the source has gone quiet.
        let gap_s = c.take_longest_interval_s().max(t_s - self.changed_s);
        self.start_s = Some(t_s);
        self.start_frames = n;
        Some((rate_hz, gap_s))
    }
}

/// Every input's windows, and the most recent closed ones (oldest first).
#[derive(Debug, Default)]
pub struct InputRates {
    windows: Vec<Window>,
    /// Bounded at [`WINDOWS_KEPT_PER_INPUT`] per input (allocated once).
    recent: VecDeque<InputWindowPoint>,
}

impl InputRates {
    /// Measures the inputs whose counters are `counters` (in the config's order).
    pub fn new(counters: &[Arc<SourceCounters>]) -> Self {
        Self {
            windows: counters
                .iter()
                .map(|c| Window {
                    counters: Arc::clone(c),
                    start_s: None,
                    start_frames: 0,
                    seen_frames: 0,
                    changed_s: 0.0,
                })
                .collect(),
            recent: VecDeque::with_capacity(WINDOWS_KEPT_PER_INPUT * counters.len()),
        }
    }

    /// The tick `frame` at `t_s` on the stage's clock: closes the windows that span
    /// [`INPUT_WINDOW_S`] by now, stamped with `unix_s()` (the tick's time since the Unix
    /// epoch, read only when a window closes). Does not allocate.
    pub fn tick(&mut self, frame: u64, t_s: f64, unix_s: &dyn Fn() -> f64) {
        for (input, w) in self.windows.iter_mut().enumerate() {
            let Some((rate_hz, gap_s)) = w.measure(t_s) else {
                continue;
            };
            if self.recent.len() == self.recent.capacity() {
                self.recent.pop_front();
            }
            self.recent.push_back(InputWindowPoint {
                input,
                frame,
                unix_s: unix_s(),
                rate_hz,
                gap_s,
            });
        }
    }

    /// The most recent closed windows, oldest first.
    pub fn recent(&self) -> impl Iterator<Item = &InputWindowPoint> {
        self.recent.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An input's windows on a manual schedule: frames counted at their times, windows
    /// measured at the loop's ticks (120 Hz), all passed in.
    struct Schedule {
        rates: InputRates,
        counters: Arc<SourceCounters>,
        frame: u64,
    }

    impl Schedule {
        fn new() -> Self {
            let counters = Arc::new(SourceCounters::default());
            Self {
                rates: InputRates::new(&[Arc::clone(&counters)]),
                counters,
                frame: 0,
            }
        }

        /// Ticks `from..to` (1/120 s apart); before each, the source's frames due by
        /// then (`frame_s`, ascending, taken from the front). Returns the windows closed.
        fn run(&mut self, ticks: std::ops::Range<u32>, frame_s: &mut Vec<f64>) -> Vec<(f64, f64)> {
            let mut points = Vec::new();
            for k in ticks {
                let t_s = f64::from(k) / 120.0;
                while frame_s.first().is_some_and(|&f| f <= t_s + 1e-12) {
                    self.counters.count_frame(frame_s.remove(0));
                }
                self.rates.tick(self.frame, t_s, &|| t_s);
                if let Some(p) = self.rates.recent().last().filter(|p| p.frame == self.frame) {
                    points.push((p.rate_hz, p.gap_s));
                }
                self.frame += 1;
            }
            points
        }
    }

    /// A steady 120 Hz source reads 120 Hz in every quarter-second window (30 ticks: the
    /// ticks' rounding does not push a window to the 31st) and gaps of one frame
    /// (8.3 ms); a 100 ms stall shows as a 100 ms gap in its window and a lower rate
    /// there; a source that stops shows its silence growing, window after window, at a
    /// rate of 0.
    #[test]
    fn rates_and_gaps_on_a_manual_schedule() {
        let mut s = Schedule::new();
        // 2 s at 120 Hz: windows close at ticks 30, 60, ..., 210.
        let mut frames: Vec<f64> = (0..240).map(|i| f64::from(i) / 120.0).collect();
        let steady = s.run(0..240, &mut frames);
        close(&steady, &[(120.0, 1.0); 7]);
        // A stall: 12 frames (100 ms) missing, then 120 Hz again until 3 s. Windows close
        // at ticks 240 (steady), 270 (23 frames, the last at 263), 300 (25 frames from 276: the 13-tick
        // interval 263 → 276 is the gap) and 330 (steady again).
        let mut frames: Vec<f64> = (240..360)
            .filter(|i| !(264..276).contains(i))
            .map(|i| f64::from(i) / 120.0)
            .collect();
        let stalled = s.run(240..360, &mut frames);
        close(
            &stalled,
            &[(120.0, 1.0), (92.0, 7.0), (100.0, 13.0), (120.0, 1.0)],
        );
        // Silence from 3 s: the window closing at 360 still holds 29 frames; every later
        // one reads none, and the gap grows by a window each time (since tick 359).
        let silent = s.run(360..480, &mut Vec::new());
        close(
            &silent,
            &[(116.0, 1.0), (0.0, 31.0), (0.0, 61.0), (0.0, 91.0)],
        );
    }

    /// `got` equals `want` (rate Hz, gap in ticks of 1/120 s) to rounding.
    fn close(got: &[(f64, f64)], want: &[(f64, f64)]) {
        assert_eq!(got.len(), want.len(), "{got:?}");
        for (g, w) in got.iter().zip(want) {
            assert!(
                (g.0 - w.0).abs() < 1e-9 && (g.1 - w.1 / 120.0).abs() < 1e-9,
                "{got:?} against {want:?}"
            );
        }
    }

    /// Only the most recent windows are kept, oldest first, with their ticks; two inputs
    /// each get their share.
    #[test]
    fn the_recent_windows_are_bounded_and_in_order() {
        let (a, b) = (
            Arc::new(SourceCounters::default()),
            Arc::new(SourceCounters::default()),
        );
        let mut rates = InputRates::new(&[Arc::clone(&a), Arc::clone(&b)]);
        // 10 s of ticks at 100 Hz (25 a window); `a` sends every tick, `b` every fifth.
        for k in 0..=1000u64 {
            let t_s = k as f64 / 100.0;
            a.count_frame(t_s);
            if k % 5 == 0 {
                b.count_frame(t_s);
            }
            rates.tick(k, t_s, &|| 1000.0 + t_s);
        }
        let recent: Vec<_> = rates.recent().copied().collect();
        assert_eq!(recent.len(), 2 * WINDOWS_KEPT_PER_INPUT);
        // The last 8 windows of each (40 windows closed by tick 1000, one per 25 ticks).
        assert_eq!(recent[0].frame, 1000 - 7 * 25);
        assert_eq!(recent.last().unwrap().frame, 1000);
        assert!(recent.windows(2).all(|w| w[0].frame <= w[1].frame));
        for p in &recent {
            let (rate, gap) = if p.input == 0 {
                (100.0, 0.01)
            } else {
                (20.0, 0.05)
            };
            assert!(
                (p.rate_hz - rate).abs() < 1e-9 && (p.gap_s - gap).abs() < 1e-9,
                "{p:?}"
            );
            assert!((p.unix_s - 1000.0 - p.frame as f64 / 100.0).abs() < 1e-9);
        }
    }
}
