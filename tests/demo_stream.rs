//! End to end over loopback: `rigless demo` and `rigless run --config` play procedural
//! characters live and the Python reference client (`protocols/vertex_stream_client.py`)
//! reads the vertex stream.

use std::process::Command;
use std::time::{Duration, Instant};

mod common;

use common::{client_summary, Daemon};

#[test]
fn python_client_reads_topology_frames_and_goodbye() {
    if Command::new("python3").arg("--version").output().is_err() {
        panic!("python3 is required (README set-up installs it)");
    }
    let demo = Daemon::start(&["demo", "--seconds", "3", "--stream", "127.0.0.1:0"]);
    let addr = demo.addr.clone();
    let s = &client_summary(&addr, &["--timeout", "20"]);
    let started = Instant::now();
    let (ok, lines) = demo.finish();
    assert!(ok, "demo failed: {lines:?}");
    assert!(started.elapsed() < Duration::from_secs(30));
    println!("{s}");
    let topo = &s["topology"];
    assert_eq!(topo["character"], "hand");
    assert_eq!(topo["vertex_count"], 5001);
    assert_eq!(topo["length_unit"], "m");
    assert_eq!(topo["up_axis"], "+Y");
    assert_eq!(topo["marker_names"].as_array().unwrap().len(), 8);
    assert_eq!(topo["joint_names"], 21);
    // The procedural hand is one part (version 2 topology).
    assert_eq!(topo["part_names"], serde_json::json!(["hand"]));
    assert_eq!(s["goodbye"], "time limit reached");
    assert_eq!(s["frame_numbers_increasing"], true);
    assert_eq!(s["vertex_count_matches"], true);
    assert_eq!(s["marker_count_matches"], true);
    assert_eq!(s["all_finite"], true);
    // 3 s at 120 Hz is 360 frames; the client joins a little after the stream starts and
    // may skip a few if the machine stalls it, but must see most of them.
    let frames = s["frames"].as_u64().unwrap();
    assert!((200..=361).contains(&frames), "frames {frames}");
    let last = s["last_frame"].as_u64().unwrap();
    // The hand is about 0.2 m tall and stays near the origin.
    for a in 0..3 {
        let lo = s["bbox_min"][a].as_f64().unwrap();
        let hi = s["bbox_max"][a].as_f64().unwrap();
        assert!(
            lo > -0.3 && hi < 0.3 && hi - lo > 0.05,
            "axis {a}: {lo}..{hi}"
        );
    }
    // The bundled session loses 5 % of samples: some frames show filled or held markers.
    let fills = &s["fill_counts"];
    let not_measured = fills["predicted"].as_u64().unwrap()
        + fills["rigid_filled"].as_u64().unwrap()
        + fills["held"].as_u64().unwrap();
    assert!(not_measured > 0, "{fills}");
    // The client saw the daemon's last frame (the loop may skip ticks on a loaded
    // machine, so the count comes from the daemon's own summary).
    let done = lines
        .iter()
        .find_map(|l| l.strip_prefix("done (time limit reached): "))
        .unwrap_or_else(|| panic!("no summary in {lines:?}"));
    let solved: u64 = done.split(' ').next().unwrap().parse().unwrap();
    assert_eq!(last + 1, solved, "{done}");
}

/// Writes a stage config of the procedural body with a looping synthetic `motion`, the
/// given `[solver]` lines and a stream on a free port, and starts `rigless run` on it for
/// `seconds`.
fn start_body_stage(
    solver: &str,
    motion: &str,
    seconds: &str,
) -> (tempfile::TempDir, std::path::PathBuf, Daemon) {
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("stage.toml");
    std::fs::write(
        &stage,
        format!("[character]\nprocedural = \"body\"\n\n[solver]\n{solver}\n\n[[inputs]]\ntype = \"synthetic\"\nmotion = \"{motion}\"\nloop = true\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n"),
    )
    .unwrap();
    let run = Daemon::start(&[
        "run",
        "--config",
        stage.to_str().unwrap(),
        "--seconds",
        seconds,
    ]);
    (dir, stage, run)
}

/// A client summary of 30 finite frames of the body, about 1.75 m tall on y = 0.
fn assert_body_frames(s: &serde_json::Value) {
    assert_eq!(s["frames"], 30);
    assert_eq!(s["all_finite"], true);
    let (ylo, yhi) = (
        s["bbox_min"][1].as_f64().unwrap(),
        s["bbox_max"][1].as_f64().unwrap(),
    );
    assert!(ylo > -0.2 && (1.5..2.2).contains(&yhi), "y {ylo}..{yhi}");
}

#[test]
fn run_serves_a_stage_config_and_reports_config_errors_with_lines() {
    let (_dir, stage, run) = start_body_stage("rate_hz = 60", "reach", "4");
    let addr = run.addr.clone();
    // Read 30 frames (half a second at 60 Hz), then hang up: the server must carry on.
    let s = &client_summary(&addr, &["--frames", "30"]);
    assert_eq!(s["topology"]["character"], "body");
    assert_eq!(s["topology"]["rate_hz"], 60.0);
    assert_eq!(s["topology"]["marker_names"].as_array().unwrap().len(), 36);
    assert_body_frames(s);
    let (ok, lines) = run.finish();
    assert!(ok, "{lines:?}");
    assert!(
        lines
            .iter()
            .any(|l| l.starts_with("done (time limit reached)")),
        "{lines:?}"
    );

    // A broken config: every problem at once, with lines, and a failing exit.
    std::fs::write(
        &stage,
        "[character]\nprocedural = \"dog\"\n[solver]\nrate_hz = 0\nfoo = 1\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args(["run", "--config", stage.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    for want in [
        "4 problems",
        "line 2: character.procedural",
        "line 4: solver.rate_hz",
        "line 5: solver.foo: unknown field",
        "no inputs",
    ] {
        assert!(err.contains(want), "missing {want:?} in {err}");
    }
}

#[test]
fn a_killed_daemon_loses_at_most_one_flush_interval_of_its_session() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("take.rlsession");
    let stage = dir.path().join("stage.toml");
    std::fs::write(
        &stage,
        "[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"replay\"\nsession = \"hand_finger_play\"\nloop = true\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n\n[recorder]\npath = \"take.rlsession\"\nflush_interval_secs = 0.25\n",
    )
    .unwrap();
    let daemon = Daemon::start(&[
        "run",
        "--config",
        stage.to_str().unwrap(),
        "--seconds",
        "60",
    ]);
    // The stream address is printed after the recorder started; let it record ~2 s.
    let printed = Instant::now();
    std::thread::sleep(Duration::from_secs(2));
    let mut child = daemon.child;
    child.kill().expect("SIGKILL");
    let killed_after = printed.elapsed().as_secs_f64();
    let _ = child.wait();
    let rec = rigless::replay::recording::Recording::load(&session).expect("session readable");
    let s = rigless::replay::session::read_session(&std::fs::read(&session).unwrap()).unwrap();
    // Sample times are the take's (the replay's source clock), 120 frames a second from
    // its first: the span recorded is the newest minus the first, plus a frame.
    let first = s
        .samples
        .iter()
        .map(|x| x.time_s)
        .fold(f64::INFINITY, f64::min);
    let newest = s.samples.iter().map(|x| x.time_s).fold(0.0, f64::max);
    let span = newest - first + 1.0 / 120.0;
    println!(
        "killed after {killed_after:.2} s; {} samples, newest at {newest:.3} s; warnings {:?}",
        s.samples.len(),
        s.warnings
    );
    assert_eq!(rec.labels.len(), 8);
    assert_eq!(rec.rate_hz, 120.0);
    // The replay starts before the daemon prints its address, so it had played at least
    // `killed_after` at the kill: what is lost is one flush interval (0.25 s) and the
    // slack of a flush running late on a loaded 2-core machine (SLACK_S).
    const SLACK_S: f64 = 0.15;
    let lost = killed_after - span;
    println!("lost at most {lost:.3} s (flush interval 0.25 s)");
    assert!(
        lost <= 0.25 + SLACK_S,
        "{span} s of the take recorded, killed after {killed_after} s"
    );
    // Every sample kept is whole and in time order: each timestamp holds the frame's 8
    // markers. The newest may hold fewer: samples reach the recorder one by one, so a
    // flush can fall inside a frame, and the kill can come before the next.
    assert!(s.samples.windows(2).all(|w| w[0].time_s <= w[1].time_s));
    let frames: Vec<&[_]> = s.samples.chunk_by(|a, b| a.time_s == b.time_s).collect();
    let (newest, whole) = frames.split_last().expect("samples were kept");
    for frame in whole {
        assert_eq!(frame.len(), 8, "a frame at {} s", frame[0].time_s);
    }
    assert!(
        (1..=8).contains(&newest.len()),
        "{} in the newest",
        newest.len()
    );
    assert!(s.samples.len() >= 8 * 120);
}

/// `run --json --rerun save=REL`: the recording lands where the command runs (not in the
/// stage's folder), and the summary is one JSON object with its documented keys.
#[test]
fn run_json_summary_and_a_relative_rerun_file() {
    let stage_dir = tempfile::tempdir().unwrap();
    let cwd = tempfile::tempdir().unwrap();
    let stage = stage_dir.path().join("stage.toml");
    std::fs::write(
        &stage,
        "[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"replay\"\nsession = \"hand_finger_play\"\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .current_dir(cwd.path())
        .args([
            "run",
            "--config",
            stage.to_str().unwrap(),
            "--seconds",
            "0.5",
        ])
        .args(["--json", "--rerun", "save=take.rrd"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        cwd.path().join("take.rrd").is_file(),
        "no take.rrd where the command ran"
    );
    assert!(!stage_dir.path().join("take.rrd").exists());
    let last: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(last["stopped"], "time limit reached", "{last}");
    // 0.5 s at 120 Hz: ticks 0..=60, each solved or (on a loaded machine) skipped and
    // counted; every solved frame logged or, when the sink fell behind, counted.
    let n = |v: &serde_json::Value| v.as_u64().unwrap_or_else(|| panic!("{v} in {last}"));
    let frames = n(&last["summary"]["frames"]);
    assert_eq!(frames + n(&last["summary"]["overruns"]), 61, "{last}");
    let rerun = &last["rerun"];
    assert_eq!(
        n(&rerun["frames_logged"]) + n(&rerun["frames_skipped"]),
        frames
    );
    // The replay sent its frames up to the last tick (8 samples each), give or take one.
    let samples = n(&last["source_samples"]);
    assert!((60 * 8..=62 * 8).contains(&samples), "{last}");
    for key in ["stream", "source_dropped", "inputs", "recorded"] {
        assert!(last.get(key).is_some(), "no {key} in {last}");
    }
}

/// An error is said once: a cause that its parent's message already quotes is not
/// repeated (`info` on a file that is not there printed the OS error twice).
#[test]
fn errors_are_said_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("take.c3d");
    let out = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args(["info", missing.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    assert!(err.contains("take.c3d"), "{err}");
}

/// `demo --actors 2`: the reference client gets both actors' topologies (Ann 0 and Bob 1
/// of 2, each the 10,116-vertex body) and frames of each, every frame checked against
/// its own actor's topology; Bob, who walks in late, ends metres from where Ann does.
#[test]
fn python_client_reads_every_actor_of_a_two_actor_stage() {
    let demo = Daemon::start(&[
        "demo",
        "--actors",
        "2",
        "--seconds",
        "4",
        "--stream",
        "127.0.0.1:0",
        "--viewer",
        "off",
    ]);
    let addr = demo.addr.clone();
    let s = &client_summary(&addr, &["--timeout", "20"]);
    let (ok, lines) = demo.finish();
    assert!(ok, "demo failed: {lines:?}");
    assert_eq!(s["goodbye"], "time limit reached", "{s}");
    for k in [
        "frame_numbers_increasing",
        "vertex_count_matches",
        "marker_count_matches",
        "joint_count_matches",
        "all_finite",
    ] {
        assert_eq!(s[k], true, "{k}: {s}");
    }
    let actors = s["actors"].as_array().unwrap();
    assert_eq!(actors.len(), 2, "{s}");
    for (i, (a, name)) in actors.iter().zip(["Ann", "Bob"]).enumerate() {
        assert_eq!(a["name"], name, "{s}");
        assert_eq!(a["index"], i, "{s}");
        assert_eq!(a["vertex_count"], 10116, "{s}");
        // 4 s at 120 Hz each; the client joins a little late and may skip a few.
        let frames = a["frames"].as_u64().unwrap();
        assert!(
            (240..=481).contains(&frames),
            "{name}: {frames} frames: {s}"
        );
    }
    // Each actor's own frames, not the other's: their paths differ by metres along z
    // (Ann walks from z ≈ 1 m, Bob from z ≈ 8 m back towards her).
    let z = |a: &serde_json::Value, k: &str| a[k][2].as_f64().unwrap();
    assert!(
        (z(&actors[1], "bbox_max") - z(&actors[0], "bbox_max")).abs() > 1.0,
        "{s}"
    );
}
