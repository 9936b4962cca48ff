//! The stream decoders of the clients rigless ships, each in its own language, on
//! messages the Rust codec encoded (they must read them exactly as written) and on 20,000
//! arbitrary mutations of them and arbitrary bytes (they must decode or refuse with their
//! own protocol error, never fail otherwise): the browser viewer's
//! (`src/output/viewer/decode.js`, under Node.js) and the Blender add-on's
//! (`clients/blender/rigless_live/stream.py`, plain Python). Each skips, saying why,
//! when its interpreter is absent.

mod common;

use glam::Vec3;
use rigless::protocol::vertex_stream::{
    encode_frame, encode_goodbye, encode_topology, FrameStatus, StopCode, Topology, WireFrame,
    WirePart,
};
use std::path::Path;
use std::process::Command;

/// Mutated and arbitrary messages each decoder is given.
const CASES: usize = 20_000;

fn topology() -> Topology {
    Topology {
        character: "tri·hand".into(),
        rate_hz: 120.0,
        length_unit: "m".into(),
        up_axis: "+Y".into(),
        handedness: "right".into(),
        vertex_count: 4,
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        marker_names: vec!["tip".into(), "nail".into(), "wrist".into()],
        joint_names: vec!["root".into(), "tip".into()],
        joint_parents: vec![-1, 0],
        parts: vec![
            WirePart {
                name: "skin".into(),
                first_vertex: 0,
                vertex_count: 3,
                first_triangle: 0,
                triangle_count: 1,
            },
            WirePart {
                name: "nail".into(),
                first_vertex: 0,
                vertex_count: 4,
                first_triangle: 1,
                triangle_count: 1,
            },
        ],
        actor: "Bob".into(),
        actor_index: 1,
        actor_count: 2,
    }
}

fn frame(n: u64) -> WireFrame {
    let k = n as f32;
    WireFrame {
        frame: n,
        actor: 1,
        source_time_s: 0.5 * n as f64,
        publish_time_s: 1.7e9 + n as f64 / 120.0,
        status: FrameStatus {
            iterations: 3,
            stop: StopCode::IterationCap,
            solve_ms: 0.75,
            ..FrameStatus::ZERO
        },
        marker_states: vec![0, 1, 3],
        markers_m: vec![Vec3::X * k, Vec3::Y, Vec3::new(0.1, -0.2, 0.3)],
        vertices_m: vec![
            Vec3::new(1.0e-7, 1.5, -2.25),
            Vec3::Y * k,
            Vec3::Z,
            Vec3::splat(f32::MIN_POSITIVE),
        ],
        received_time_s: 1.7e9 + n as f64 / 120.0 - 0.002,
        joints_m: vec![Vec3::ZERO, Vec3::new(0.0, 0.1 * k, 0.0)],
    }
}

/// Writes the messages to `dir/messages.bin` and returns the frames written.
fn write_messages(dir: &Path) -> Vec<WireFrame> {
    let mut b = Vec::new();
    encode_topology(&topology(), &mut b);
    let frames = vec![frame(7), frame(8)];
    for f in &frames {
        encode_frame(&f.view(), &mut b);
    }
    encode_goodbye("session ended", &mut b);
    std::fs::write(dir.join("messages.bin"), b).unwrap();
    frames
}

fn run(program: &str, script: &str, dir: &Path) -> Option<serde_json::Value> {
    if Command::new(program).arg("--version").output().is_err() {
        common::skip_for_missing_peer(&format!("{program} is not installed"));
        return None;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join(script);
    let out = Command::new(program)
        .arg(&script)
        .arg(dir)
        .arg(CASES.to_string())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(serde_json::from_str(stdout.lines().last().expect("a result line")).unwrap())
}

/// f32 values widened to f64, to compare with what a decoder read.
fn floats(v: &[Vec3]) -> Vec<f64> {
    v.iter()
        .flat_map(|p| p.to_array())
        .map(|x| x as f64)
        .collect()
}

/// A JSON array of numbers as f64 (JavaScript prints 7.0 as 7, Python as 7.0).
fn numbers(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap_or_else(|| panic!("an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

fn check(r: &serde_json::Value, frames: &[WireFrame]) {
    let d = &r["decoded"];
    let t = topology();
    assert_eq!(d[0]["character"], t.character.as_str(), "{r}");
    assert_eq!(d[0]["vertexCount"], 4);
    assert_eq!(d[0]["triangles"], serde_json::json!([0, 1, 2, 0, 2, 3]));
    assert_eq!(
        d[0]["markerNames"],
        serde_json::json!(["tip", "nail", "wrist"])
    );
    assert_eq!(d[0]["jointParents"], serde_json::json!([-1, 0]));
    // Version 4: the topology names its actor, its index and the count; frames carry
    // the index.
    assert_eq!(d[0]["actor"], "Bob", "{r}");
    assert_eq!(d[0]["actorIndex"], 1);
    assert_eq!(d[0]["actorCount"], 2);
    for (i, f) in frames.iter().enumerate() {
        let g = &d[1 + i];
        assert_eq!(g["frame"], f.frame, "{r}");
        assert_eq!(g["actor"], f.actor, "{r}");
        assert_eq!(g["publishTime"], f.publish_time_s);
        assert_eq!(g["receivedTime"], f.received_time_s);
        assert_eq!(g["states"], serde_json::json!(f.marker_states));
        // Exactly the f32 values written (each widened to f64 the same way).
        assert_eq!(numbers(&g["vertices"]), floats(&f.vertices_m), "{r}");
        assert_eq!(numbers(&g["joints"]), floats(&f.joints_m), "{r}");
    }
    assert_eq!(d[3]["reason"], "session ended");
    assert_eq!(r["bad_count"], 0, "{r}");
    let (acc, refd) = (
        r["accepted"].as_u64().unwrap(),
        r["refused"].as_u64().unwrap(),
    );
    assert_eq!(acc + refd, CASES as u64, "{r}");
    // Most mutations must be refused (a decoder that accepts anything passes nothing);
    // a changed float or name still decodes, so some are accepted.
    assert!(refd > CASES as u64 / 2 && acc > 0, "{r}");
}

#[test]
fn the_browser_decoder_reads_what_the_codec_writes_and_refuses_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let frames = write_messages(dir.path());
    if let Some(r) = run("node", "tests/browser/decode_check.mjs", dir.path()) {
        check(&r, &frames);
        assert_eq!(r["decoded"][0]["parts"][1]["name"], "nail");
        assert_eq!(r["decoded"][1]["stop"], "iteration cap");
    }
}

#[test]
fn the_blender_decoder_reads_what_the_codec_writes_and_refuses_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let frames = write_messages(dir.path());
    if let Some(r) = run("python3", "tests/blender/decode_check.py", dir.path()) {
        check(&r, &frames);
        assert_eq!(
            r["decoded"][0]["parts"],
            serde_json::json!([["skin", 0, 3, 0, 1], ["nail", 0, 4, 1, 1]])
        );
    }
}
