//! Serial data gloves: a glove's curls pose the hand through the solver (wrist from
//! optical markers), and `rigless listen glove://` reads a glove stream over a
//! pseudo-terminal pair, through an unplug and a replug of the device.

use glam::{DQuat, DVec3};
use rigless::bench::characters::{demo_hand, hand_bind_params};

mod common;
use rigless::character::procedural::{skin_pose, Pose};
use rigless::input::glove::{default_finger_joints, FingerCalibration, HandMap};
use rigless::markers::MarkerFrame;
use rigless::protocol::glove::{encode_alpha, encode_legacy, GloveReading, DEFAULT_MAX_VALUE};
use rigless::rig::bind::Rig;
use rigless::solve::frame::{Solver, SolverParams};
use serialport::SerialPort;
use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A glove reading that changes with `n`: each finger curls on its own phase, the index
/// and pinky splay, per-joint readings on the middle finger. Curl of the thumb = `n` so
/// that a received line tells which one it was.
fn reading(n: u32) -> GloveReading {
    let max = DEFAULT_MAX_VALUE as f64;
    let wave = |phase: f64| ((0.5 - 0.5 * ((n as f64) * 0.13 + phase).cos()) * max) as u32;
    let mut r = GloveReading {
        curl: [
            Some(n % (DEFAULT_MAX_VALUE + 1)),
            Some(wave(0.7)),
            Some(wave(1.4)),
            Some(wave(2.1)),
            Some(wave(2.8)),
        ],
        ..Default::default()
    };
    r.splay[1] = Some(wave(0.3));
    r.splay[4] = Some(wave(1.9));
    r.joint_curl[2] = [Some(wave(0.0)), Some(wave(0.5)), Some(wave(1.0)), None];
    r.buttons = (n % 4) as u16;
    r
}

/// The glove drives the fingers and three optical markers on the back of the hand drive
/// the wrist: the mesh must match the skinned truth of that pose within the quality
/// target (DESIGN.md: mean vertex error ≤ 2% of the character's height), and the solved
/// finger joints must sit where forward kinematics of the glove's angles puts them.
#[test]
fn glove_curls_and_optical_wrist_pose_the_hand() {
    let ch = demo_hand();
    let rig = Arc::new(Rig::bind(&ch, &hand_bind_params()).expect("hand binds"));
    let sk = &ch.skeleton;
    let cal = [FingerCalibration {
        open: 0,
        closed: DEFAULT_MAX_VALUE,
    }; 5];
    let map = HandMap::new(sk, &default_finger_joints(), cal, DEFAULT_MAX_VALUE).unwrap();
    let mut solver = Solver::new(Arc::clone(&rig), SolverParams::default());
    let nm = rig.n_markers;
    let wrist_markers: Vec<usize> = (0..nm)
        .filter(|&k| rig.marker_names[k].starts_with("hand_"))
        .collect();
    assert_eq!(wrist_markers.len(), 3);
    let mut pins = vec![f64::NAN; rig.ik.n_params()];
    let mut verts = vec![DVec3::ZERO; ch.vertices.len()];
    let mut truth = vec![DVec3::ZERO; ch.vertices.len()];
    let mut truth_markers = vec![DVec3::ZERO; nm];
    let (mut wr, mut wp) = (vec![DQuat::IDENTITY; sk.len()], vec![DVec3::ZERO; sk.len()]);
    let mut worst_err = 0.0f64;
    let mut worst_joint_m = 0.0f64;
    for n in 0..48u32 {
        let t = n as f64 / 60.0;
        let r = reading(n * 40);
        let mut local = vec![DQuat::IDENTITY; sk.len()];
        map.local_rotations(&r, &mut local);
        local[0] = DQuat::from_rotation_x(0.4 * t) * DQuat::from_rotation_z(-0.3 * t);
        let pose = Pose {
            local,
            root_offset: DVec3::new(0.05 * t, -0.02 * t, 0.03 * t),
        };
        skin_pose(&ch, &pose, &mut truth, &mut truth_markers);
        // Only the wrist cluster is seen; the nail markers are not.
        let mut frame = MarkerFrame::all_present(t, truth_markers.clone());
        for k in 0..nm {
            if !wrist_markers.contains(&k) {
                frame.positions[k] = DVec3::NAN;
            }
        }
        map.write_pins(&r, &|j| rig.ik.angle_params(j), &mut pins);
        solver.set_pins(&pins);
        solver.solve(&frame, Instant::now() + Duration::from_secs(10), &mut verts);
        let mean: f64 = verts
            .iter()
            .zip(&truth)
            .map(|(a, b)| (*a - *b).length())
            .sum::<f64>()
            / verts.len() as f64;
        worst_err = worst_err.max(mean / rig.height_m);
        sk.forward(&pose.local, pose.root_offset, &mut wr, &mut wp);
        let (_, solved) = solver.joint_world();
        for f in map.joints() {
            for j in f {
                worst_joint_m = worst_joint_m.max((solved[j] - wp[j]).length());
            }
        }
    }
    // Quality target of DESIGN.md.
    assert!(
        worst_err <= 0.02,
        "mean vertex error {worst_err} of the height"
    );
    // The wrist fit from three exact markers and the pinned angles are exact up to the
    // posture fit's stopping tolerance (1e-4 rad steps on a 0.2 m hand: 0.02 mm).
    assert!(
        worst_joint_m < 2e-5,
        "finger joints off by {worst_joint_m} m"
    );
}

/// Held by every test that spawns a process or opens a pseudo-terminal: a child spawned
/// while another test holds a master would inherit it and keep that device open through
/// its unplug.
static PTY_AND_SPAWN: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Reads lines of a child's stream into a channel.
fn lines_of(r: impl std::io::Read + Send + 'static) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(r).lines() {
            let Ok(line) = line else { break };
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits up to 10 s for a line containing every one of `needles`.
fn wait_for(rx: &mpsc::Receiver<String>, needles: &[&str], seen: &mut Vec<String>) {
    let end = Instant::now() + Duration::from_secs(10);
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        match rx.recv_timeout(left) {
            Ok(l) => {
                let hit = needles.iter().all(|n| l.contains(n));
                seen.push(l);
                if hit {
                    return;
                }
            }
            Err(_) => break,
        }
    }
    panic!("no line with {needles:?} on stderr; saw {seen:#?}");
}

/// Writes lines `range` (alpha or legacy) at about 500 lines per second.
fn write_lines(port: &mut serialport::TTYPort, range: std::ops::Range<u32>, legacy: bool) {
    for n in range {
        let mut s = String::new();
        if legacy {
            encode_legacy(&reading(n), &mut s);
        } else {
            encode_alpha(&reading(n), &mut s);
        }
        port.write_all(s.as_bytes()).unwrap();
        std::thread::sleep(Duration::from_millis(2));
    }
    port.flush().unwrap();
}

/// Collects JSON lines from stdout until `count` have arrived (10 s at most).
fn collect(rx: &mpsc::Receiver<String>, count: usize, into: &mut Vec<serde_json::Value>) {
    let end = Instant::now() + Duration::from_secs(10);
    while into.len() < count {
        let Some(left) = end.checked_duration_since(Instant::now()) else {
            break;
        };
        match rx.recv_timeout(left) {
            Ok(l) => into.push(serde_json::from_str(&l).expect("listen --json prints JSON")),
            Err(_) => break,
        }
    }
}

fn thumb_curl_raw(v: &serde_json::Value) -> u32 {
    (v["glove"]["curl"][0].as_f64().unwrap() * DEFAULT_MAX_VALUE as f64).round() as u32
}

fn glove_over_pty(legacy: bool) {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyGLOVE");
    let plug = |link: &std::path::Path| {
        let (master, slave) = serialport::TTYPort::pair().expect("a pseudo-terminal pair");
        let name = slave.name().expect("the slave's path");
        drop(slave);
        let _ = std::fs::remove_file(link);
        std::os::unix::fs::symlink(&name, link).unwrap();
        master
    };
    let url = format!(
        "glove://{}?baud=115200&format={}",
        link.display(),
        if legacy { "legacy" } else { "alpha" }
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_rigless"))
        .args(["listen", &url, "--json", "--seconds", "40"])
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let err = lines_of(child.stderr.take().unwrap());
    let out = lines_of(child.stdout.take().unwrap());
    let mut log = Vec::new();
    // The glove is plugged in after the listener started (which also keeps the
    // pseudo-terminal's master out of the child: it would inherit it and hold the
    // device open through the unplug).
    wait_for(&err, &["retrying"], &mut log);
    let mut master = plug(&link);
    wait_for(&err, &["glove port", "open"], &mut log);
    let mut got = Vec::new();
    write_lines(&mut master, 0..150, legacy);
    collect(&out, 150, &mut got);
    assert_eq!(got.len(), 150, "lines before the unplug");
    // Unplug: the port goes away; the listener notices and keeps trying.
    drop(master);
    wait_for(&err, &["reopening"], &mut log);
    std::thread::sleep(Duration::from_millis(400));
    // Replug at the same path (a new device node behind it, as udev's by-id links do).
    let mut master = plug(&link);
    wait_for(&err, &["glove port", "open"], &mut log);
    write_lines(&mut master, 150..300, legacy);
    collect(&out, 300, &mut got);
    // Stop as Ctrl-C does, and read the summary.
    let _ = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status();
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    let summary: Vec<String> = err.try_iter().collect();
    // Every line written while plugged in arrived, in order, decoded exactly.
    let seq: Vec<u32> = got.iter().map(thumb_curl_raw).collect();
    assert_eq!(seq, (0..300).collect::<Vec<_>>());
    for (v, n) in got.iter().zip(0u32..) {
        let want = reading(n);
        for f in 0..5 {
            // Fractions of full scale; JSON parsing may round the last bit.
            let curl = v["glove"]["curl"][f].as_f64().unwrap() * DEFAULT_MAX_VALUE as f64;
            assert_eq!(curl.round() as u32, want.curl[f].unwrap());
        }
        let pressed = v["glove"]["buttons"].as_array().unwrap().len();
        assert_eq!(pressed, want.buttons.count_ones() as usize);
        assert_eq!(
            v["markers"].as_array().unwrap().len(),
            20,
            "4 joints per finger"
        );
    }
    // An open hand (line 0 has every curl near 0 except the thumb's 0 exactly) puts the
    // thumb's joints at rest; the curled fingers' tips move towards the palm.
    let sk = demo_hand().skeleton;
    let pos = |v: &serde_json::Value, name: &str| {
        let m = v["markers"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["name"] == name)
            .unwrap_or_else(|| panic!("no {name}"));
        let a: Vec<f64> = serde_json::from_value(m["position_m"].clone()).unwrap();
        DVec3::new(a[0], a[1], a[2])
    };
    let rest = |name: &str| sk.joints.iter().find(|j| j.name == name).unwrap().rest;
    assert!((pos(&got[0], "thumb_tip") - rest("thumb_tip")).length() < 1e-9);
    let tip_to_base = |v: &serde_json::Value| (pos(v, "ring_tip") - pos(v, "ring_1")).length();
    let open_len = (rest("ring_tip") - rest("ring_1")).length();
    let most_curled = got
        .iter()
        .max_by_key(|v| (v["glove"]["curl"][3].as_f64().unwrap() * 1e6) as i64)
        .unwrap();
    assert!(
        tip_to_base(most_curled) < 0.75 * open_len,
        "a curled ring finger spans {} m of {open_len}",
        tip_to_base(most_curled)
    );
    let last = summary.last().cloned().unwrap_or_default();
    assert!(
        last.contains("300 packets") && last.contains("2 connections"),
        "summary {last:?}; log {log:#?}"
    );
}

/// One test for both encodings: run one after the other, no child process can inherit
/// the other's pseudo-terminal master.
#[test]
fn listen_reads_a_glove_through_unplug_and_replug() {
    let _one_at_a_time = PTY_AND_SPAWN.lock().unwrap_or_else(|p| p.into_inner());
    glove_over_pty(false);
    glove_over_pty(true);
}

/// A stage with a glove input (and no optical markers: the wrist stays at rest) streams a
/// hand whose fingers follow the glove: open, the mesh reaches as far as the rest mesh;
/// as a fist, the fingertips fold back towards the palm.
#[test]
fn a_stage_with_a_glove_curls_the_streamed_hand() {
    use std::sync::atomic::{AtomicU8, Ordering};
    let _one_at_a_time = PTY_AND_SPAWN.lock().unwrap_or_else(|p| p.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyGLOVE");
    let stage = dir.path().join("stage.toml");
    std::fs::write(
        &stage,
        format!(
            "[character]\nprocedural = \"hand\"\n\n[[inputs]]\ntype = \"glove\"\nurl = \"glove://{}\"\ncalibration.index = {{ open = 100, closed = 3900 }}\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n",
            link.display()
        ),
    )
    .unwrap();
    // The daemon starts before the glove is plugged in (see glove_over_pty).
    let daemon = common::Daemon::start(&[
        "run",
        "--config",
        stage.to_str().unwrap(),
        "--seconds",
        "12",
    ]);
    let (mut master, slave) = serialport::TTYPort::pair().expect("a pseudo-terminal pair");
    let name = slave.name().unwrap();
    // Closed before the link appears, as a device node nobody holds.
    drop(slave);
    std::os::unix::fs::symlink(name, &link).unwrap();
    // 0: open hand, 1: fist, 2: stop.
    let mode = Arc::new(AtomicU8::new(0));
    let writer = {
        let mode = Arc::clone(&mode);
        std::thread::spawn(move || {
            let end = Instant::now() + Duration::from_secs(15);
            while Instant::now() < end {
                let r = match mode.load(Ordering::Relaxed) {
                    0 => GloveReading {
                        curl: [Some(100); 5],
                        ..Default::default()
                    },
                    1 => GloveReading {
                        curl: [Some(3900); 5],
                        ..Default::default()
                    },
                    _ => break,
                };
                let mut s = String::new();
                encode_alpha(&r, &mut s);
                // Until the daemon opens the port, the master's writes fail (no slave
                // open): those lines are lost, as a glove's are before it is read.
                let _ = master.write_all(s.as_bytes());
                std::thread::sleep(Duration::from_millis(10));
            }
        })
    };
    let rest_max_y = demo_hand()
        .vertices
        .iter()
        .map(|v| v.y)
        .fold(f64::MIN, f64::max);
    std::thread::sleep(Duration::from_millis(1000));
    let open = common::client_summary(&daemon.addr, &["--frames", "30"]);
    mode.store(1, Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(1000));
    let fist = common::client_summary(&daemon.addr, &["--frames", "30"]);
    mode.store(2, Ordering::Relaxed);
    writer.join().unwrap();
    let (ok, lines) = daemon.finish();
    assert!(ok, "{lines:?}");
    let top = |s: &serde_json::Value| s["bbox_max"][1].as_f64().unwrap();
    // Open: the fingertips reach the rest mesh's top (within 2 mm: the mesh is solved,
    // not copied); as a fist they fold back by more than a finger's distal segments.
    assert!(
        (top(&open) - rest_max_y).abs() < 0.002,
        "open top {} rest {rest_max_y}",
        top(&open)
    );
    assert!(
        top(&fist) < rest_max_y - 0.04,
        "fist top {} rest {rest_max_y}",
        top(&fist)
    );
}
