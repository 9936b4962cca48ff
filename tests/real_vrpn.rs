//! Golden tests with the real VRPN 07.38 TCP session in `../shared/data/vrpn` (a
//! `vrpn_server` with a spinning tracker and `vrpn_print_devices` as client; skipped when
//! absent): every message of both directions decodes, descriptions name senders and
//! types, and every position report is a unit quaternion and a finite position.
//! Expected counts were read off the capture independently (a Python struct walk that
//! consumed every byte).

use rigless::protocol::vrpn::{decode_message, parse_cookie, parse_pos_quat, Names, POS_QUAT};
use std::collections::HashMap;

mod common;

/// What a walk over a capture found.
struct Walk {
    version: (u32, u32),
    names: Names,
    /// Messages per (sender, type) name.
    counts: HashMap<(String, String), usize>,
    /// Position reports with their sender's name.
    reports: Vec<(String, rigless::protocol::vrpn::PosQuat)>,
}

/// Walks a capture from its cookie to its last byte.
fn walk(b: &[u8]) -> Walk {
    let version = parse_cookie(b[..24].try_into().unwrap()).unwrap();
    let mut names = Names::default();
    let mut counts = HashMap::new();
    let mut reports = Vec::new();
    let mut at = 24;
    while at < b.len() {
        let (m, n) = decode_message(&b[at..])
            .unwrap()
            .expect("the capture holds whole messages");
        at += n;
        if names.observe(&m).unwrap() {
            continue;
        }
        let key = (
            names.sender(m.sender).unwrap_or("?").to_owned(),
            names.kind(m.kind).unwrap_or("?").to_owned(),
        );
        if key.1 == POS_QUAT {
            reports.push((key.0.clone(), parse_pos_quat(m.payload).unwrap()));
        }
        *counts.entry(key).or_insert(0) += 1;
    }
    assert_eq!(at, b.len(), "the walk ends exactly at the end");
    Walk {
        version,
        names,
        counts,
        reports,
    }
}

#[test]
fn server_to_client_session() {
    let Some(b) = common::shared_file("vrpn/spin0_tcp_session.server_to_client.bin") else {
        return;
    };
    let Walk {
        version,
        names,
        counts,
        reports,
    } = walk(&b);
    assert_eq!(version, (7, 38));
    assert_eq!(names.sender(2), Some("Spin0"));
    assert_eq!(names.kind(4), Some(POS_QUAT));
    let n = |s: &str, t: &str| {
        counts
            .get(&(s.to_owned(), t.to_owned()))
            .copied()
            .unwrap_or(0)
    };
    assert_eq!(n("Spin0", POS_QUAT), 442);
    assert_eq!(n("Tracker0", POS_QUAT), 339);
    assert_eq!(n("Spin0", "vrpn_Tracker Velocity"), 442);
    assert_eq!(n("Spin0", "vrpn_Base pong_message"), 5);
    // Spin0 (the spinning tracker): sensors 0 and 1, 221 reports each; Tracker0 (the
    // server's other tracker): sensors 0 to 2, 113 each.
    let mut per_sensor: HashMap<(String, i32), usize> = HashMap::new();
    for (sender, r) in &reports {
        let q = r.rotation;
        let norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        assert!((norm - 1.0).abs() < 1e-6, "{r:?}");
        assert!(r.position.is_finite());
        *per_sensor.entry((sender.clone(), r.sensor)).or_insert(0) += 1;
    }
    let mut got: Vec<((String, i32), usize)> = per_sensor.into_iter().collect();
    got.sort();
    let want: Vec<((String, i32), usize)> = [
        (("Spin0", 0), 221),
        (("Spin0", 1), 221),
        (("Tracker0", 0), 113),
        (("Tracker0", 1), 113),
        (("Tracker0", 2), 113),
    ]
    .into_iter()
    .map(|((s, k), n)| ((s.to_owned(), k), n))
    .collect();
    assert_eq!(got, want);
    // The spinning tracker turns: its sensor 0 does not report one rotation throughout.
    let spins: Vec<[f64; 4]> = reports
        .iter()
        .filter(|(s, r)| s == "Spin0" && r.sensor == 0)
        .map(|(_, r)| r.rotation)
        .collect();
    assert!(spins.windows(2).any(|w| w[0] != w[1]));
}

#[test]
fn client_to_server_session() {
    let Some(b) = common::shared_file("vrpn/spin0_tcp_session.client_to_server.bin") else {
        return;
    };
    let Walk { version, names, .. } = walk(&b);
    assert_eq!(version, (7, 38));
    // The client names its own senders, starting with the device it asks for.
    assert_eq!(names.sender(1), Some("Spin0"));
}

/// The server's side of the real session and its Spin0 reports, in order (`None`, with
/// the reason printed, when the shared data is absent).
fn spin0_server_bytes() -> Option<(Vec<u8>, Vec<rigless::protocol::vrpn::PosQuat>)> {
    let capture = common::shared_file("vrpn/spin0_tcp_session.server_to_client.bin")?;
    let expected = walk(&capture)
        .reports
        .into_iter()
        .filter(|(s, _)| s == "Spin0")
        .map(|(_, r)| r)
        .collect();
    Some((capture, expected))
}

/// Runs the client (in `mode`) against `addr` until it has as many Spin0 reports as
/// `expected` (10 s at most), checks they are `expected` bit for bit, and returns its
/// counters.
fn read_spin0(
    mode: rigless::protocol::url::VrpnMode,
    addr: std::net::SocketAddr,
    expected: &[rigless::protocol::vrpn::PosQuat],
) -> rigless::input::vrpn::VrpnStats {
    use std::sync::atomic::{AtomicBool, Ordering};
    let stop = AtomicBool::new(false);
    let stats = rigless::input::vrpn::VrpnStats::default();
    let mut got = Vec::new();
    let started = std::time::Instant::now();
    rigless::input::vrpn::run_mode(mode, addr, "Spin0", &stop, &stats, &mut |_, _, r| {
        got.push(*r);
        if got.len() == expected.len() {
            stop.store(true, Ordering::Relaxed);
        }
    });
    assert!(started.elapsed() < std::time::Duration::from_secs(10));
    assert_eq!(got, expected, "every Spin0 report, in order, bit for bit");
    stats
}

#[test]
fn the_tcp_client_reads_a_replayed_real_session() {
    use rigless::protocol::url::VrpnMode;
    use std::io::{Read, Write};
    use std::sync::atomic::Ordering;
    let Some((capture, expected)) = spin0_server_bytes() else {
        return;
    };
    // A loopback server that replays the captured bytes, then reads what the client says.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let server = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        s.write_all(&capture).unwrap();
        s.set_read_timeout(Some(std::time::Duration::from_secs(5)))
            .unwrap();
        let mut hello = vec![0u8; 24];
        s.read_exact(&mut hello).unwrap();
        // Keep the connection until the client is done.
        let mut rest = Vec::new();
        let _ = s.read_to_end(&mut rest);
        (hello, rest)
    });
    let stats = read_spin0(VrpnMode::Tcp, addr, &expected);
    assert_eq!(stats.connections.load(Ordering::Relaxed), 1);
    // The client spoke first with a VRPN 07.38 cookie and its descriptions.
    let (hello, rest) = server.join().unwrap();
    assert_eq!(parse_cookie(hello[..24].try_into().unwrap()), Ok((7, 38)));
    let mut names = Names::default();
    let mut at = 0;
    while let Ok(Some((m, n))) = decode_message(&rest[at..]) {
        names.observe(&m).unwrap();
        at += n;
    }
    assert_eq!(names.sender(0), Some("Spin0"));
    assert_eq!(names.kind(2), Some(POS_QUAT));
}

/// The UDP connection mode with the real session's bytes: a loopback server that acts as
/// `vrpn_server` does (takes the client's connection request on its UDP port, calls back
/// over TCP, sends the cookie and descriptions there, and the rest of the capture as
/// datagrams of whole messages to the UDP port the client described).
#[test]
fn the_udp_mode_client_reads_a_real_session_sent_as_datagrams() {
    use rigless::protocol::url::VrpnMode;
    use rigless::protocol::vrpn::{
        datagrams, parse_connection_request, parse_udp_description, UDP_DESCRIPTION,
    };
    use std::io::{Read, Write};
    use std::sync::atomic::Ordering;
    let Some((capture, expected)) = spin0_server_bytes() else {
        return;
    };
    // Split the capture: descriptions (negative types) for TCP, the rest for UDP.
    let (mut tcp_part, mut udp_part) = (capture[..24].to_vec(), Vec::new());
    let mut at = 24;
    while let Ok(Some((m, n))) = decode_message(&capture[at..]) {
        let bytes = &capture[at..at + n];
        if m.kind < 0 {
            tcp_part.extend_from_slice(bytes);
        } else {
            udp_part.extend_from_slice(bytes);
        }
        at += n;
    }
    let server_udp = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    server_udp
        .set_read_timeout(Some(std::time::Duration::from_secs(5)))
        .unwrap();
    let addr = server_udp.local_addr().unwrap();
    let server = std::thread::spawn(move || {
        let mut req = [0u8; 256];
        let (n, _) = server_udp
            .recv_from(&mut req)
            .expect("a connection request");
        let back = parse_connection_request(&req[..n]).unwrap();
        let mut s = std::net::TcpStream::connect(back).unwrap();
        s.write_all(&tcp_part).unwrap();
        s.set_read_timeout(Some(std::time::Duration::from_secs(5)))
            .unwrap();
        // Read the client's cookie and messages until its UDP description.
        let mut got = Vec::new();
        let mut chunk = [0u8; 4096];
        let dest = loop {
            let n = s.read(&mut chunk).unwrap();
            assert!(n > 0, "the client hung up before describing its UDP port");
            got.extend_from_slice(&chunk[..n]);
            let mut at = 24.min(got.len());
            let mut dest = None;
            while let Ok(Some((m, used))) = decode_message(&got[at..]) {
                if m.kind == UDP_DESCRIPTION {
                    dest = Some(parse_udp_description(&m).unwrap());
                }
                at += used;
            }
            if let Some(d) = dest {
                break d;
            }
        };
        let parts = datagrams(&udp_part, 1472);
        for r in &parts {
            server_udp.send_to(&udp_part[r.clone()], dest).unwrap();
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        // Keep the connection until the client is done.
        let mut rest = Vec::new();
        let _ = s.read_to_end(&mut rest);
        parts.len()
    });
    let stats = read_spin0(VrpnMode::Udp, addr, &expected);
    let sent = server.join().unwrap();
    assert_eq!(stats.datagrams.load(Ordering::Relaxed), sent as u64);
    assert_eq!(stats.bad_datagrams.load(Ordering::Relaxed), 0);
    assert_eq!(stats.connections.load(Ordering::Relaxed), 1);
}
