//! The live pipeline driven by a manual clock: synthetic sessions with known truth go
//! through the channel, the marker buffer and the solver; frames come out of the slots.

use crossbeam_channel::bounded;
use rigless::character::body::BodyMotion;
use rigless::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params, Motion};
use rigless::character::procedural::skin_pose;
use rigless::character::session::{SyntheticParams, SyntheticSession};
use rigless::daemon::pipeline::{run_loop, LoopParams, LoopStatus, Pipeline};
use rigless::markers::buffer::{BufferConfig, MarkerBuffer};
use rigless::markers::FillState;
use rigless::output::frame::DeformedFrame;
use rigless::rig::bind::Rig;
use rigless::runtime::clock::{Clock, ManualClock};
use rigless::runtime::slot::LatestSlot;
use rigless::solve::frame::{Method, Solver, SolverParams};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Counts allocations made by the current thread (to check the per-frame path).
struct CountingAlloc;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn allocations() -> u64 {
    ALLOCATIONS.with(|c| c.get())
}

const RATE_HZ: f64 = 120.0;

struct Setup {
    rig: Arc<Rig>,
    motion: Motion,
    session: SyntheticSession,
    pipeline: Pipeline,
    tx: crossbeam_channel::Sender<rigless::markers::MarkerSample>,
    slot: Arc<LatestSlot<DeformedFrame>>,
}

fn setup(gap_fraction: f64, seconds: f64) -> Setup {
    setup_with(gap_fraction, seconds, BufferConfig::default())
}

fn setup_with(gap_fraction: f64, seconds: f64, cfg: BufferConfig) -> Setup {
    let rig = Arc::new(Rig::bind(&demo_hand(), &hand_bind_params()).unwrap());
    setup_of(
        rig,
        demo_hand(),
        Motion::FingerPlay,
        gap_fraction,
        seconds,
        cfg,
        7,
    )
}

/// The session of `motion` on `ch` (bound as `rig`) through a fresh pipeline.
fn setup_of(
    rig: Arc<Rig>,
    ch: rigless::character::Character,
    motion: Motion,
    gap_fraction: f64,
    seconds: f64,
    cfg: BufferConfig,
    seed: u64,
) -> Setup {
    let session = SyntheticSession::new(
        Arc::new(ch),
        motion,
        SyntheticParams {
            rate_hz: RATE_HZ,
            duration_secs: seconds,
            noise_m: 0.0005,
            gap_fraction,
            seed,
            ..SyntheticParams::default()
        },
    );
    let (tx, rx) = bounded(4096);
    let slot = Arc::new(LatestSlot::new());
    let buffer = MarkerBuffer::new(cfg, &rig.marker_rest, &rig.marker_joint);
    let solver = Solver::new(Arc::clone(&rig), SolverParams::default());
    let pipeline = Pipeline::new(solver, buffer, rx, vec![Arc::clone(&slot)]);
    Setup {
        rig,
        motion,
        session,
        pipeline,
        tx,
        slot,
    }
}

/// The skinned truth of a session's motion, to score frames against.
struct Truth {
    ch: Arc<rigless::character::Character>,
    motion: Motion,
    height_m: f64,
    vertices: Vec<glam::DVec3>,
    markers: Vec<glam::DVec3>,
    /// The largest vertex distance of the last frame scored, fraction of the height.
    last_worst: f64,
}

impl Truth {
    fn new(s: &Setup) -> Self {
        let ch = Arc::clone(s.session.character());
        Self {
            vertices: vec![glam::DVec3::ZERO; ch.vertices.len()],
            markers: vec![glam::DVec3::ZERO; ch.markers.len()],
            height_m: s.rig.height_m,
            motion: s.motion,
            last_worst: 0.0,
            ch,
        }
    }

    /// Mean vertex distance of a frame from the truth at `t_s`, as a fraction of the
    /// height.
    fn error(&mut self, f: &DeformedFrame, t_s: f64) -> f64 {
        let pose = self.motion.pose(&self.ch.skeleton, t_s);
        skin_pose(&self.ch, &pose, &mut self.vertices, &mut self.markers);
        let (mut sum, mut worst) = (0.0f64, 0.0f64);
        for (a, b) in f.vertices_m.iter().zip(&self.vertices) {
            let d = (a.as_dvec3() - *b).length();
            sum += d;
            worst = worst.max(d);
        }
        self.last_worst = worst / self.height_m;
        sum / self.vertices.len() as f64 / self.height_m
    }
}

impl Setup {
    /// Sends the session's frame `i` into the channel, stamped at its own time; returns
    /// that time and how many samples were sent.
    fn feed(&mut self, i: usize, batch: &mut Vec<rigless::markers::MarkerSample>) -> (f64, usize) {
        let t = i as f64 / RATE_HZ;
        batch.clear();
        self.session.frame(i, t, batch);
        for smp in batch.iter() {
            self.tx.try_send(*smp).unwrap();
        }
        (t, batch.len())
    }
}

/// A deadline no frame reaches: quality checks must not depend on the machine's speed.
fn far_deadline() -> Instant {
    Instant::now() + Duration::from_secs(3600)
}

/// How a session tracked its truth.
struct Tracking {
    /// Mean and worst per-frame mean vertex error, fractions of the height.
    mean: f64,
    worst_frame: f64,
    /// The largest distance of any vertex in any frame, fraction of the height.
    worst_vertex: f64,
    /// Marker-frames in each fill state.
    states: [usize; 4],
}

/// Plays a session through the pipeline tick by tick and scores every frame.
fn play_session(mut s: Setup) -> Tracking {
    let mut truth = Truth::new(&s);
    let mut batch = Vec::new();
    let (mut err_sum, mut err_max, mut frames) = (0.0f64, 0.0f64, 0usize);
    let mut last_frame = None;
    let mut states = [0usize; 4];
    let mut worst_vertex = 0.0f64;
    for i in 0..s.session.frames() {
        let (t, sent) = s.feed(i, &mut batch);
        let rep = s.pipeline.tick(t, far_deadline(), &|| t);
        assert_eq!(rep.samples, sent);
        let f = s.slot.take().expect("every tick publishes");
        assert_eq!(f.frame, rep.frame);
        if let Some(l) = last_frame {
            assert_eq!(f.frame, l + 1);
        }
        last_frame = Some(f.frame);
        for st in &f.marker_states {
            states[*st as usize] += 1;
        }
        let e = truth.error(&f, t);
        worst_vertex = worst_vertex.max(truth.last_worst);
        err_sum += e;
        err_max = err_max.max(e);
        frames += 1;
    }
    Tracking {
        mean: err_sum / frames as f64,
        worst_frame: err_max,
        worst_vertex,
        states,
    }
}

#[test]
fn frames_track_the_truth_through_occlusion_gaps() {
    let Tracking {
        mean: err_mean,
        worst_frame: err_max,
        states,
        ..
    } = play_session(setup(0.10, 6.0));
    println!("gap-filled tracking: mean {err_mean:.4}, worst frame {err_max:.4} of height, states {states:?}");
    // The same session with every gap held (no prediction, no rigid fill).
    let held_only = BufferConfig {
        predict_max_gap_secs: 1e-9,
        rigid_after_secs: 1e9,
        ..BufferConfig::default()
    };
    let Tracking {
        mean: held_mean,
        worst_frame: held_max,
        states: held_states,
        ..
    } = play_session(setup_with(0.10, 6.0, held_only));
    println!("held-only tracking:  mean {held_mean:.4}, worst frame {held_max:.4} of height, states {held_states:?}");
    // With 10 % of samples missing the states must show it (the session's gap draw).
    assert!(states[FillState::Predicted as usize] > 0);
    assert!(states[FillState::Held as usize] > 0);
    assert_eq!(held_states[FillState::Predicted as usize], 0);
    // Filling must beat holding by a margin: measured 0.0211 against 0.0252 of the
    // height (0.84 times; the session, its gaps and the ticks are deterministic). A fill
    // that predicted nothing would give 1.0 times; 0.9 catches a broken prediction.
    assert!(
        err_mean < 0.9 * held_mean,
        "filled {err_mean} vs held {held_mean}"
    );
    // Without gaps the hand tracks to about 1.3 % of its height (README); a tenth of the
    // samples missing, some for up to a second, may cost up to half as much again.
    assert!(err_mean < 0.025, "mean vertex error {err_mean} of height");
}

/// The body walking with a tenth of its samples in occlusion gaps, against the skinned
/// truth. Its marker set has no knee or ankle markers, so a foot's heel and toe alone
/// place the shin and the foot: a toe whose prediction coasts to a stop while the foot
/// swings on would swing the foot back towards it, were the prediction trusted as a
/// measurement. The solver weighs a predicted marker by its confidence squared instead.
#[test]
fn the_body_walk_tracks_the_truth_through_occlusion_gaps() {
    let rig = Arc::new(Rig::bind(&demo_body(), &body_bind_params()).unwrap());
    let run = |gap_fraction: f64, seed: u64| {
        let walk = Motion::Body(BodyMotion::Walk);
        let cfg = BufferConfig::default();
        play_session(setup_of(
            Arc::clone(&rig),
            demo_body(),
            walk,
            gap_fraction,
            6.0,
            cfg,
            seed,
        ))
    };
    let clean = run(0.0, 7);
    println!(
        "body walk, no gaps: mean {:.4}, worst frame {:.4}, worst vertex {:.4} of height",
        clean.mean, clean.worst_frame, clean.worst_vertex
    );
    // Measured (mean, worst frame, worst vertex; fractions of the height), the sessions
    // and the solve being deterministic: with predictions trusted (and remembered) as
    // measurements (0.0051, 0.0203, 0.259) and (0.0055, 0.0205, 0.286); weighed by confidence
    // squared (0.0046, 0.0152, 0.196) and (0.0042, 0.0119, 0.130). The bounds sit
    // between the two, nearer the second.
    for (seed, bounds) in [(7, [0.0049, 0.0175, 0.225]), (11, [0.0048, 0.0160, 0.200])] {
        let t = run(0.10, seed);
        println!(
            "body walk, 10 % in gaps, seed {seed}: mean {:.4}, worst frame {:.4}, worst vertex {:.4} of height, states {:?}",
            t.mean, t.worst_frame, t.worst_vertex, t.states
        );
        assert!(
            t.states[FillState::Predicted as usize] > 0 && t.states[FillState::Held as usize] > 0
        );
        assert!(
            t.mean < bounds[0] && t.worst_frame < bounds[1] && t.worst_vertex < bounds[2],
            "seed {seed}: {:.4} {:.4} {:.4} against {bounds:?}",
            t.mean,
            t.worst_frame,
            t.worst_vertex
        );
        // Gaps cost something, but the walk stays within 1.5 times its clean error.
        assert!(
            t.mean < 1.5 * clean.mean,
            "{} against {}",
            t.mean,
            clean.mean
        );
    }
}

/// Allocations in the warm ticks (from the tenth on) of `seconds` of `motion` with 10 %
/// of the samples in gaps, solved with `method`, and how many marker samples were
/// rigid-filled on the way.
fn warm_tick_allocations(
    ch: rigless::character::Character,
    bind: rigless::character::bind_params::BindParams,
    motion: Motion,
    method: Method,
    seconds: f64,
) -> (u64, usize) {
    let rig = Arc::new(Rig::bind(&ch, &bind).unwrap());
    let mut session = SyntheticSession::new(
        Arc::new(ch),
        motion,
        SyntheticParams {
            rate_hz: RATE_HZ,
            duration_secs: seconds,
            gap_fraction: 0.10,
            seed: 7,
            ..SyntheticParams::default()
        },
    );
    let (tx, rx) = bounded(16_384);
    let slot = Arc::new(LatestSlot::new());
    let buffer = MarkerBuffer::new(BufferConfig::default(), &rig.marker_rest, &rig.marker_joint);
    let params = SolverParams {
        method,
        ..SolverParams::default()
    };
    let solver = Solver::new(Arc::clone(&rig), params);
    let mut pipeline = Pipeline::new(solver, buffer, rx, vec![Arc::clone(&slot)]);
    let mut batch = Vec::with_capacity(256);
    let (mut allocated, mut rigid) = (0, 0);
    for i in 0..session.frames() {
        let t = i as f64 / RATE_HZ;
        batch.clear();
        session.frame(i, t, &mut batch);
        for smp in &batch {
            tx.try_send(*smp).unwrap();
        }
        let deadline = far_deadline();
        let before = allocations();
        pipeline.tick(t, deadline, &|| t);
        // A sink takes the frame and lets go of it, as the stream's dispatcher does.
        let f = slot.take();
        if i >= 10 {
            allocated += allocations() - before;
        }
        rigid += f.map_or(0, |f| {
            f.marker_states
                .iter()
                .filter(|s| **s == FillState::RigidFilled)
                .count()
        });
    }
    (allocated, rigid)
}

/// The per-frame path (drain, gap filling, solve, full mesh, publish) allocates nothing
/// once warm: the hand with ARAP, the body with ARAP while rigid filling works, and the
/// body with the harmonic method.
#[test]
fn the_warm_loop_does_not_allocate() {
    let cases = [
        (
            "hand, ARAP",
            demo_hand(),
            hand_bind_params(),
            Motion::FingerPlay,
            Method::Arap,
            4.0,
        ),
        (
            "body walk, ARAP",
            demo_body(),
            body_bind_params(),
            Motion::Body(BodyMotion::Walk),
            Method::Arap,
            3.0,
        ),
        (
            "body walk, harmonic",
            demo_body(),
            body_bind_params(),
            Motion::Body(BodyMotion::Walk),
            Method::Harmonic,
            2.0,
        ),
    ];
    for (name, ch, bind, motion, method, seconds) in cases {
        let (allocated, rigid) = warm_tick_allocations(ch, bind, motion, method, seconds);
        assert_eq!(allocated, 0, "{name}: allocations in warm ticks");
        if matches!(motion, Motion::Body(_)) {
            // The body's head and hand clusters fill their gaps rigidly: that path ran.
            assert!(rigid > 0, "{name}: no marker was rigid-filled");
        }
    }
}

/// The loop from 10 s to 11 s on its clock at the test rate: 121 ticks due.
const ONE_SECOND_FROM_10: LoopParams = LoopParams {
    start_s: 10.0,
    rate_hz: RATE_HZ,
    deadline_fraction: 0.8,
    end_s: Some(11.0),
    status_interval_s: 0.5,
};

#[test]
fn run_loop_paces_ticks_on_the_clock_and_stops_at_the_end() {
    let mut s = setup(0.0, 1.0);
    let clock = ManualClock::new(10.0);
    let stop = AtomicBool::new(false);
    let status = LatestSlot::<LoopStatus>::new();
    let last = run_loop(&mut s.pipeline, &clock, ONE_SECOND_FROM_10, &stop, &status);
    // Ticks at 10 + k/120 for k = 0..=120: 121 frames, no overruns on a manual clock.
    assert_eq!(last.frames, 121);
    assert_eq!(last.overruns, 0);
    assert!((clock.now_s() - 11.0).abs() < 1e-9);
    let st = status.take().expect("status published");
    assert!(
        (st.frame_rate_hz - RATE_HZ).abs() < 1.0,
        "rate {}",
        st.frame_rate_hz
    );
    // No input at all: every marker held, and the mesh stays at rest.
    let f = s.slot.take().unwrap();
    assert!(f.marker_states.iter().all(|s| *s == FillState::Held));
    let rest_err = f
        .vertices_m
        .iter()
        .zip(&s.rig.mesh_rest)
        .map(|(a, b)| (a.as_dvec3() - *b).length())
        .fold(0.0, f64::max);
    assert!(
        rest_err < 1e-6 * s.rig.height_m,
        "drift {rest_err} m with no input"
    );
}

/// What a run with a loss of every marker shows.
struct LossRun {
    /// Largest vertex movement over the held stretch (from 0.5 s into the loss to its
    /// end), metres.
    settle_m: f64,
    /// Largest vertex movement between consecutive frames in the loss's last second.
    last_second_drift_m: f64,
    /// Mean vertex error of each frame, fraction of the height.
    errors: Vec<f64>,
}

/// Plays the hand with every sample of frames `lost` withheld.
fn play_with_loss(lost: std::ops::Range<usize>, frames: usize) -> LossRun {
    let mut s = setup(0.0, 30.0);
    let mut truth = Truth::new(&s);
    let mut batch = Vec::new();
    let mut first_held: Option<Vec<glam::Vec3>> = None;
    let mut previous: Option<Vec<glam::Vec3>> = None;
    let (mut settle_m, mut last_second_drift_m) = (0.0f64, 0.0f64);
    let mut errors = Vec::new();
    for i in 0..frames {
        let t = i as f64 / RATE_HZ;
        batch.clear();
        s.session.frame(i, t, &mut batch);
        if !lost.contains(&i) {
            for smp in &batch {
                s.tx.try_send(*smp).unwrap();
            }
        }
        s.pipeline.tick(t, far_deadline(), &|| t);
        let f = s.slot.take().unwrap();
        assert!(
            f.vertices_m.iter().all(|v| v.is_finite()) && f.markers_m.iter().all(|v| v.is_finite()),
            "NaN at frame {i}"
        );
        if i >= lost.start + 60 && i < lost.end {
            assert!(f.marker_states.iter().all(|st| *st == FillState::Held));
            let moved = |p: &Vec<glam::Vec3>| {
                p.iter()
                    .zip(&f.vertices_m)
                    .map(|(a, b)| (*a - *b).length() as f64)
                    .fold(0.0, f64::max)
            };
            match &first_held {
                None => first_held = Some(f.vertices_m.clone()),
                Some(p) => settle_m = settle_m.max(moved(p)),
            }
            if let (Some(p), true) = (&previous, i + 120 >= lost.end) {
                last_second_drift_m = last_second_drift_m.max(moved(p));
            }
            previous = Some(f.vertices_m.clone());
        }
        errors.push(truth.error(&f, t));
    }
    LossRun {
        settle_m,
        last_second_drift_m,
        errors,
    }
}

#[test]
fn all_markers_lost_for_ten_seconds_then_back() {
    let (lost_from, lost_to) = (120usize, 120 + 1200);
    let frames = lost_to + 12;
    let lossy = play_with_loss(lost_from..lost_to, frames);
    let reference = play_with_loss(0..0, frames);
    let after = &lossy.errors[lost_to..lost_to + 6];
    let uninterrupted = &reference.errors[lost_to..lost_to + 6];
    println!(
        "held: settled by {:.2e} m, last second {:.2e} m/frame; after return {after:.4?}; uninterrupted {uninterrupted:.4?}",
        lossy.settle_m, lossy.last_second_drift_m
    );
    // Holding: with no information the mesh only finishes converging (the ARAP iterations
    // of a frame stop at a relative tolerance, and the volume restoration gives the
    // flesh at creases its volume back over a few frames, so the held pose settles
    // geometrically): under 1 mm in all on a 0.2 m hand, and under 1 µm per frame by
    // the end.
    assert!(
        lossy.settle_m < 1e-3,
        "held pose moved {} m",
        lossy.settle_m
    );
    assert!(
        lossy.last_second_drift_m < 1e-6,
        "still moving {} m per frame",
        lossy.last_second_drift_m
    );
    // Back within 3 frames: the third frame after the markers return tracks as well as
    // a run that never lost them, within a tenth of a percent of the height.
    assert!(
        after[2] < uninterrupted[2] + 0.001,
        "after return {after:?}, uninterrupted {uninterrupted:?}"
    );
}

/// A clock that stalls: every `every`-th wait ends `stall_s` past the time asked for, as a
/// machine that stops the loop's thread does. Otherwise a manual clock.
struct StallingClock {
    now_s: std::sync::Mutex<(f64, u64)>,
    every: u64,
    stall_s: f64,
}

impl Clock for StallingClock {
    fn now_s(&self) -> f64 {
        self.now_s.lock().unwrap().0
    }
    fn sleep_until(&self, t_s: f64) {
        let mut g = self.now_s.lock().unwrap();
        g.1 += 1;
        let stall = if g.1.is_multiple_of(self.every) {
            self.stall_s
        } else {
            0.0
        };
        g.0 = g.0.max(t_s) + stall;
    }
    fn unix_s(&self, t_s: f64) -> f64 {
        1.7e9 + t_s
    }
    fn deadline_at(&self, _t_s: f64) -> Instant {
        far_deadline()
    }
}

/// Ticks that fall more than a period behind are skipped and counted as overruns, never
/// run in a burst: a 2.5-period stall every 30th wait over one second at 120 Hz.
#[test]
fn late_ticks_are_skipped_and_counted_not_bunched() {
    let mut s = setup(0.0, 1.5);
    let period = 1.0 / RATE_HZ;
    let clock = StallingClock {
        now_s: std::sync::Mutex::new((10.0, 0)),
        every: 30,
        stall_s: 2.5 * period,
    };
    let stop = AtomicBool::new(false);
    let status = LatestSlot::<LoopStatus>::new();
    let last = run_loop(&mut s.pipeline, &clock, ONE_SECOND_FROM_10, &stop, &status);
    // Each stall puts the loop 2.5 periods behind its tick: the 2 whole periods are
    // skipped (overruns) and the loop runs the tick that is due, half a period late. 121
    // ticks are due in the second; the loop waits 121 − 2 × stalls times, so the stalls
    // at waits 30, 60 and 90 happen and the one at 120 does not: 6 overruns, 115 frames.
    assert_eq!((last.frames, last.overruns), (115, 6), "{last:?}");
    assert_eq!(
        last.frames + last.overruns,
        121,
        "every due tick run or counted: {last:?}"
    );
    // A frame's number is its tick's: the last, tick 120, is numbered 120 although 115
    // frames were solved, so a client sees the skipped ticks as gaps.
    let f = s.slot.take().expect("a published frame");
    assert_eq!(f.frame, 120);
}

/// The loop's count of deadline stops: the hand's pipeline given a mid-curl frame cold
/// (many iterations to go) and a deadline already passed stops that tick after one
/// iteration and counts it; the same markers for five more ticks, with time to spare,
/// add nothing. A count that missed the stop, or counted the other ticks, fails.
#[test]
fn the_loop_counts_the_ticks_its_deadline_stops() {
    use rigless::character::procedural::{hand_pose, HandMotion};
    use rigless::markers::MarkerSample;
    use rigless::solve::arap::StopReason;
    let ch = demo_hand();
    let rig = Arc::new(Rig::bind(&ch, &hand_bind_params()).unwrap());
    let mut truth = vec![glam::DVec3::ZERO; ch.vertices.len()];
    let mut markers = vec![glam::DVec3::ZERO; ch.markers.len()];
    skin_pose(
        &ch,
        &hand_pose(&ch.skeleton, HandMotion::FingerPlay, 1.0),
        &mut truth,
        &mut markers,
    );
    let (tx, rx) = bounded(64);
    let buffer = MarkerBuffer::new(BufferConfig::default(), &rig.marker_rest, &rig.marker_joint);
    let solver = Solver::new(Arc::clone(&rig), SolverParams::default());
    let mut pipeline = Pipeline::new(solver, buffer, rx, Vec::new());
    let send = |t: f64| {
        for (k, p) in markers.iter().enumerate() {
            let s = MarkerSample {
                marker: k as u32,
                time_s: t,
                source_time_s: t,
                position_m: *p,
                occluded: false,
            };
            tx.try_send(s).unwrap();
        }
    };
    send(0.0);
    let cut = pipeline.tick(0.0, Instant::now(), &|| 0.0);
    assert_eq!(
        (cut.solve.stop, cut.solve.iterations),
        (StopReason::Deadline, 1),
        "{:?}",
        cut.solve
    );
    for i in 1..=5 {
        let t = f64::from(i) / RATE_HZ;
        send(t);
        let calm = pipeline.tick(t, far_deadline(), &|| t);
        assert_ne!(calm.solve.stop, StopReason::Deadline, "{:?}", calm.solve);
    }
    let status = pipeline.status(1.0, 0);
    assert_eq!(status.deadline_stops, 1, "{status:?}");
}

/// A sender far faster than the loop (another thread sending 200,000 samples as fast as
/// the channel takes them) never keeps a frame's drain going: each frame takes at most
/// what was queued when it began (the channel holds 4,096), so the loop keeps its rate,
/// and the sender's samples that find the queue full are its to drop. Measured: at most
/// 4,096 (the bound); with the drain unbounded, as it was, one frame took 137,086 while
/// the sender kept up.
#[test]
fn a_flood_never_keeps_a_frame_draining() {
    use rigless::markers::MarkerSample;
    use std::sync::atomic::Ordering;
    let mut s = setup(0.0, 1.0);
    let (tx, stop) = (s.tx.clone(), Arc::new(AtomicBool::new(false)));
    let flood = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let mut sent = 0u64;
            while sent < 200_000 && !stop.load(Ordering::Relaxed) {
                let sample = MarkerSample {
                    marker: (sent % 8) as u32,
                    time_s: 0.001,
                    source_time_s: 0.001,
                    position_m: glam::DVec3::new(0.0, 0.1, 0.0),
                    occluded: false,
                };
                if tx.try_send(sample).is_ok() {
                    sent += 1;
                }
            }
            sent
        })
    };
    // Frames, one after another, for as long as the flood lasts.
    let start = Instant::now();
    let (mut most, mut total, mut frames) = (0, 0, 0u64);
    while !flood.is_finished() {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "the flood never ended"
        );
        let drained = s.pipeline.feed(0.001 * frames as f64);
        most = most.max(drained);
        total += drained;
        frames += 1;
    }
    stop.store(true, Ordering::Relaxed);
    let sent = flood.join().unwrap();
    println!(
        "{sent} sent over {frames} frames, {total} drained; the most one frame drained: {most}"
    );
    assert_eq!(sent, 200_000);
    assert!(most <= 4096, "{most} samples drained in one frame");
    assert!(total > 0, "nothing drained");
}
