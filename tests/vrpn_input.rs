//! A stage with a VRPN input, in-process on the system clock: a loopback VRPN server
//! streams the procedural hand's markers at rest as sensors of one tracker; the stage
//! maps sensors to markers by its config and solves the hand at rest.

use rigless::config::parse_stage;
use rigless::daemon::stage::{Stage, StartOptions};
use rigless::markers::FillState;
use rigless::protocol::vrpn::{
    cookie, description_payload, encode_message, encode_pos_quat, PosQuat, POS_QUAT,
    SENDER_DESCRIPTION, TYPE_DESCRIPTION,
};
use rigless::runtime::clock::SystemClock;
use rigless::runtime::slot::LatestSlot;
use std::io::Write;
use std::sync::Arc;
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
    // hangs up). Sensor k carries marker 7 - k, as the stage's `sensors` map says.
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
                    sensor: (sent.len() - 1 - k) as i32,
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
        .map(|(k, (name, _))| format!("\"{}\" = \"{name}\"", markers.len() - 1 - k))
        .collect();
    let cfg = parse_stage(
        &format!(
            "[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"vrpn\"\nurl = \"vrpn://Hand@tcp://127.0.0.1:{port}\"\nsensors = {{ {} }}\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n",
            sensors.join(", ")
        ),
        "vrpn stage",
    )
    .unwrap();
    let frames = Arc::new(LatestSlot::new());
    let stage = Stage::start_with(
        &cfg,
        std::path::Path::new("."),
        Arc::new(SystemClock::new()),
        StartOptions {
            stop_after_secs: Some(2.0),
            frames: Some(Arc::clone(&frames)),
            ..StartOptions::default()
        },
    )
    .unwrap();
    let summary = stage.join().unwrap();
    let last = frames.take().expect("frames were solved");
    server.join().unwrap();
    // Every marker fed at 120 Hz: none held at the end (measured, or predicted when a
    // loaded machine delays the last reports past the 25 ms measured window), and the
    // reports reached the loop (about 2 s of 8 sensors; at least half of them).
    assert!(
        last.marker_states.iter().all(|s| *s != FillState::Held),
        "{:?}",
        last.marker_states
    );
    assert!(summary.source_samples >= 8 * 120, "{summary:?}");
    // Each sensor fed the marker the config names for it, at its rest position: the
    // solved mesh is the hand at rest.
    common::assert_hand_at_rest(&last);
}
