//! Two performers in one take: a character is one performer, so it takes one subject's
//! labels (`Ann:LFHD`, never also `Bob:LFHD`), the one `[character] subject` names or
//! else the one with most matching labels, and never jumps between them. Whole stages
//! in-process on a manual clock, the take written as a C3D file of two subjects.

mod common;

use glam::DVec3;
use rigless::config::parse_stage;
use rigless::daemon::stage::{Stage, StartOptions, Summary};
use rigless::output::frame::DeformedFrame;
use rigless::replay::bundled::bundled;
use rigless::replay::c3d::{write_c3d, Processor};
use rigless::replay::recording::Recording;
use rigless::runtime::clock::ManualClock;
use rigless::runtime::slot::LatestSlot;
use std::sync::Arc;

/// How far Bob walks beside Ann, metres (along x).
const APART_M: f64 = 3.0;

/// The bundled body walk twice in one file: `Ann:` labels where it was recorded, `Bob:`
/// labels the same walk [`APART_M`] to the side (Ann's labels first).
fn two_subjects(dir: &std::path::Path) -> std::path::PathBuf {
    let rec =
        Recording::from_c3d("body_walk", bundled("body_walk").expect("bundled walk")).expect("C3D");
    let labels: Vec<String> = ["Ann", "Bob"]
        .iter()
        .flat_map(|s| rec.labels.iter().map(move |l| format!("{s}:{l}")))
        .collect();
    let frames: Vec<Vec<DVec3>> = rec
        .frames
        .iter()
        .map(|f| {
            let bob = f.iter().map(|p| *p + DVec3::X * APART_M);
            f.iter().copied().chain(bob).collect()
        })
        .collect();
    let path = dir.join("two.c3d");
    let bytes = write_c3d(&labels, rec.rate_hz, &frames, Processor::Intel).expect("written");
    std::fs::write(&path, bytes).expect("saved");
    path
}

/// The body driven by the two-subject take for 2 s, `subject` its `[character]
/// subject` line (empty for none): the summary and the last frame.
fn run(subject: &str) -> (Summary, Arc<DeformedFrame>) {
    let dir = tempfile::tempdir().unwrap();
    let path = two_subjects(dir.path());
    let text = format!(
        "[character]\nprocedural = \"body\"\n{subject}\n\n[[inputs]]\ntype = \"replay\"\npath = {:?}\n",
        path.display().to_string()
    );
    let cfg = parse_stage(&text, "two subjects").unwrap();
    let frames = Arc::new(LatestSlot::new());
    let stage = Stage::start_with(
        &cfg,
        dir.path(),
        Arc::new(ManualClock::new(0.0)),
        StartOptions {
            stop_after_secs: Some(2.0),
            frames: Some(Arc::clone(&frames)),
            ..StartOptions::default()
        },
    )
    .unwrap();
    let summary = stage.join().unwrap();
    (summary, frames.take().expect("a frame was published"))
}

/// The mean of `points` along x, metres.
fn mean_x(points: &[glam::Vec3]) -> f64 {
    points.iter().map(|p| f64::from(p.x)).sum::<f64>() / points.len().max(1) as f64
}

/// Without a subject named, the body takes one performer's labels (the two have as many;
/// the first listed, Ann's) and its mesh stands where Ann walks; named, it takes Bob's
/// and stands 3 m away. The other's 36 labels are ignored either way: fed 36 of 72.
#[test]
fn a_take_of_two_performers_drives_the_body_with_one() {
    let (ann, ann_last) = run("");
    let (bob, bob_last) = run("subject = \"Bob\"");
    for s in [&ann, &bob] {
        assert_eq!((s.labels_fed, s.labels_ignored), (Some(36), Some(36)));
        // The walk's own residual on the body (measured 0.64 mm RMS); a mesh pulled
        // between two people 3 m apart misses by metres.
        println!("residual RMS {:.2} mm", s.status.marker_residual_mm_rms);
        assert!(s.status.marker_residual_mm_rms < 1.5, "{:?}", s.status);
    }
    // The markers each frame shows are the ones it took; its mesh is around them.
    let (ann_x, bob_x) = (mean_x(&ann_last.vertices_m), mean_x(&bob_last.vertices_m));
    println!("mesh at x = {ann_x:.3} m (Ann), {bob_x:.3} m (Bob)");
    assert!(
        (mean_x(&ann_last.markers_m) - ann_x).abs() < 0.2,
        "the mesh stands at its markers"
    );
    // Bob's walk is Ann's moved 3 m: the two meshes stand 3 m apart, within a
    // centimetre (the same solve of the same markers, moved).
    assert!(((bob_x - ann_x) - APART_M).abs() < 0.01, "{ann_x} {bob_x}");
}

/// A subject that cannot prefix a label is refused, with its key.
#[test]
fn a_subject_with_a_colon_is_refused_by_name() {
    let text = "[character]\nprocedural = \"body\"\nsubject = \"Ann:LFHD\"\n";
    let e = parse_stage(text, "bad").unwrap_err().to_string();
    assert!(e.contains("character.subject"), "{e}");
}

/// Off line (`replay --solve ... --export`, `calibrate --check`) the same: the subject
/// with most labels (here the first of two alike, Ann) feeds the body, and the report
/// names the other's labels ignored.
#[test]
fn an_offline_replay_of_two_performers_solves_one_and_says_so() {
    use rigless::character::demo::{body_bind_params, demo_body};
    use rigless::daemon::offline::{replay_offline, OfflineOptions};
    use rigless::rig::bind::Rig;
    use rigless::solve::frame::SolverParams;
    let dir = tempfile::tempdir().unwrap();
    let rec = Recording::load(&two_subjects(dir.path())).expect("written take");
    let rig = Arc::new(Rig::bind(&demo_body(), &body_bind_params()).expect("bind"));
    let solve = |rec: &Recording| {
        replay_offline(
            Arc::clone(&rig),
            SolverParams::default(),
            rec,
            OfflineOptions::default(),
        )
        .expect("solves")
        .expect("labels fed")
    };
    let report = solve(&rec);
    assert_eq!(report.labels_fed, 36);
    let others = report.other_subjects.expect("Bob's labels named");
    println!("{others}");
    assert!(
        others.starts_with(
            "36 labels of subject \"Bob\" ignored (the character takes \"Ann\"'s labels"
        ),
        "{others}"
    );
    // The walk's own misfit on the body, as in the stage above.
    println!("residual RMS {:.2} mm", report.residual_mm_rms);
    assert!(report.residual_mm_rms < 1.5, "{}", report.residual_mm_rms);
    // `replay --subject Bob` keeps Bob's columns alone: nothing left to ignore.
    let mut bob = rec.clone();
    assert_eq!(bob.keep_subject("bob"), 36);
    assert_eq!(bob.labels.len(), 36);
    assert!(bob.labels.iter().all(|l| l.starts_with("Bob:")));
    assert!(bob.frames.iter().all(|f| f.len() == 36));
    let report = solve(&bob);
    assert_eq!((report.labels_fed, report.other_subjects), (36, None));
}

/// Takes the OSC input's frames until it has `want` of them, keeping each sample.
struct Collect {
    want: usize,
    frames: usize,
    samples: Vec<(u32, DVec3)>,
    done: Arc<std::sync::atomic::AtomicBool>,
}

impl rigless::input::InputSink for Collect {
    fn frame(&mut self, frame: &rigless::input::InputFrame<'_>) -> bool {
        self.samples
            .extend(frame.samples.iter().map(|s| (s.marker, s.position_m)));
        self.frames += 1;
        let more = self.frames < self.want;
        if !more {
            self.done.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        more
    }
    fn glove(
        &mut self,
        _: f64,
        _: &rigless::protocol::glove::GloveReading,
        _: &rigless::input::glove::HandMap,
    ) -> bool {
        true
    }
}

/// Live over OSC on loopback: packets carrying both performers' markers feed only the
/// first subject matched (Ann, listed first), every sample of hers, and the input's
/// closing line counts Bob's refused.
#[test]
fn a_live_stream_of_two_performers_feeds_the_first_subject_matched() {
    use rigless::input::config::{InputConfig, OscInputConfig};
    use rigless::input::{Input, OpenContext};
    use rigless::markers::index::SubjectFilter;
    use rigless::protocol::osc::encode_native;
    use std::sync::atomic::{AtomicBool, Ordering};
    const FRAMES: usize = 20;
    let markers: Vec<String> = ["LFHD", "RFHD"].iter().map(|s| s.to_string()).collect();
    let cfg = InputConfig::Osc(OscInputConfig {
        url: "osc://127.0.0.1:0".into(),
        ..OscInputConfig::default()
    });
    let ctx = OpenContext {
        base_dir: std::path::Path::new("."),
        markers: Some(&markers),
        skeleton: None,
        procedural: None,
        subject: &SubjectFilter::One,
        actors: None,
    };
    let input = Input::open(&cfg, &ctx).expect("binds");
    let addr = input.local_addr().expect("bound");
    let stop = Arc::new(AtomicBool::new(false));
    let done = Arc::new(AtomicBool::new(false));
    let (stop2, done2) = (Arc::clone(&stop), Arc::clone(&done));
    let log = common::LogCapture::default();
    let dispatch = tracing::Dispatch::new(log.subscriber(tracing::Level::WARN));
    let runner = std::thread::spawn(move || {
        let _said = tracing::dispatcher::set_default(&dispatch);
        let clock = rigless::runtime::clock::SystemClock::new();
        let mut sink = Collect {
            want: FRAMES,
            frames: 0,
            samples: Vec::new(),
            done: done2,
        };
        let line = input.run(&clock, 0.0, &stop2, &mut sink).expect("runs");
        (line, sink)
    });
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let ann = DVec3::new(0.0, 1.7, 0.0);
    let bob = ann + DVec3::X * APART_M;
    // UDP on loopback: sent again until the input has its frames, 5 s at most.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    let mut frame = 0;
    while !done.load(Ordering::Relaxed) && std::time::Instant::now() < deadline {
        let packet = encode_native(
            frame,
            (0, 1),
            &[
                ("Ann:LFHD", ann),
                ("Bob:LFHD", bob),
                ("Bob:RFHD", bob),
                ("Ann:RFHD", ann),
            ],
        );
        socket.send_to(&packet, addr).unwrap();
        frame += 1;
        std::thread::yield_now();
    }
    stop.store(true, Ordering::Relaxed);
    let (line, sink) = runner.join().unwrap();
    println!("{line}");
    assert_eq!(sink.frames, FRAMES, "every frame within 5 s");
    assert_eq!(sink.samples.len(), 2 * FRAMES, "Ann's two markers a frame");
    assert!(sink.samples.iter().all(|(_, p)| (*p - ann).length() < 1e-6));
    let refused = format!(
        "{} samples of subject \"Bob\" ignored (the character takes \"Ann\"'s labels)",
        2 * FRAMES
    );
    assert!(line.contains(&refused), "{line}");
    // Said once, not once a packet.
    assert_eq!(
        log.count("WARN", "labels of subject \"Bob\" ignored"),
        1,
        "{:?}",
        log.lines()
    );
}
