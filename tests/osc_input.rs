//! The OSC input: golden decodes of the real captures in `../shared/data/osc` (skipped
//! when absent), and live over loopback with a real OSC sender (python-osc, which
//! `.ci/run` installs): into `rigless listen`, and through the daemon to the vertex
//! stream.

use rigless::protocol::osc::OscMapping;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

mod common;

fn capture(name: &str) -> Option<Vec<u8>> {
    common::shared_file(&format!("osc/{name}"))
}

#[test]
fn real_captures_decode() {
    let m = OscMapping::default();
    if let Some(b) = capture("liblo_oscsend_marker.bin") {
        // oscsend localhost PORT /marker/LFHD fff 1.5 -2.25 3
        let f = m.decode(&b).unwrap();
        assert_eq!(f.markers().len(), 1);
        assert_eq!(f.markers()[0].name, "LFHD");
        assert_eq!(f.markers()[0].position_m.to_array(), [1.5, -2.25, 3.0]);
        assert_eq!(f.source_time_s(), None);
    }
    if let Some(b) = capture("pythonosc_bundle_markers.bin") {
        let f = m.decode(&b).unwrap();
        let got: Vec<(&str, [f64; 3])> = f
            .markers()
            .iter()
            .map(|k| (k.name.as_str(), k.position_m.to_array()))
            .collect();
        assert_eq!(got, [("LFHD", [1.0, 2.0, 3.0]), ("RFHD", [4.0, 5.0, 6.0])]);
        // Time tag "immediately": no source time.
        assert_eq!(f.source_time_s(), None);
    }
    if let Some(b) = capture("vmc_bundle_vmcp.bin") {
        let f = m.decode(&b).unwrap();
        assert_eq!(f.markers().len(), 2);
        assert_eq!(f.markers()[0].name, "root");
        assert_eq!(f.markers()[0].position_m.to_array(), [0.0, 1.0, 0.0]);
        // LeftUpperLeg at Unity (0.1, -0.05, 0): right-handed z = -0.
        assert_eq!(f.markers()[1].name, "LeftUpperLeg");
        let p = f.markers()[1].position_m;
        assert!(
            (p - glam::DVec3::new(0.1, -0.05, 0.0)).length() < 1e-7,
            "{p}"
        );
        assert_eq!(f.vmc_time_s, Some(1.5));
        assert_eq!(f.ignored_messages, 1, "/VMC/Ext/OK is read and ignored");
    }
}

fn python_osc() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import pythonosc"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "python-osc is missing: python3 -m pip install python-osc (.ci/run does)"
    );
    ok
}

/// Sends `frames` bundles of the procedural hand's 8 markers (rest positions offset by
/// `dy` metres) from python-osc at 240 Hz: `/rigless/frame` and `/rigless/marker`.
fn send_hand(port: u16, frames: usize, names_and_rest: &[(String, [f64; 3])]) {
    let markers: Vec<String> = names_and_rest
        .iter()
        .map(|(n, p)| format!("({n:?}, {}, {}, {})", p[0], p[1], p[2]))
        .collect();
    let script = format!(
        r#"
import time
from pythonosc.udp_client import SimpleUDPClient
from pythonosc.osc_bundle_builder import OscBundleBuilder, IMMEDIATELY
from pythonosc.osc_message_builder import OscMessageBuilder
c = SimpleUDPClient("127.0.0.1", {port})
markers = [{markers}]
start = time.time()
for i in range({frames}):
    b = OscBundleBuilder(IMMEDIATELY)
    m = OscMessageBuilder("/rigless/frame"); m.add_arg(i); b.add_content(m.build())
    for name, x, y, z in markers:
        m = OscMessageBuilder("/rigless/marker")
        m.add_arg(name); m.add_arg(float(x)); m.add_arg(float(y)); m.add_arg(float(z))
        b.add_content(m.build())
    c.send(b.build())
    delay = start + (i + 1) / 240.0 - time.time()
    if delay > 0:
        time.sleep(delay)
"#,
        markers = markers.join(", ")
    );
    let out = Command::new("python3")
        .args(["-c", &script])
        .output()
        .expect("run python-osc");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn hand_markers() -> Vec<(String, [f64; 3])> {
    rigless::character::demo::demo_hand()
        .markers
        .iter()
        .map(|m| (m.name.clone(), m.rest.to_array()))
        .collect()
}

/// Starts `rigless listen osc://127.0.0.1:PORT --json` on a free port for `packets`
/// packets (30 s at most) and waits until it listens; returns the port and the child.
fn start_listen(packets: usize) -> (u16, std::process::Child) {
    // Pick a free port, then let rigless bind it.
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut listen = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args([
            "listen",
            &format!("osc://127.0.0.1:{port}"),
            "--json",
            "--packets",
            &packets.to_string(),
            "--seconds",
            "30",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for "listening on" on stderr before anything is sent.
    let mut err = BufReader::new(listen.stderr.take().unwrap());
    let mut first = String::new();
    err.read_line(&mut first).unwrap();
    assert!(first.starts_with("listening on"), "{first}");
    (port, listen)
}

/// `rigless listen` on a network URL is listening within 50 ms of its start (it used
/// to mesh the procedural hand first, for a glove's sake: 1.6 s of CPU in which packets
/// sent were lost). Measured from the spawn to its "listening on" line: 3.8 ms here;
/// the bound is the requirement itself.
#[test]
fn listen_binds_its_socket_at_once() {
    let start = std::time::Instant::now();
    let (_, mut listen) = start_listen(1);
    let took = start.elapsed();
    listen.kill().unwrap();
    listen.wait().unwrap();
    println!("listening {took:?} after the spawn");
    assert!(took < std::time::Duration::from_millis(50), "{took:?}");
}

#[test]
fn listen_receives_every_packet_from_a_real_sender() {
    if !python_osc() {
        return;
    }
    let (port, listen) = start_listen(240);
    // The issue's target: 50 markers a frame at 240 Hz (the hand's 8 and 42 more).
    let mut markers = hand_markers();
    for k in 0..42 {
        markers.push((format!("M{k:02}"), [0.01 * k as f64, 1.0, -0.5]));
    }
    send_hand(port, 240, &markers);
    let out = listen.wait_with_output().unwrap();
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // One second at 240 Hz, 50 markers a packet, on loopback: nothing lost.
    assert_eq!(lines.len(), 240);
    for (i, l) in lines.iter().enumerate() {
        assert_eq!(l["frame"], i as i64);
        let ms = l["markers"].as_array().unwrap();
        assert_eq!(ms.len(), 50);
        assert_eq!(ms[49]["name"], "M41");
        assert_eq!(ms[0]["name"], markers[0].0.as_str());
        let p: Vec<f64> = ms[0]["position_m"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        // f32 on the wire.
        for (got, want) in p.iter().zip(markers[0].1) {
            assert!((got - want).abs() < 1e-6);
        }
    }
}

/// A stage with an OSC input, in-process on the system clock, fed by python-osc (a real
/// sender, a separate process) with the hand's markers at rest: the samples reach the
/// loop, and the solved frame is the hand at rest ([`common::assert_hand_at_rest`]), so
/// each marker arrived under its own name, in metres, on its own axes.
#[test]
fn the_daemon_solves_what_a_real_osc_sender_sends() {
    use rigless::daemon::stage::{Stage, StartOptions};
    use rigless::runtime::slot::LatestSlot;
    use std::sync::Arc;
    if !python_osc() {
        return;
    }
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let cfg = rigless::config::parse_stage(
        &format!("[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"osc\"\nurl = \"osc://127.0.0.1:{port}\"\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n"),
        "osc stage",
    )
    .unwrap();
    let frames = Arc::new(LatestSlot::new());
    let stage = Stage::start_with(
        &cfg,
        std::path::Path::new("."),
        Arc::new(rigless::runtime::clock::SystemClock::new()),
        StartOptions {
            stop_after_secs: Some(4.0),
            frames: Some(Arc::clone(&frames)),
            ..StartOptions::default()
        },
    )
    .unwrap();
    // 480 bundles at 240 Hz: 2 s, the interpreter's start included within the 4 s.
    let markers = hand_markers();
    send_hand(port, 480, &markers);
    let summary = stage.join().unwrap();
    let last = frames.take().expect("frames were solved");
    // 8 markers a bundle; a tenth lost would still leave this (loopback UDP loses none
    // on an idle machine).
    assert!(summary.source_samples >= 480 * 8 * 9 / 10, "{summary:?}");
    common::assert_hand_at_rest(&last);
}

/// liblo's `oscsend` (Debian's liblo-tools, which `.ci/run` installs), one message per
/// run as a stage's existing sender would send it: `/marker/NAME fff` and
/// `/mocap/NAME fff`, read by `rigless listen` with their values.
#[test]
fn listen_decodes_what_liblo_oscsend_sends() {
    let have = Command::new("oscsend")
        .output()
        .is_ok_and(|o| !o.stderr.is_empty() || !o.stdout.is_empty());
    assert!(
        have,
        "liblo's oscsend is missing: apt-get install liblo-tools (.ci/run does)"
    );
    let sends: Vec<(String, [f32; 3])> = (0..20)
        .map(|i| {
            let name = if i % 2 == 0 {
                "/marker/LFHD"
            } else {
                "/mocap/RWRA"
            };
            let f = i as f32;
            (name.to_owned(), [0.125 * f, -1.5 + f, 1e-3 * f])
        })
        .collect();
    let (port, listen) = start_listen(sends.len());
    for (addr, p) in &sends {
        let out = Command::new("oscsend")
            .args(["127.0.0.1", &port.to_string(), addr, "fff"])
            .args(p.map(|v| v.to_string()))
            .output()
            .expect("run oscsend");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        // Loopback keeps order; the pause only keeps the processes apart.
        std::thread::sleep(Duration::from_millis(5));
    }
    let out = listen.wait_with_output().unwrap();
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), sends.len());
    for (l, (addr, p)) in lines.iter().zip(&sends) {
        let ms = l["markers"].as_array().unwrap();
        assert_eq!(ms.len(), 1);
        assert_eq!(ms[0]["name"], addr.rsplit('/').next().unwrap());
        // A lone message has no time tag.
        assert!(l["source_time_s"].is_null());
        let got: Vec<f64> = serde_json::from_value(ms[0]["position_m"].clone()).unwrap();
        // f32 on the wire: exact once narrowed back (JSON may round the widened value's
        // last bit).
        let got: Vec<f32> = got.iter().map(|&v| v as f32).collect();
        assert_eq!(got, p.to_vec());
    }
}
