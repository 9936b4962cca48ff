//! A stage with a VRPN input end to end: a loopback VRPN server streams the procedural
//! hand's markers as sensors of one tracker; the daemon maps sensors to markers by its
//! config, solves, and the Python client reads frames with every marker measured.

use rigless::protocol::vrpn::{
    cookie, description_payload, encode_message, encode_pos_quat, PosQuat, POS_QUAT,
    SENDER_DESCRIPTION, TYPE_DESCRIPTION,
};
use std::io::Write;
use std::time::{Duration, Instant};

mod common;

#[test]
fn a_vrpn_tracker_drives_the_daemon() {
    let markers: Vec<(String, glam::DVec3)> = rigless::character::demo::demo_hand()
        .markers
        .iter()
        .map(|m| (m.name.clone(), m.rest))
        .collect();
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let sent = markers.clone();
    // The server: descriptions, then 8 sensors at 120 Hz for up to 8 s (until the client
    // hangs up).
    let server = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        let mut out = cookie().to_vec();
        encode_message(
            &mut out,
            0,
            0,
            0,
            SENDER_DESCRIPTION,
            &description_payload("Hand"),
        );
        encode_message(
            &mut out,
            0,
            0,
            0,
            TYPE_DESCRIPTION,
            &description_payload(POS_QUAT),
        );
        if s.write_all(&out).is_err() {
            return;
        }
        let start = Instant::now();
        for f in 0..960u32 {
            out.clear();
            for (k, (_, p)) in sent.iter().enumerate() {
                let r = PosQuat {
                    sensor: k as i32,
                    position: *p,
                    rotation: [0.0, 0.0, 0.0, 1.0],
                };
                encode_message(&mut out, f, 0, 0, 0, &encode_pos_quat(&r));
            }
            if s.write_all(&out).is_err() {
                return;
            }
            let due = Duration::from_secs_f64((f + 1) as f64 / 120.0);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                std::thread::sleep(wait);
            }
        }
    });
    let sensors: Vec<String> = markers
        .iter()
        .enumerate()
        .map(|(k, (name, _))| format!("\"{k}\" = \"{name}\""))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("stage.toml");
    std::fs::write(
        &stage,
        format!(
            "[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"vrpn\"\nurl = \"vrpn://Hand@tcp://127.0.0.1:{port}\"\nsensors = {{ {} }}\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n",
            sensors.join(", ")
        ),
    )
    .unwrap();
    let daemon =
        common::Daemon::start(&["run", "--config", stage.to_str().unwrap(), "--seconds", "5"]);
    let addr = daemon.addr.clone();
    std::thread::sleep(Duration::from_millis(500));
    let s = &common::client_summary(&addr, &["--frames", "60"]);
    assert_eq!(s["frames"], 60);
    // Every marker fed at 120 Hz: all measured (a frame or two may catch a marker
    // between reports on a loaded machine).
    let measured = s["fill_counts"]["measured"].as_u64().unwrap();
    assert!(measured >= 60 * 8 - 16, "{}", s["fill_counts"]);
    let (ok, lines) = daemon.finish();
    assert!(ok, "{lines:?}");
    let _ = server.join();
}
