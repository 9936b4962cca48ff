//! The Rerun sink: `rigless demo --rerun save=PATH` writes a `.rrd` that Rerun's own
//! tooling (the Python SDK of the same version, 0.36.3, which `.ci/run` installs) reads
//! back with the expected entities, frames and markers.

use std::process::Command;

mod common;

/// Reads an `.rrd` with rerun-sdk's `RrdReader` and prints, as JSON: rows per entity
/// path, the timelines, the largest marker count in one row, and the iterations logged.
const READER: &str = r#"
import json, sys
import rerun as rr
from rerun.experimental import RrdReader
rows, timelines, markers, iterations, conv_timelines = {}, set(), 0, [], set()
for chunk in RrdReader(sys.argv[1]).stream():
    path = str(chunk.entity_path)
    rows[path] = rows.get(path, 0) + chunk.num_rows
    timelines.update(chunk.timeline_names)
    if path == "/solver/convergence":
        conv_timelines.update(chunk.timeline_names)
    batch = chunk.to_record_batch()
    for name in batch.schema.names:
        if path == "/character/markers" and name.endswith("Points3D:positions"):
            col = batch.column(name).to_pylist()
            markers = max([markers] + [len(v or []) for v in col])
        if path == "/solver/iterations" and name.endswith("Scalars:scalars"):
            col = batch.column(name).to_pylist()
            iterations += [v[0] for v in col if v]
print(json.dumps({"version": rr.__version__, "rows": rows, "timelines": sorted(timelines),
                  "markers": markers, "iterations": iterations,
                  "convergence_timelines": sorted(conv_timelines)}))
"#;

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
    let out = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args([
            "demo",
            "--seconds",
            "2",
            "--stream",
            "127.0.0.1:0",
            "--rerun",
            &format!("save={}", rrd.display()),
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The summary says how many frames went to Rerun.
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
    // 2 s at 120 Hz; the sink may skip frames it could not keep up with (counted).
    assert!(logged >= 60, "{logged} frames logged");
    let read = Command::new("python3")
        .args(["-c", READER, rrd.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        read.status.success(),
        "{}",
        String::from_utf8_lossy(&read.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&read.stdout).unwrap();
    let rows = |p: &str| v["rows"][p].as_u64().unwrap_or(0);
    // Every logged frame has its mesh (mesh_every = 1), markers, skeleton and series.
    for path in [
        "/character/mesh",
        "/character/markers",
        "/character/skeleton",
        "/solver/iterations",
        "/solver/solve_ms",
        "/solver/volume_error",
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
}
