//! Several actors on one stage: `[[actors]]` each take their own labels, are solved each
//! by its own pipeline (on the stage's solver threads), enter late and hold when their
//! markers vanish, without disturbing the others. Whole stages in-process on a manual
//! clock, fed the bundled two-actor session and takes written from it.

mod common;

use glam::DVec3;
use rigless::config::parse_stage;
use rigless::daemon::stage::{Stage, StartOptions, Summary};
use rigless::output::frame::DeformedFrame;
use rigless::replay::bundled::{bundled, TWO_ACTORS};
use rigless::replay::c3d::{write_c3d, Processor};
use rigless::replay::recording::Recording;
use rigless::runtime::clock::ManualClock;
use rigless::runtime::slot::LatestSlot;
use std::sync::Arc;

/// Two bodies, Ann's and Bob's, each claiming its subject's labels; `extra` is added to
/// the config (inputs, solver keys).
fn two_actor_stage(extra: &str) -> String {
    format!(
        "[[actors]]\nname = \"Ann\"\nprocedural = \"body\"\nsubject = \"Ann\"\n\n[[actors]]\nname = \"Bob\"\nprocedural = \"body\"\nsubject = \"Bob\"\n\n{extra}"
    )
}

/// Runs `text` for `secs` seconds (None: until the inputs end) on a manual clock;
/// returns the summary and each actor's last frame.
fn run(text: &str, dir: &std::path::Path, secs: Option<f64>) -> (Summary, Vec<Arc<DeformedFrame>>) {
    // No stream: tests run side by side, and the default port is one.
    let text = format!("{text}\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n");
    let cfg = parse_stage(&text, "actors test").unwrap();
    let n = cfg.actor_specs().len();
    let slots: Vec<Arc<LatestSlot<DeformedFrame>>> =
        (0..n).map(|_| Arc::new(LatestSlot::new())).collect();
    let stage = Stage::start_with(
        &cfg,
        dir,
        Arc::new(ManualClock::new(0.0)),
        StartOptions {
            stop_after_secs: secs,
            actor_frames: slots.clone(),
            ..StartOptions::default()
        },
    )
    .unwrap();
    assert_eq!(stage.info().actors.len(), n);
    let summary = stage.join().unwrap();
    let last = slots
        .iter()
        .map(|s| s.take().expect("every actor published a frame"))
        .collect();
    (summary, last)
}

fn mean(points: &[glam::Vec3]) -> DVec3 {
    points.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / points.len().max(1) as f64
}

/// The bundled two-actor session drives both bodies, each with its own labels: every
/// one of the 72 labels feeds a marker, each actor is fed its 36 markers' samples (960
/// frames), and each mesh stands where its performer walks at the end (Ann 9.6 m along
/// +Z, Bob back near the start, 0.4 m to the side).
#[test]
fn the_two_actor_session_drives_each_body_with_its_own_labels() {
    let dir = tempfile::tempdir().unwrap();
    let text = two_actor_stage("[[inputs]]\ntype = \"replay\"\nsession = \"body_two_actors\"\n");
    let (s, last) = run(&text, dir.path(), None);
    assert_eq!((s.labels_fed, s.labels_ignored), (Some(72), Some(0)));
    assert_eq!(s.actors.len(), 2);
    for a in &s.actors {
        let b = &a.status.buffer;
        // Every sample of the actor's 36 markers over 960 frames, its gaps included.
        assert_eq!(b.accepted + b.occluded, 36 * 960, "{}: {b:?}", a.name);
        assert_eq!(a.status.frames, 960);
        // The walk alone on the body fits to 0.64 mm RMS (tests/subjects.rs); the same
        // here for each (measured 0.66-0.67); a body fed the other's markers misses by
        // metres.
        println!(
            "{}: residual RMS {:.2} mm",
            a.name, a.status.marker_residual_mm_rms
        );
        assert!(
            a.status.marker_residual_mm_rms < 1.5,
            "{}: {:?}",
            a.name,
            a.status
        );
    }
    // At 8 s Ann has walked 8 × 1.2 m along +Z from the origin; Bob, turned about from
    // (0.4, 0, 9.6), is back at z = 0. The pelvis is within a few cm of the mesh's mean.
    let (ann, bob) = (mean(&last[0].vertices_m), mean(&last[1].vertices_m));
    println!("Ann at {ann:.2}, Bob at {bob:.2}");
    let walked = 1.2 * (959.0 / 120.0);
    assert!((ann.z - walked).abs() < 0.2 && ann.x.abs() < 0.1, "{ann}");
    assert!(
        (bob.z - (9.6 - walked)).abs() < 0.2 && (bob.x - 0.4).abs() < 0.1,
        "{bob}"
    );
}

/// Bob enters the volume 1.5 s in: until then all his markers are held and the summary
/// of a run that stops at 1 s says so, while Ann is measured throughout; his entry does
/// not disturb her (her frames and residual are the same as when she is alone).
#[test]
fn an_actor_who_enters_late_holds_until_his_markers_appear() {
    let dir = tempfile::tempdir().unwrap();
    let text = two_actor_stage("[[inputs]]\ntype = \"replay\"\nsession = \"body_two_actors\"\n");
    let (early, _) = run(&text, dir.path(), Some(1.0));
    let (ann, bob) = (&early.actors[0].status, &early.actors[1].status);
    assert_eq!(
        bob.fill_now[3], 36,
        "every one of Bob's markers held: {bob:?}"
    );
    assert_eq!(bob.buffer.accepted, 0);
    assert!(ann.fill_now[0] >= 30, "Ann is measured: {ann:?}");
    assert!(TWO_ACTORS[1].enters_s > 1.0);
    // Ann alone: the same take with Bob's labels claimed by nobody.
    let alone = "[[actors]]\nname = \"Ann\"\nprocedural = \"body\"\nsubject = \"Ann\"\n[[inputs]]\ntype = \"replay\"\nsession = \"body_two_actors\"\n";
    let (solo, _) = run(alone, dir.path(), None);
    let (with_bob, _) = run(&text, dir.path(), None);
    let (a, b) = (&solo.actors[0].status, &with_bob.actors[0].status);
    assert_eq!(a.frames, b.frames);
    assert_eq!(a.buffer.accepted, b.buffer.accepted);
    // Deterministic on the manual clock: the same solve to the last digit.
    assert_eq!(a.marker_residual_mm_rms, b.marker_residual_mm_rms);
    // Bob's labels in the solo run are nobody's: refused, counted, and named.
    assert_eq!(solo.labels_ignored, Some(36));
}

/// Bare names never collide across actors: a take whose two subjects have the same
/// labels feeds each actor its own, and a third subject nobody claims is ignored and
/// named in the input's closing line.
#[test]
fn a_third_subject_nobody_claims_is_ignored_and_named() {
    let dir = tempfile::tempdir().unwrap();
    let rec = Recording::from_c3d("two", bundled("body_two_actors").unwrap()).unwrap();
    // Cy: Ann's walk again, 3 m to the side.
    let n = rec.labels.len() / 2;
    let mut labels = rec.labels.clone();
    labels.extend(rec.labels[..n].iter().map(|l| l.replace("Ann:", "Cy:")));
    let frames: Vec<Vec<DVec3>> = rec
        .frames
        .iter()
        .map(|f| {
            let cy = f[..n].iter().map(|p| *p + DVec3::X * 3.0);
            f.iter().copied().chain(cy).collect()
        })
        .collect();
    let path = dir.path().join("three.c3d");
    let bytes = write_c3d(&labels, rec.rate_hz, &frames, Processor::Intel).unwrap();
    std::fs::write(&path, bytes).unwrap();
    let text = two_actor_stage(&format!(
        "[[inputs]]\ntype = \"replay\"\npath = {:?}\n",
        path.display().to_string()
    ));
    let (s, last) = run(&text, dir.path(), Some(2.0));
    assert_eq!((s.labels_fed, s.labels_ignored), (Some(72), Some(36)));
    // Ann stays at her own walk (x about 0), not pulled towards Cy's 3 m away.
    let ann = mean(&last[0].vertices_m);
    assert!(ann.x.abs() < 0.1, "{ann}");
}

/// Every `[[actors]]` problem at once, each at its line: a duplicate name, two actors
/// claiming the same subject, a subject and labels both given, an unknown key, and
/// `[character]` given as well.
#[test]
fn actor_problems_are_reported_at_once_with_their_lines() {
    let text = r#"[character]
procedural = "body"

[[actors]]
name = "Ann"
procedural = "body"
subject = "Ann"

[[actors]]
name = "Ann"
procedural = "body"
subject = "ann"

[[actors]]
name = "Cy"
procedural = "body"
subject = "Cy"
labels = ["Cy_*"]

[[actors]]
name = "Dee"
procedural = "body"
colour = "red"

[[inputs]]
type = "replay"
session = "body_two_actors"
"#;
    let e = parse_stage(text, "stage.toml").unwrap_err().to_string();
    println!("{e}");
    for want in [
        "line 1: character: give either [character]",
        "line 10: actors[1].name: actor \"Ann\" is named twice",
        "actors[1]: actor \"Ann\" claims labels actor \"Ann\" (actors[0]) claims",
        "actors[2].labels: give either subject or labels",
        "actors[3].colour: unknown field",
    ] {
        assert!(e.contains(want), "missing {want:?} in:\n{e}");
    }
    // Two actors without subject or labels both claim the unprefixed labels.
    let both_bare = "[[actors]]\nname = \"A\"\nprocedural = \"body\"\n[[actors]]\nname = \"B\"\nprocedural = \"hand\"\n[[inputs]]\ntype = \"synthetic\"\n";
    let e = parse_stage(both_bare, "s.toml").unwrap_err().to_string();
    assert!(e.contains("labels without a subject prefix"), "{e}");
    // A pattern that takes another's subject.
    let overlap = "[[actors]]\nname = \"A\"\nprocedural = \"body\"\nsubject = \"Ann\"\n[[actors]]\nname = \"B\"\nprocedural = \"body\"\nlabels = [\"An*\"]\n[[inputs]]\ntype = \"synthetic\"\n";
    let e = parse_stage(overlap, "s.toml").unwrap_err().to_string();
    assert!(e.contains("claims labels"), "{e}");
}

/// `[solver] threads` spreads the actors over threads; the solve does not depend on it
/// (deterministic on the manual clock: the same residuals with one thread and two).
#[test]
fn the_solve_does_not_depend_on_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let with = |threads: usize| {
        two_actor_stage(&format!(
            "[solver]\nthreads = {threads}\n[[inputs]]\ntype = \"replay\"\nsession = \"body_two_actors\"\n"
        ))
    };
    let (one, _) = run(&with(1), dir.path(), Some(3.0));
    let (two, _) = run(&with(2), dir.path(), Some(3.0));
    for (a, b) in one.actors.iter().zip(&two.actors) {
        assert_eq!(a.status.frames, b.status.frames);
        assert_eq!(
            a.status.marker_residual_mm_rms, b.status.marker_residual_mm_rms,
            "{}",
            a.name
        );
    }
}

/// A label swap between two bodies walking 0.3 m apart (six markers' labels exchanged
/// for a second): with the identity gate no frame of Ann's mesh moves more than 0.1 m
/// towards Bob (measured: at most 0.012 m, 676 samples gated); without it the swap
/// pulls her mesh 0.26 m towards him for the whole second (about 120 frames), so the
/// case does test the gate.
#[test]
fn a_label_swap_between_two_actors_never_pulls_one_towards_the_other() {
    use rigless::bench::actors::{label_swap, PULL_LIMIT_M};
    let dir = tempfile::tempdir().unwrap();
    let on = label_swap(dir.path(), 0.3, true).unwrap();
    println!("{on:?}");
    assert_eq!(on.frames_pulled, 0, "{on:?}");
    assert!(on.worst_pull_m < 0.03, "{on:?}");
    assert!(on.identity_gated > 300, "{on:?}");
    let off = label_swap(dir.path(), 0.3, false).unwrap();
    println!("{off:?}");
    assert!(
        off.frames_pulled > 60 && off.worst_pull_m > 2.0 * PULL_LIMIT_M,
        "{off:?}"
    );
}

/// The command line's actor flags refuse what they cannot do, naming what the take has:
/// `calibrate --actor` a subject the take lacks, `replay --solve --actors` a take of one
/// performer.
#[test]
fn the_actor_flags_name_what_the_take_has() {
    let take = |name: &str| format!("{}/replay/{name}.c3d", env!("CARGO_MANIFEST_DIR"));
    let run = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigless"))
            .args(args)
            .output()
            .expect("rigless runs");
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (ok, err) = run(&[
        "calibrate",
        "body",
        &take("body_two_actors"),
        "--actor",
        "Cy",
    ]);
    assert!(
        !ok && err.contains("its subjects: \"Ann\", \"Bob\""),
        "{err}"
    );
    let (ok, err) = run(&[
        "replay",
        &take("body_walk"),
        "--solve",
        "body",
        "--actors",
        "--viewer",
        "off",
    ]);
    assert!(!ok && err.contains("has 1 performer"), "{err}");
    let (ok, err) = run(&["calibrate", "body", &take("body_walk"), "--actors"]);
    assert!(!ok && err.contains("has 1 performer"), "{err}");
}

/// `calibrate --actors --write` on the two-actor session: each performer calibrated on
/// its own labels (both are the body itself: scale 1 within 1 %, 36 placed), each
/// layout written into its own copy of the character file, which loads.
#[test]
fn calibrate_actors_writes_a_file_per_performer() {
    let dir = tempfile::tempdir().unwrap();
    let rigless = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigless"))
            .args(args)
            .current_dir(dir.path())
            .output()
            .expect("rigless runs");
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{text}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        text
    };
    rigless(&["export-character", "body", "."]);
    let take = format!("{}/replay/body_two_actors.c3d", env!("CARGO_MANIFEST_DIR"));
    let out = rigless(&["calibrate", "body.toml", &take, "--actors", "--write"]);
    println!("{out}");
    assert_eq!(out.matches("verdict      good").count(), 2, "{out}");
    for actor in ["Ann", "Bob"] {
        assert!(out.contains(&format!("actor {actor} (36 labels)")), "{out}");
        let loaded = rigless::character::file::load_character(
            &dir.path().join(format!("body-{actor}.toml")),
        )
        .unwrap();
        assert_eq!(loaded.character.markers.len(), 36, "{actor}");
        assert!(
            (loaded.marker_scale - 1.0).abs() < 0.01,
            "{actor}: marker_scale {}",
            loaded.marker_scale
        );
    }
}

/// `[calibration] first_secs` on a stage of two: the first seconds are captured once and
/// each actor is calibrated on its own labels. Ann is 1.1 times the body and Bob 0.9
/// times (the range-of-motion take scaled, Bob's 3 m to the side): each calibration
/// finds its own performer's size within 1 % (the calibration's target) and places all
/// 36 labels, and then each body follows its performer within 0.7 mm RMS (0.35 mm
/// measured for each).
#[test]
fn a_live_calibration_calibrates_each_actor_on_its_own_labels() {
    let dir = tempfile::tempdir().unwrap();
    let rom = Recording::from_c3d("body_rom", bundled("body_rom").unwrap()).unwrap();
    let mut labels = Vec::new();
    for subject in ["Ann", "Bob"] {
        labels.extend(rom.labels.iter().map(|l| format!("{subject}:{l}")));
    }
    let frames: Vec<Vec<DVec3>> = rom
        .frames
        .iter()
        .map(|f| {
            let ann = f.iter().map(|p| *p * 1.1);
            let bob = f.iter().map(|p| *p * 0.9 + DVec3::new(3.0, 0.0, 0.0));
            ann.chain(bob).collect()
        })
        .collect();
    let bytes = write_c3d(&labels, rom.rate_hz, &frames, Processor::Intel).unwrap();
    std::fs::write(dir.path().join("two.c3d"), bytes).unwrap();
    let text = two_actor_stage(
        "[[inputs]]\ntype = \"replay\"\npath = \"two.c3d\"\n\n[calibration]\nfirst_secs = 12.0\nalways = true\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n",
    );
    let cfg = parse_stage(&text, "two calibrated").unwrap();
    let stage = Stage::start_with(
        &cfg,
        dir.path(),
        Arc::new(ManualClock::new(0.0)),
        StartOptions {
            stop_after_secs: Some(2.0),
            ..StartOptions::default()
        },
    )
    .unwrap();
    for (a, size) in stage.info().actors.iter().zip([1.1, 0.9]) {
        let line = a.calibration.as_deref().expect("each actor calibrated");
        println!("{}: {line}", a.name);
        assert!(line.contains("36 placed, 0 left out"), "{line}");
        let found: f64 = line
            .split("the actor is ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|x| x.parse().ok())
            .unwrap_or_else(|| panic!("no size in {line}"));
        assert!(
            (found / size - 1.0).abs() < 0.01,
            "{}: {found} for {size}",
            a.name
        );
    }
    let summary = stage.join().unwrap();
    for a in &summary.actors {
        let rms = a.status.marker_residual_mm_rms;
        println!("{}: residual {rms:.2} mm RMS after calibration", a.name);
        assert!(rms > 0.0 && rms < 0.7, "{}: {rms}", a.name);
    }
}

/// One file per actor: two replay inputs of takes without subject prefixes, each named
/// its performer's by `subject` (the body's walk as Ann's, its reach 3 m to the side as
/// Bob's), feed each actor its own file's 36 markers and nothing of the other's.
#[test]
fn one_file_per_actor_feeds_each_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let reach = Recording::from_c3d("body_reach", bundled("body_reach").unwrap()).unwrap();
    let frames: Vec<Vec<DVec3>> = reach
        .frames
        .iter()
        .map(|f| f.iter().map(|p| *p + DVec3::new(3.0, 0.0, 0.0)).collect())
        .collect();
    let bytes = write_c3d(&reach.labels, reach.rate_hz, &frames, Processor::Intel).unwrap();
    std::fs::write(dir.path().join("bob.c3d"), bytes).unwrap();
    let text = two_actor_stage(
        "[[inputs]]\ntype = \"replay\"\nsession = \"body_walk\"\nsubject = \"Ann\"\n\n[[inputs]]\ntype = \"replay\"\npath = \"bob.c3d\"\nsubject = \"Bob\"\n",
    );
    let (summary, last) = run(&text, dir.path(), Some(2.0));
    // Each input's 36 labels all feed a marker: 72 fed, none ignored.
    assert_eq!(
        (summary.labels_fed, summary.labels_ignored),
        (Some(72), Some(0))
    );
    // Ann walks near x = 0, Bob reaches near x = 3: each mesh where its own file is.
    let x = |f: &DeformedFrame| mean(&f.vertices_m).x;
    assert!(x(&last[0]).abs() < 1.0, "Ann at x {}", x(&last[0]));
    assert!((x(&last[1]) - 3.0).abs() < 1.0, "Bob at x {}", x(&last[1]));
    for a in &summary.actors {
        assert!(
            a.status.marker_residual_mm_rms < 2.0,
            "{}: {:?}",
            a.name,
            a.status
        );
    }
}
