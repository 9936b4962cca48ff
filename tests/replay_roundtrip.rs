//! Replay to OSC, then receive with the OSC input over loopback: sample by sample, what
//! arrives is the recording (to f32), occlusions included.

use rigless::input::osc::{bind, run, OscStats};
use rigless::protocol::osc::OscMapping;
use rigless::replay::bundled::bundled;
use rigless::replay::recording::Recording;
use rigless::replay::sender::{replay, ReplayOptions, Target};
use rigless::runtime::clock::SystemClock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// One received packet: its frame number and its markers (name, position, occluded).
type Received = (i64, Vec<(String, glam::DVec3, bool)>);

#[test]
fn replay_to_osc_arrives_sample_by_sample() {
    let rec =
        Recording::from_c3d("hand_finger_play", bundled("hand_finger_play").unwrap()).unwrap();
    let sock = bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = sock.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    // 2 s of the file (241 frames) at 4× speed.
    let frames = 241usize;
    let receiver = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let stats = OscStats::default();
            let mut got: Vec<Received> = Vec::new();
            run(&sock, &OscMapping::default(), &stop, &stats, &mut |_, f| {
                got.push((
                    f.frame.unwrap(),
                    f.markers()
                        .iter()
                        .map(|m| (m.name.clone(), m.position_m, m.occluded))
                        .collect(),
                ));
                if got.len() == frames {
                    stop.store(true, Ordering::Relaxed);
                }
            });
            got
        })
    };
    let opts = ReplayOptions {
        speed: 4.0,
        end_s: Some(2.0),
        ..ReplayOptions::default()
    };
    let never = AtomicBool::new(false);
    let stats = replay(
        &rec,
        Target::Osc(addr),
        &opts,
        &SystemClock::new(),
        0.05,
        &never,
    )
    .unwrap();
    assert_eq!(stats.packets as usize, frames);
    // Bounded wait for the receiver: it stops itself at the last frame.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while !receiver.is_finished() && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    stop.store(true, Ordering::Relaxed);
    let got = receiver.join().unwrap();
    assert_eq!(got.len(), frames, "every packet arrived on loopback");
    let mut occluded = 0;
    for (n, (frame, markers)) in got.iter().enumerate() {
        assert_eq!(*frame, n as i64);
        assert_eq!(markers.len(), rec.labels.len());
        for (k, (name, p, occ)) in markers.iter().enumerate() {
            assert_eq!(name, &rec.labels[k]);
            let want = rec.frames[n][k];
            assert_eq!(*occ, !want.is_finite(), "frame {n}, {name}");
            if want.is_finite() {
                // f32 on the wire.
                assert!(
                    (*p - want).length() < 1e-6,
                    "frame {n}, {name}: {p} vs {want}"
                );
            } else {
                occluded += 1;
            }
        }
    }
    // The bundled session's gaps came through as occlusions.
    assert!(occluded > 0);
}

#[test]
fn replay_as_a_vrpn_server_reaches_a_tcp_mode_vrpn_client_sample_by_sample() {
    vrpn_round_trip(rigless::protocol::url::VrpnMode::Tcp);
}

/// The UDP connection mode: the client asks over UDP, the server calls back, and the
/// reports come as datagrams (loopback neither loses nor reorders them).
#[test]
fn replay_as_a_vrpn_server_reaches_a_udp_mode_vrpn_client_sample_by_sample() {
    vrpn_round_trip(rigless::protocol::url::VrpnMode::Udp);
}

fn vrpn_round_trip(mode: rigless::protocol::url::VrpnMode) {
    use rigless::input::vrpn::{run_mode, VrpnStats};
    use rigless::protocol::url::VrpnMode;
    let rec =
        Recording::from_c3d("hand_finger_play", bundled("hand_finger_play").unwrap()).unwrap();
    // A free port for the server (picked, then released: loopback only).
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let addr: std::net::SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
    let frames = 121usize; // 1 s of the file
    let expected: usize = rec.frames[..frames]
        .iter()
        .flatten()
        .filter(|p| p.is_finite())
        .count();
    let stop = Arc::new(AtomicBool::new(false));
    let client = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let stats = VrpnStats::default();
            let mut got = Vec::new();
            run_mode(mode, addr, "Hand", &stop, &stats, &mut |_, _, r| {
                got.push(*r);
                if got.len() == expected {
                    stop.store(true, Ordering::Relaxed);
                }
            });
            (got, stats)
        })
    };
    let opts = ReplayOptions {
        speed: 2.0,
        end_s: Some(1.0),
        ..ReplayOptions::default()
    };
    let never = AtomicBool::new(false);
    let target = Target::Vrpn {
        device: "Hand".into(),
        bind: addr,
    };
    // Start once the client is connected (TCP: it retries every 0.5 s) or has asked to
    // be (UDP: it asks every second; the server calls back at its first frame).
    let start_s = match mode {
        VrpnMode::Tcp => 1.0,
        VrpnMode::Udp => 2.5,
    };
    replay(&rec, target, &opts, &SystemClock::new(), start_s, &never).unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while !client.is_finished() && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    stop.store(true, Ordering::Relaxed);
    let (got, stats) = client.join().unwrap();
    if mode == VrpnMode::Udp {
        // The first frames go over TCP, until the client's UDP description has arrived
        // (a frame or three at 240 frames a second); the rest as datagrams of whole
        // messages.
        let datagrams = stats.datagrams.load(Ordering::Relaxed);
        assert!(datagrams >= frames as u64 - 6, "{datagrams} datagrams");
        assert_eq!(stats.bad_datagrams.load(Ordering::Relaxed), 0);
    }
    // Every present sample, in order, exactly (VRPN carries f64).
    let want: Vec<(i32, glam::DVec3)> = rec.frames[..frames]
        .iter()
        .flat_map(|f| {
            f.iter()
                .enumerate()
                .filter(|(_, p)| p.is_finite())
                .map(|(k, p)| (k as i32, *p))
        })
        .collect();
    let have: Vec<(i32, glam::DVec3)> = got.iter().map(|r| (r.sensor, r.position)).collect();
    let first_diff = have.iter().zip(&want).position(|(a, b)| a != b);
    assert!(
        have.len() == want.len() && first_diff.is_none(),
        "{} of {} samples, first difference at {first_diff:?}",
        have.len(),
        want.len()
    );
}

/// Replay as a NatNet server: the NatNet input, told the replay's command port, connects,
/// gets the model definitions and reads every frame, markers named `replay:LABEL`, each
/// sample as in the file (to f32), missing ones occluded.
#[test]
fn replay_to_natnet_reaches_the_natnet_input_sample_by_sample() {
    use rigless::input::natnet::{bind as natnet_bind, markers_of, run_input, NatNetStats};
    use rigless::protocol::natnet::Version;
    let rec =
        Recording::from_c3d("hand_finger_play", bundled("hand_finger_play").unwrap()).unwrap();
    let data = natnet_bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let data_addr = data.local_addr().unwrap();
    // A free port for the replay's command socket (picked, then released: loopback only).
    let command = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let frames = 121usize; // 1 s of the file
    let receiver = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let stats = NatNetStats::default();
            let mut got: Vec<Received> = Vec::new();
            run_input(
                &data,
                data_addr,
                Version(3, 0),
                Some(command),
                &stop,
                &stats,
                &mut |_, f, names| {
                    // Frames before the model definitions arrived carry no names: skip.
                    if names.sets.is_empty() {
                        return;
                    }
                    let mut named = Vec::new();
                    markers_of(f, names, &mut named);
                    got.push((
                        i64::from(f.frame),
                        named
                            .into_iter()
                            .map(|m| (m.name, m.position_m, m.occluded))
                            .collect(),
                    ));
                },
            )
            .unwrap();
            got
        })
    };
    let opts = ReplayOptions {
        speed: 2.0,
        end_s: Some(1.0),
        ..ReplayOptions::default()
    };
    let never = AtomicBool::new(false);
    let target = Target::NatNet {
        data: data_addr,
        command: Some(command),
    };
    // The client asks for a connection every second: start once it has (its first
    // request waits in the command socket's buffer until the first frame reads it).
    replay(&rec, target, &opts, &SystemClock::new(), 1.5, &never).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(200));
    stop.store(true, Ordering::Relaxed);
    let got = receiver.join().unwrap();
    // The first frame answers the connect request, the second the model-definition
    // request: named frames follow from about the third on, to the last.
    assert!(got.len() >= frames - 4, "{} named frames", got.len());
    assert_eq!(got.last().unwrap().0, frames as i64 - 1);
    for (n, markers) in &got {
        let row = &rec.frames[*n as usize];
        assert_eq!(markers.len(), rec.labels.len());
        for ((name, p, occluded), (label, want)) in markers.iter().zip(rec.labels.iter().zip(row)) {
            assert_eq!(name, &format!("replay:{label}"));
            if want.is_finite() {
                assert!(!occluded);
                assert_eq!(p.as_vec3(), want.as_vec3(), "{name} frame {n}");
            } else {
                assert!(*occluded && !p.is_finite(), "{name} frame {n}");
            }
        }
    }
}
