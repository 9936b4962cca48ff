//! Helpers shared by the integration tests.

#![allow(dead_code)] // each test binary uses its own subset

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

/// The shared data folder beside the checkout: real recordings, meshes and captures
/// from other people's systems, which the project does not ship.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
}

/// A path under the shared data folder, or `None` when it is absent: the test then
/// skips, printing why; with `RIGLESS_REQUIRE_SHARED_DATA` set (`.ci/run` sets it when
/// the folder is there) an absent file is a failure instead.
pub fn shared_path(rel: &str) -> Option<PathBuf> {
    let p = shared_dir().join(rel);
    if p.exists() {
        return Some(p);
    }
    let why = format!(
        "{} is absent (the shared test data is not part of this repository)",
        p.display()
    );
    if std::env::var_os("RIGLESS_REQUIRE_SHARED_DATA").is_some() {
        panic!("{why}; RIGLESS_REQUIRE_SHARED_DATA is set");
    }
    eprintln!("skipped: {why}");
    None
}

/// A file of the shared data folder read whole, or `None` as [`shared_path`].
pub fn shared_file(rel: &str) -> Option<Vec<u8>> {
    let p = shared_path(rel)?;
    Some(std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
}

/// Bounded wait for the demo to print its stream address (binding the hand takes about a
/// second; a loaded CI machine may take several).
pub const STARTUP_TIMEOUT: Duration = Duration::from_secs(60);

/// A running `rigless` with its stdout collected on a thread, and the stream address it
/// printed.
pub struct Daemon {
    pub child: std::process::Child,
    pub addr: String,
    pub lines: std::thread::JoinHandle<Vec<String>>,
}

impl Daemon {
    pub fn start(args: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_rigless"))
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start rigless");
        let stdout = child.stdout.take().unwrap();
        let (addr_tx, addr_rx) = std::sync::mpsc::channel();
        let lines = std::thread::spawn(move || {
            let mut lines = Vec::new();
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if let Some(a) = line.strip_prefix("vertex stream listening on tcp://") {
                    let _ = addr_tx.send(a.to_owned());
                }
                lines.push(line);
            }
            lines
        });
        let Ok(addr) = addr_rx.recv_timeout(STARTUP_TIMEOUT) else {
            let _ = child.kill();
            panic!("rigless {args:?} printed no stream address within {STARTUP_TIMEOUT:?}");
        };
        Self { child, addr, lines }
    }

    /// Waits for the exit; returns whether it succeeded and everything it printed.
    pub fn finish(mut self) -> (bool, Vec<String>) {
        let ok = self.child.wait().expect("rigless exits").success();
        (ok, self.lines.join().unwrap())
    }
}

/// Runs the Python reference client against `addr` with extra arguments.
pub fn python_client(addr: &str, args: &[&str]) -> std::process::Output {
    Command::new("python3")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/protocols/vertex_stream_client.py"
        ))
        .arg(addr)
        .args(args)
        .output()
        .expect("run the Python client")
}

/// Runs the Python reference client against `addr` and returns its JSON `summary`
/// (panicking with the client's error output if it failed).
pub fn client_summary(addr: &str, args: &[&str]) -> serde_json::Value {
    let out = python_client(addr, args);
    assert!(
        out.status.success(),
        "client failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).expect("UTF-8 output");
    let v: serde_json::Value = serde_json::from_str(text.trim()).expect("client JSON");
    v["summary"].clone()
}

/// Log lines written through `tracing` while [`Self::subscriber`] was the default
/// (plain text, one event a line), for tests that count what a component says.
#[derive(Clone, Default)]
pub struct LogCapture(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl LogCapture {
    /// A subscriber that writes every event at `max_level` or above here.
    pub fn subscriber(&self, max_level: tracing::Level) -> impl tracing::Subscriber + Send + Sync {
        let me = self.clone();
        tracing_subscriber::fmt()
            .with_ansi(false)
            .with_max_level(max_level)
            .with_writer(move || me.clone())
            .finish()
    }

    /// The lines so far.
    pub fn lines(&self) -> Vec<String> {
        String::from_utf8_lossy(&self.0.lock().unwrap())
            .lines()
            .map(str::to_owned)
            .collect()
    }

    /// The lines so far at level `level` ("WARN", "INFO", ...) that contain `text`.
    pub fn count(&self, level: &str, text: &str) -> usize {
        self.lines()
            .iter()
            .filter(|l| l.contains(level) && l.contains(text))
            .count()
    }
}

impl std::io::Write for LogCapture {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// A small topology (no rig needed) for the stream server tests: one triangle, two
/// markers, one joint, one part.
pub fn tiny_topology() -> rigless::protocol::vertex_stream::Topology {
    rigless::protocol::vertex_stream::Topology {
        character: "tiny".into(),
        rate_hz: 100.0,
        length_unit: "m".into(),
        up_axis: "+Y".into(),
        handedness: "right".into(),
        vertex_count: 3,
        triangles: vec![[0, 1, 2]],
        marker_names: vec!["A".into(), "B".into()],
        joint_names: vec!["root".into()],
        joint_parents: vec![-1],
        parts: vec![rigless::protocol::vertex_stream::WirePart {
            name: "tiny".into(),
            first_vertex: 0,
            vertex_count: 3,
            first_triangle: 0,
            triangle_count: 1,
        }],
        actor: "tiny".into(),
        actor_index: 0,
        actor_count: 1,
    }
}

/// Solver tolerances at round-off, for the invariants that must hold exactly (a rigid
/// motion moves every vertex rigidly).
pub fn tight_solver_params() -> rigless::solve::frame::SolverParams {
    let mut p = rigless::solve::frame::SolverParams {
        max_iterations: 200,
        tolerance: 1e-12,
        ..rigless::solve::frame::SolverParams::default()
    };
    p.ik.step_tolerance_rad = 1e-13;
    p.ik.cost_tolerance = 0.0;
    p
}

/// Runs `program SCRIPT RIGLESS_BINARY OUT_DIR` (a check written in another language that
/// drives rigless as a user would), bounded by `timeout`, and returns the JSON object it
/// prints on its last line; panics with what it printed when it fails or overruns.
pub fn run_json_check(
    program: &str,
    script: &str,
    out_dir: &std::path::Path,
    timeout: Duration,
) -> serde_json::Value {
    run_json_check_with(program, script, out_dir, &[], timeout)
}

/// [`run_json_check`] with `extra` arguments after the output folder.
#[allow(dead_code)]
pub fn run_json_check_with(
    program: &str,
    script: &str,
    out_dir: &std::path::Path,
    extra: &[&str],
    timeout: Duration,
) -> serde_json::Value {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(script);
    let mut child = Command::new(program)
        .arg(&script)
        .arg(env!("CARGO_BIN_EXE_rigless"))
        .arg(out_dir)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{program} {}: {e}", script.display()));
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > timeout {
            child.kill().unwrap();
            panic!("{} took more than {timeout:?}", script.display());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let output = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}\n{stdout}");
    let line = stdout.lines().last().expect("a result line");
    println!("{line}");
    serde_json::from_str(line).unwrap_or_else(|e| panic!("{e}: {line}"))
}

/// A real peer a test needs (a browser, Blender, an interpreter) is absent: with
/// `RIGLESS_REQUIRE_PEERS` set (`.ci/run` sets it, after installing them) that is a
/// failure; otherwise the test skips, printing why.
pub fn skip_for_missing_peer(why: &str) {
    if std::env::var_os("RIGLESS_REQUIRE_PEERS").is_some() {
        panic!("{why} (RIGLESS_REQUIRE_PEERS is set: .ci/run should have installed it)");
    }
    eprintln!("skipped: {why}");
}

/// The procedural hand's solved frame is its rest pose: every marker where the hand
/// carries it (1e-5 m: sent as f64, read back as the stream's f32) and every vertex
/// within 0.5 mm of rest (the solver stops at a relative change of 1e-3, a few
/// micrometres from the exact rest pose on this 20 cm hand). Markers fed to the wrong
/// slots, in the wrong units or axes, move the mesh by centimetres. Returns the largest
/// vertex distance, metres.
pub fn assert_hand_at_rest(frame: &rigless::output::frame::DeformedFrame) -> f64 {
    let hand = rigless::character::demo::demo_hand();
    for (k, m) in hand.markers.iter().enumerate() {
        let d = (frame.markers_m[k].as_dvec3() - m.rest).length();
        assert!(
            d < 1e-5,
            "marker {} is {d} m from its rest position",
            m.name
        );
    }
    let worst = frame
        .vertices_m
        .iter()
        .zip(&hand.vertices)
        .map(|(v, r)| (v.as_dvec3() - *r).length())
        .fold(0.0, f64::max);
    println!(
        "largest vertex distance from the rest pose: {:.4} mm",
        worst * 1e3
    );
    assert!(worst < 5e-4, "the hand is {worst} m from its rest pose");
    worst
}

/// A vertex-stream server on loopback (TCP and WebSocket, with the viewer page) serving
/// the tiny topology to at most `max_clients`, fed from `slot`.
pub fn loopback_stream(
    max_clients: usize,
    slot: &std::sync::Arc<
        rigless::runtime::slot::LatestSlot<rigless::output::frame::DeformedFrame>,
    >,
) -> rigless::output::stream::StreamServer {
    let loopback: std::net::SocketAddr = "127.0.0.1:0".parse().unwrap();
    rigless::output::stream::StreamServer::start(
        &rigless::output::config::StreamOutputConfig {
            tcp: Some(loopback),
            websocket: Some(loopback),
            max_clients,
            viewer: true,
            websocket_any_port_if_taken: false,
        },
        &[tiny_topology()],
        vec![std::sync::Arc::clone(slot)],
    )
    .unwrap()
}
