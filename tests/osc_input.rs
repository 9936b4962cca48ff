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

#[test]
fn listen_receives_every_packet_from_a_real_sender() {
    if !python_osc() {
        return;
    }
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
            "240",
            "--seconds",
            "30",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for "listening on" on stderr before sending.
    let mut err = BufReader::new(listen.stderr.take().unwrap());
    let mut first = String::new();
    err.read_line(&mut first).unwrap();
    assert!(first.starts_with("listening on"), "{first}");
    let markers = hand_markers();
    send_hand(port, 240, &markers);
    let out = listen.wait_with_output().unwrap();
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // One second at 240 Hz, 8 markers a packet, on loopback: nothing lost.
    assert_eq!(lines.len(), 240);
    for (i, l) in lines.iter().enumerate() {
        assert_eq!(l["frame"], i as i64);
        let ms = l["markers"].as_array().unwrap();
        assert_eq!(ms.len(), 8);
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

#[test]
fn the_daemon_solves_what_a_real_osc_sender_sends() {
    if !python_osc() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("stage.toml");
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    std::fs::write(
        &stage,
        format!("[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"osc\"\nurl = \"osc://127.0.0.1:{port}\"\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n"),
    )
    .unwrap();
    let daemon =
        common::Daemon::start(&["run", "--config", stage.to_str().unwrap(), "--seconds", "6"]);
    let addr = daemon.addr.clone();
    let markers = hand_markers();
    let sender = std::thread::spawn(move || send_hand(port, 480, &markers));
    std::thread::sleep(Duration::from_millis(500));
    // A client reads 60 frames while the sender runs: every marker measured, the mesh at
    // rest (the markers are at their rest positions).
    let s = &common::client_summary(&addr, &["--frames", "60"]);
    sender.join().unwrap();
    assert_eq!(s["frames"], 60);
    let measured = s["fill_counts"]["measured"].as_u64().unwrap();
    assert!(measured >= 60 * 8 - 8, "{}", s["fill_counts"]);
    let (_, lines) = daemon.finish();
    assert!(lines.iter().any(|l| l.starts_with("done (")), "{lines:?}");
}
