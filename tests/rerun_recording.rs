//! The Rerun sink: `rigless demo --rerun save=PATH` writes a `.rrd` that Rerun's own
//! tooling (the Python SDK of the same version, 0.36.3, which `.ci/run` installs) reads
//! back with the expected entities, frames and markers.

use rigless::config::parse_stage;
use rigless::daemon::stage::{Stage, StartOptions};
use rigless::runtime::clock::ManualClock;
use std::process::Command;
use std::sync::Arc;

mod common;

/// Reads an `.rrd` with rerun-sdk's `RrdReader` and prints, as JSON: rows per entity
/// path, the timelines, the largest marker count in one row, the iterations logged, the
/// scalars of the input series and their frames, the edge count of each control-mesh row, and the names of
/// the blueprint's views.
const READER: &str = r#"
import json, sys
import rerun as rr
from rerun.experimental import RrdReader
reader = RrdReader(sys.argv[1])
rows, timelines, markers, iterations, conv_timelines = {}, set(), 0, [], set()
inputs, input_frames, control_edges, mesh_colors, tied = {}, {}, [], [], []
for chunk in reader.stream():
    path = str(chunk.entity_path)
    rows[path] = rows.get(path, 0) + chunk.num_rows
    timelines.update(chunk.timeline_names)
    if path == "/solver/convergence":
        conv_timelines.update(chunk.timeline_names)
    batch = chunk.to_record_batch()
    for name in batch.schema.names:
        col = None
        if path.startswith("/character/") and path.endswith("/markers") and name.endswith("Points3D:positions"):
            col = batch.column(name).to_pylist()
            markers = max([markers] + [len(v or []) for v in col])
        if path == "/solver/iterations" and name.endswith("Scalars:scalars"):
            iterations += [v[0] for v in batch.column(name).to_pylist() if v]
        if path.startswith("/inputs/") and name.endswith("Scalars:scalars"):
            inputs.setdefault(path, []).extend(
                v[0] for v in batch.column(name).to_pylist() if v)
        if path.startswith("/inputs/") and name == "frame":
            input_frames.setdefault(path, []).extend(batch.column(name).to_pylist())
        if path == "/character/control_mesh" and name.endswith("LineStrips3D:strips"):
            control_edges += [len(v or []) for v in batch.column(name).to_pylist()]
        if path == "/character/mesh" and name.endswith("Mesh3D:vertex_colors"):
            mesh_colors += [(len(v), len(set(v))) for v in batch.column(name).to_pylist() if v]
        if path == "/character/correspondences" and name.endswith("Points3D:positions"):
            tied += [len(v) for v in batch.column(name).to_pylist() if v]
views = []
for store in reader.blueprints():
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name.endswith("ViewBlueprint:display_name"):
                views += [v[0] for v in batch.column(name).to_pylist() if v]
print(json.dumps({"version": rr.__version__, "rows": rows, "timelines": sorted(timelines),
                  "markers": markers, "iterations": iterations,
                  "convergence_timelines": sorted(conv_timelines), "inputs": inputs,
                  "input_frames": input_frames,
                  "control_edges": control_edges, "views": sorted(views),
                  "mesh_colors": mesh_colors, "tied": tied}))
"#;

/// Runs `rigless ARGS` to completion and returns its stdout and the number of frames its
/// summary says went to Rerun.
fn run_rigless(args: &[&str]) -> (String, u64) {
    let out = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args(args)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let logged: u64 = stdout
        .lines()
        .find_map(|l| {
            l.strip_prefix("rerun: ")?
                .split(" frames logged")
                .next()?
                .parse()
                .ok()
        })
        .unwrap_or_else(|| panic!("no rerun summary in {stdout}"));
    (stdout, logged)
}

/// Runs the procedural hand fed by the bundled finger-play session for `seconds`, with
/// `extra` TOML appended to `[outputs.rerun]` (whose target is a file) and `solver`
/// TOML in `[solver]`; returns what [`READER`] reads back and the frames logged.
fn run_hand_stage(solver: &str, extra: &str, seconds: &str) -> (serde_json::Value, u64) {
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("stage.toml");
    std::fs::write(
        &stage,
        format!("[character]\nprocedural = \"hand\"\n\n[solver]\n{solver}\n\n[[inputs]]\ntype = \"replay\"\nsession = \"hand_finger_play\"\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n\n[outputs.rerun]\ntarget = \"save=stage.rrd\"\n{extra}\n"),
    )
    .unwrap();
    let (_, logged) = run_rigless(&[
        "run",
        "--config",
        stage.to_str().unwrap(),
        "--seconds",
        seconds,
    ]);
    (read_back(&dir.path().join("stage.rrd")), logged)
}

/// What [`READER`] says about `rrd`.
fn read_back(rrd: &std::path::Path) -> serde_json::Value {
    let read = Command::new("python3")
        .args(["-c", READER, rrd.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        read.status.success(),
        "{}",
        String::from_utf8_lossy(&read.stderr)
    );
    serde_json::from_slice(&read.stdout).unwrap()
}

fn rerun_sdk() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import rerun; assert rerun.__version__ == '0.36.3'"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "rerun-sdk 0.36.3 is missing: python3 -m pip install rerun-sdk==0.36.3 (.ci/run does)"
    );
    ok
}

#[test]
fn demo_saves_a_recording_that_rerun_reads_back() {
    if !rerun_sdk() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let rrd = dir.path().join("demo.rrd");
    let (_, logged) = run_rigless(&[
        "demo",
        "--seconds",
        "2",
        "--stream",
        "127.0.0.1:0",
        "--rerun",
        &format!("save={}", rrd.display()),
    ]);
    // 2 s at 120 Hz; the sink may skip frames it could not keep up with (counted).
    assert!(logged >= 60, "{logged} frames logged");
    let v = read_back(&rrd);
    let rows = |p: &str| v["rows"][p].as_u64().unwrap_or(0);
    // Every logged frame has its mesh (mesh_every = 1; its triangles once more, static),
    // markers, skeleton and series.
    assert_eq!(rows("/character/mesh"), logged + 1, "{v}");
    for path in [
        "/character/markers",
        "/character/skeleton",
        "/solver/iterations",
        "/solver/solve_ms",
        "/solver/volume_error",
        "/solver/untangle_projections",
        "/markers/measured",
    ] {
        assert_eq!(rows(path), logged, "{path}: {v}");
    }
    // Ours, the convergence's `iteration`, and the SDK's own log_time.
    assert_eq!(
        v["timelines"],
        serde_json::json!(["frame", "iteration", "log_time", "time"]),
        "{v}"
    );
    // Only the convergence trace is on the iteration timeline.
    assert_eq!(
        v["convergence_timelines"],
        serde_json::json!(["frame", "iteration", "log_time", "time"]),
        "{v}"
    );
    // The hand's 8 markers (all present at some frame of the bundled session).
    assert_eq!(v["markers"], 8, "{v}");
    // Iterations as the solver reported them: small whole numbers.
    let its: Vec<f64> = serde_json::from_value(v["iterations"].clone()).unwrap();
    assert_eq!(its.len() as u64, logged);
    assert!(
        its.iter()
            .all(|i| i.fract() == 0.0 && (0.0..=30.0).contains(i)),
        "{its:?}"
    );
    // Each frame's convergence trace holds the criterion after each of its local steps:
    // one more than its iterations (the first step comes before any), at most the
    // trace's 32. A trace logged for the wrong frame or cut short changes the sum.
    let traced: u64 = its.iter().map(|i| (*i as u64 + 1).min(32)).sum();
    assert_eq!(rows("/solver/convergence"), traced, "{v}");
    // The default blueprint: the 3D view and the plots.
    assert_eq!(
        v["views"],
        serde_json::json!([
            "character",
            "convergence",
            "inputs",
            "markers",
            "quality",
            "timing"
        ]),
        "{v}"
    );
    // No control mesh unless asked for.
    assert_eq!(rows("/character/control_mesh"), 0, "{v}");
}

/// A stage asking for the control mesh every 4th frame, fed by the bundled session
/// (120 Hz): the wireframe comes with the mesh, with the same edges each time, and the
/// input's series is there (its values are exact on a manual clock, below).
#[test]
fn stage_logs_the_control_mesh_and_the_input_series() {
    if !rerun_sdk() {
        return;
    }
    let (v, logged) = run_hand_stage("", "mesh_every = 4\ncontrol_mesh = true", "2");
    assert!(logged >= 60, "{logged} frames logged");
    let rows = |p: &str| v["rows"][p].as_u64().unwrap_or(0);
    // Frames 0, 4, 8, ..., 240: at most those 61 (the sink skips frames when the
    // machine is busy, and the skipped ones may be any), and at least 60 less what the
    // sink skipped.
    let meshes = rows("/character/mesh") - 1;
    assert!(
        meshes <= 240 / 4 + 1 && meshes >= (240 / 4u64).saturating_sub(240 - logged.min(240)),
        "{meshes} of {logged}"
    );
    assert_eq!(rows("/character/control_mesh"), meshes, "{v}");
    let edges: Vec<u64> = serde_json::from_value(v["control_edges"].clone()).unwrap();
    // The hand's control mesh has thousands of edges, the same ones every time.
    assert!(
        edges[0] > 1000 && edges.iter().all(|e| *e == edges[0]),
        "{edges:?}"
    );
    // A window every 30 ticks of the 241 (frames the sink skipped lose none): 8, or
    // fewer if the loop itself fell behind and skipped ticks on this busy machine.
    let rate: Vec<f64> =
        serde_json::from_value(v["inputs"]["/inputs/0_replay/packet_rate_hz"].clone()).unwrap();
    let gap: Vec<f64> =
        serde_json::from_value(v["inputs"]["/inputs/0_replay/gap_ms"].clone()).unwrap();
    assert!(
        (6..=8).contains(&rate.len()) && gap.len() == rate.len(),
        "{v}"
    );
}

/// The input series of a whole stage in-process on a manual clock (run as fast as it
/// computes, the Rerun sink skipping frames as it must): the bundled session replayed at
/// full and at half speed reads exactly 120 and 60 Hz, with gaps of one of its frames
/// (8.3 and 16.7 ms), in every quarter-second window: one point each at frames 30, 60,
/// ..., 240 of the 241 ticks (120 Hz, both speeds).
#[test]
fn the_input_series_is_exact_on_a_manual_clock() {
    if !rerun_sdk() {
        return;
    }
    for (speed, rate_hz) in [(1.0, 120.0), (0.5, 60.0)] {
        let dir = tempfile::tempdir().unwrap();
        let rrd = dir.path().join("stage.rrd");
        let text = format!(
            "[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"replay\"\nsession = \"hand_finger_play\"\nspeed = {speed}\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n\n[outputs.rerun]\ntarget = \"save={}\"\n",
            rrd.display()
        );
        let cfg = parse_stage(&text, "test stage").unwrap();
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
        let summary = stage.join().unwrap();
        assert_eq!(summary.status.frames, 241);
        let v = read_back(&rrd);
        let series = |name: &str| -> Vec<f64> {
            serde_json::from_value(v["inputs"][format!("/inputs/0_replay/{name}")].clone())
                .unwrap_or_else(|e| panic!("{name}: {e} in {v}"))
        };
        let (rate, gap) = (series("packet_rate_hz"), series("gap_ms"));
        // The windows' spans are sums of floating-point tick times: 1e-6 of rounding.
        assert_eq!(rate.len(), 8, "{v}");
        assert!(rate.iter().all(|r| (r - rate_hz).abs() < 1e-6), "{rate:?}");
        assert_eq!(gap.len(), 8, "{v}");
        assert!(
            gap.iter().all(|g| (g - 1e3 / rate_hz).abs() < 1e-6),
            "{gap:?}"
        );
        let frames: Vec<i64> =
            serde_json::from_value(v["input_frames"]["/inputs/0_replay/packet_rate_hz"].clone())
                .unwrap();
        assert_eq!(frames, (1..=8).map(|k| k * 30).collect::<Vec<i64>>(), "{v}");
    }
}

/// The harmonic method with `harmonic_field = true`: the mesh frames carry one colour
/// per vertex (the field's angle), varied over the moving hand, and the correspondences
/// come as points, the same number each time.
#[test]
fn harmonic_stage_logs_its_rotation_field() {
    if !rerun_sdk() {
        return;
    }
    let (v, logged) = run_hand_stage(
        "method = \"harmonic\"",
        "mesh_every = 8\nharmonic_field = true",
        "1.5",
    );
    assert!(logged >= 45, "{logged} frames logged");
    let rows = |p: &str| v["rows"][p].as_u64().unwrap_or(0);
    let meshes = rows("/character/mesh") - 1;
    assert!(meshes >= 3, "{v}");
    // Positions per mesh frame, colours static once: one more row.
    assert_eq!(rows("/character/correspondences"), meshes + 1, "{v}");
    let colors: Vec<(u64, u64)> = serde_json::from_value(v["mesh_colors"].clone()).unwrap();
    assert_eq!(colors.len() as u64, meshes, "{v}");
    // The hand's 5,001 vertices each get a colour; a curling hand's field takes many
    // (all but the first frame, which may come before the first sample: the rest pose,
    // one colour).
    assert!(colors.iter().all(|&(n, _)| n == 5001), "{colors:?}");
    let varied = colors
        .iter()
        .filter(|&&(_, distinct)| distinct > 50)
        .count();
    assert!(varied + 1 >= colors.len(), "{colors:?}");
    let tied: Vec<u64> = serde_json::from_value(v["tied"].clone()).unwrap();
    assert!(
        tied.len() as u64 == meshes && tied.iter().all(|n| *n == tied[0] && *n > 500),
        "{tied:?}"
    );
}

/// `rigless replay FILE --solve hand --end 1.5 --rerun save=...` solves a recording
/// file through the pipeline and records it.
#[test]
fn replay_solves_a_recording_into_rerun() {
    if !rerun_sdk() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args(["make-sessions", dir.path().to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success());
    let rrd = dir.path().join("replay.rrd");
    let (stdout, logged) = run_rigless(&[
        "replay",
        dir.path().join("hand_finger_play.c3d").to_str().unwrap(),
        "--solve",
        "hand",
        "--stream",
        "127.0.0.1:0",
        "--end",
        "1.5",
        "--rerun",
        &format!("save={}", rrd.display()),
    ]);
    // 1.5 s at 120 Hz: 180 ticks; the stop lands between two ticks, so one either way.
    let frames: u64 = stdout
        .lines()
        .find_map(|l| {
            l.strip_prefix("done (time limit reached): ")?
                .split(" frames")
                .next()?
                .parse()
                .ok()
        })
        .unwrap_or_else(|| panic!("no summary in {stdout}"));
    assert!((179..=181).contains(&frames), "{frames} frames: {stdout}");
    assert!(logged >= 45, "{logged} frames logged");
    let v = read_back(&rrd);
    let rows = |p: &str| v["rows"][p].as_u64().unwrap_or(0);
    assert_eq!(rows("/character/markers"), logged, "{v}");
    assert_eq!(v["markers"], 8, "{v}");
    assert!(rows("/inputs/0_replay/packet_rate_hz") >= 5, "{v}");
}

/// The two-actor demo logs each actor under its own paths (`character/Ann/...`,
/// `solver/Bob/...`), each with its own 36 markers, and nothing under the one-actor
/// paths; the frames logged are both actors' (each frame one actor's).
#[test]
fn two_actors_log_under_their_own_paths() {
    if !rerun_sdk() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let rrd = dir.path().join("two.rrd");
    let (_, logged) = run_rigless(&[
        "demo",
        "--actors",
        "2",
        "--seconds",
        "2",
        "--stream",
        "127.0.0.1:0",
        "--viewer",
        "off",
        "--rerun",
        &format!("save={}", rrd.display()),
    ]);
    let v = read_back(&rrd);
    let rows = |p: &str| v["rows"][p].as_u64().unwrap_or(0);
    let mut each = 0;
    for actor in ["Ann", "Bob"] {
        // Each actor's frames: its mesh (plus the static triangles), markers, skeleton
        // and series, row for row; 2 s at 120 Hz, less what the sink skipped.
        let meshes = rows(&format!("/character/{actor}/mesh")) - 1;
        assert!(meshes >= 60, "{actor}: {v}");
        for path in ["markers", "skeleton"] {
            assert_eq!(rows(&format!("/character/{actor}/{path}")), meshes, "{v}");
        }
        for path in ["solver/{a}/solve_ms", "markers/{a}/measured"] {
            let path = format!("/{}", path.replace("{a}", actor));
            assert_eq!(rows(&path), meshes, "{path}: {v}");
        }
        each += meshes;
    }
    assert_eq!(each, logged, "{v}");
    // The body's 36 markers in an actor's row, never both actors' 72 in one.
    assert_eq!(v["markers"], 36, "{v}");
    for path in ["/character/mesh", "/character/markers", "/solver/solve_ms"] {
        assert_eq!(rows(path), 0, "{path}: {v}");
    }
}
