//! The network inputs against hostile or broken peers, on loopback with bounded waits:
//! a spoofed NatNet server info (from another socket, to the command socket and the
//! data port) changes nothing and frames keep decoding; a server whose info states a
//! version its frames are not in is decoded with the version before, said once; a VRPN
//! server that goes silent is given up and reconnected within the silence timeout plus
//! the reconnect interval, a quiet one that answers pings is kept, and each kind of
//! reason for a drop is said once.

use rigless::input::natnet::{
    bind, command_socket, markers_of, run_input, run_with_server, CommandClient, NatNetStats,
};
use rigless::protocol::natnet::{
    encode_frame, encode_model_def, encode_server_info, Description, MocapFrame, ServerInfo,
    Version, NAT_CONNECT, NAT_REQUEST_MODELDEF,
};
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

mod common;

const V3: Version = Version(3, 0);

fn server_info(natnet: Version, data_port: u16) -> Vec<u8> {
    encode_server_info(&ServerInfo {
        app: "Motive".into(),
        app_version: [3, 0, 0, 0],
        natnet,
        clock_hz: Some(1_000_000),
        data_port: Some(data_port),
        multicast_group: None,
    })
}

/// A NatNet 3.0 frame numbered `n`: the marker set `Hand`, three markers.
fn frame(n: i32) -> Vec<u8> {
    encode_frame(&MocapFrame {
        frame: n,
        marker_sets: vec![(
            "Hand".into(),
            (0..3).map(|k| glam::Vec3::splat(k as f32 * 0.1)).collect(),
        )],
        timestamp_s: f64::from(n) / 100.0,
        ..MocapFrame::default()
    })
    .unwrap()
}

fn models(names: &[&str]) -> Vec<u8> {
    encode_model_def(&[Description::MarkerSet {
        name: "Hand".into(),
        markers: names.iter().map(|n| (*n).to_owned()).collect(),
    }])
    .unwrap()
}

/// [`serve`] as NatNet 3.0 for `run_for`, calling `spoof(client's command address, k)`
/// once a turn for `k` in `0..SPOOFS` from half a second on. Returns the frames sent
/// and the spoofs made.
fn serve_spoofed(
    server: &UdpSocket,
    data: SocketAddr,
    run_for: Duration,
    spoof: &mut dyn FnMut(SocketAddr, i32),
) -> (i32, i32) {
    let mut spoofs = 0;
    let sent = serve(
        server,
        data,
        &server_info(V3, data.port()),
        run_for,
        &mut |t, command| {
            if t > Duration::from_millis(500) && spoofs < SPOOFS {
                spoof(command, spoofs);
                spoofs += 1;
            }
        },
    );
    (sent, spoofs)
}

/// Spoofs [`serve_spoofed`] makes.
const SPOOFS: i32 = 20;

/// A loopback NatNet server for `run_for`: answers connect requests with `info` and
/// model-definition requests with three markersets (`Thumb`, `Index`, `Middle`), streams
/// a frame every 10 ms to `data` once a client connected, and calls `each(elapsed,
/// client's command address)` every turn. Returns the frames it sent.
fn serve(
    server: &UdpSocket,
    data: SocketAddr,
    info: &[u8],
    run_for: Duration,
    each: &mut dyn FnMut(Duration, SocketAddr),
) -> i32 {
    server
        .set_read_timeout(Some(Duration::from_millis(2)))
        .unwrap();
    let models = models(&["Thumb", "Index", "Middle"]);
    let start = Instant::now();
    let mut client = None;
    let mut sent = 0;
    let mut buf = [0u8; 2048];
    while start.elapsed() < run_for {
        if let Ok((n, from)) = server.recv_from(&mut buf) {
            match u16::from_le_bytes([buf[0], buf[1]]) {
                _ if n < 4 => {}
                NAT_CONNECT => {
                    client = Some(from);
                    server.send_to(info, from).unwrap();
                }
                NAT_REQUEST_MODELDEF => {
                    server.send_to(&models, from).unwrap();
                }
                _ => {}
            }
        }
        if let Some(c) = client {
            let due = (start.elapsed().as_millis() / 10) as i32;
            while sent < due {
                server.send_to(&frame(sent), data).unwrap();
                sent += 1;
            }
            each(start.elapsed(), c);
        }
    }
    sent
}

#[test]
fn the_command_socket_binds_where_the_server_is_reached() {
    let s = command_socket("127.0.0.1:1510".parse().unwrap()).unwrap();
    assert_eq!(
        s.local_addr().unwrap().ip(),
        std::net::IpAddr::from([127, 0, 0, 1]),
        "not every interface"
    );
}

/// Another socket on the same host sends a server info stating NatNet 4.1 (and model
/// definitions renaming the markers) to the client's command socket and to its data
/// port, 20 of each, from 0.5 s on: the client still decodes every frame as 3.0 and keeps
/// the server's names.
#[test]
fn a_spoofed_server_info_changes_nothing() {
    let server = UdpSocket::bind("127.0.0.1:0").unwrap();
    let server_addr = server.local_addr().unwrap();
    let data = bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let data_addr = data.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let log = common::LogCapture::default();
    let client = {
        let (stop, log) = (Arc::clone(&stop), log.clone());
        std::thread::spawn(move || {
            let stats = NatNetStats::default();
            let mut got: Vec<(i32, Vec<String>)> = Vec::new();
            tracing::subscriber::with_default(log.subscriber(tracing::Level::INFO), || {
                run_input(
                    &data,
                    data_addr,
                    V3,
                    Some(server_addr),
                    &stop,
                    &stats,
                    &mut |_, f, names| {
                        let mut named = Vec::new();
                        markers_of(f, names, &mut named);
                        got.push((f.frame, named.into_iter().map(|m| m.name).collect()));
                    },
                )
                .unwrap();
            });
            (got, stats)
        })
    };
    let spoofer = UdpSocket::bind("127.0.0.1:0").unwrap();
    let (lie, renamed) = (
        server_info(Version(4, 1), data_addr.port()),
        models(&["X", "Y", "Z"]),
    );
    let (sent, spoofs) = serve_spoofed(
        &server,
        data_addr,
        Duration::from_millis(2000),
        &mut |command, _| {
            for to in [command, data_addr] {
                spoofer.send_to(&lie, to).unwrap();
                spoofer.send_to(&renamed, to).unwrap();
            }
        },
    );
    std::thread::sleep(Duration::from_millis(100));
    stop.store(true, Ordering::Relaxed);
    let (got, stats) = client.join().unwrap();
    assert_eq!(spoofs, 20);
    // Frames 50 and on were sent after the first lie.
    let after = got.iter().filter(|(n, _)| *n >= 50).count();
    println!(
        "{sent} frames sent, {} decoded ({after} after the first lie), {} ignored",
        got.len(),
        stats.foreign.load(Ordering::Relaxed)
    );
    assert!(sent >= 150, "{sent} frames sent");
    assert!(
        got.len() as i32 >= sent - 2,
        "{} of {sent} frames decoded",
        got.len()
    );
    assert!(after as i32 >= sent - 52, "{after} frames after the lie");
    assert_eq!(
        stats.foreign.load(Ordering::Relaxed),
        80,
        "every lie ignored and counted"
    );
    assert_eq!(stats.packets.decode_errors.load(Ordering::Relaxed), 0);
    assert_eq!(
        got.last().unwrap().1,
        ["Hand:Thumb", "Hand:Index", "Hand:Middle"]
    );
    println!("the log:\n{}", log.lines().join("\n"));
    assert_eq!(log.count("WARN", "natnet: ignoring"), 1, "said once");
    assert_eq!(log.count("INFO", "NatNet 4.1"), 0);
}

/// A NatNet client (`strict_source` as given) on a fresh loopback data port, talking to
/// the server socket it returns: its thread records each frame's number until `stop`,
/// then gives them with its command client and figures; what it logs goes to `log`.
struct Client {
    server: UdpSocket,
    data_addr: SocketAddr,
    stop: Arc<AtomicBool>,
    log: common::LogCapture,
    thread: std::thread::JoinHandle<(Vec<i32>, CommandClient, NatNetStats)>,
}

fn start_client(strict: bool) -> Client {
    let server = UdpSocket::bind("127.0.0.1:0").unwrap();
    let server_addr = server.local_addr().unwrap();
    let data = bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let data_addr = data.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let log = common::LogCapture::default();
    let thread = {
        let (stop, log) = (Arc::clone(&stop), log.clone());
        std::thread::spawn(move || {
            let command = command_socket(server_addr).unwrap();
            let stats = NatNetStats::default();
            let mut cc = CommandClient::new(V3, true);
            cc.strict_source = strict;
            let mut frames = Vec::new();
            tracing::subscriber::with_default(log.subscriber(tracing::Level::INFO), || {
                run_with_server(
                    &data,
                    &command,
                    server_addr,
                    &mut cc,
                    &stop,
                    &stats,
                    &mut |_, f, _| frames.push(f.frame),
                )
                .unwrap();
            });
            (frames, cc, stats)
        })
    };
    Client {
        server,
        data_addr,
        stop,
        log,
        thread,
    }
}

/// Another socket on the server's host sends 20 frames of its own (numbered from 10,000)
/// to the client's data port while the server streams: by default they are taken,
/// counted and said once; with `strict_source` they are dropped (counted and said once
/// too), and every frame of the server's is still delivered. Before, they were taken
/// unsaid and uncounted.
#[test]
fn frames_from_another_sender_are_counted_and_dropped_when_strict() {
    for strict in [false, true] {
        let Client {
            server,
            data_addr,
            stop,
            log,
            thread,
            ..
        } = start_client(strict);
        let spoofer = UdpSocket::bind("127.0.0.1:0").unwrap();
        let (sent, spoofs) = serve_spoofed(
            &server,
            data_addr,
            Duration::from_millis(1000),
            &mut |_, k| {
                spoofer.send_to(&frame(10_000 + k), data_addr).unwrap();
            },
        );
        std::thread::sleep(Duration::from_millis(100));
        stop.store(true, Ordering::Relaxed);
        let (frames, _, stats) = thread.join().unwrap();
        let theirs = frames.iter().filter(|&&n| n >= 10_000).count();
        let ours = frames.len() - theirs;
        println!("strict {strict}: {sent} sent, {ours} of ours and {theirs} of theirs delivered");
        assert_eq!(spoofs, 20);
        assert!(ours as i32 >= sent - 2, "{ours} of {sent} delivered");
        assert_eq!(theirs, if strict { 0 } else { 20 });
        assert_eq!(stats.frames_elsewhere.load(Ordering::Relaxed), 20);
        assert_eq!(log.count("WARN", "not the stream's sender"), 1, "said once");
    }
}

/// The server itself states NatNet 4.1, again every 200 ms, but streams 3.0 frames:
/// every frame is delivered all the same, the client goes back to 3.0 after
/// `FALLBACK_FRAMES` frames, and says so once.
#[test]
fn frames_that_only_decode_with_the_version_before_bring_it_back_once() {
    let Client {
        server,
        data_addr,
        stop,
        log,
        thread,
        ..
    } = start_client(false);
    let lie = server_info(Version(4, 1), data_addr.port());
    let mut next_lie = Duration::from_millis(200);
    let sent = serve(
        &server,
        data_addr,
        &lie,
        Duration::from_millis(1500),
        &mut |t, command| {
            if t >= next_lie {
                server.send_to(&lie, command).unwrap();
                next_lie += Duration::from_millis(200);
            }
        },
    );
    std::thread::sleep(Duration::from_millis(100));
    stop.store(true, Ordering::Relaxed);
    let (frames, cc, stats) = thread.join().unwrap();
    let version = cc.version;
    println!(
        "{sent} frames sent, {} decoded, {} not decodable; the log:\n{}",
        frames.len(),
        stats.packets.decode_errors.load(Ordering::Relaxed),
        log.lines().join("\n")
    );
    assert!(sent >= 100, "{sent} frames sent");
    assert!(
        frames.len() as i32 >= sent - 2,
        "{} of {sent} frames",
        frames.len()
    );
    assert_eq!(stats.packets.decode_errors.load(Ordering::Relaxed), 0);
    assert_eq!(version, V3);
    assert_eq!(
        log.count("WARN", "do not decode as NatNet 4.1"),
        1,
        "said once"
    );
}

mod vrpn {
    use super::common;
    use rigless::input::vrpn::{run, VrpnStats, RECONNECT_S, SILENCE_TIMEOUT_S};
    use rigless::protocol::vrpn::{
        cookie, decode_message, description_payload, encode_message, encode_pos_quat, Names,
        PosQuat, COOKIE_LEN, PING, PONG, POS_QUAT, SENDER_DESCRIPTION, TYPE_DESCRIPTION,
    };
    use std::io::{Read, Write};
    use std::net::{TcpListener, TcpStream};
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    /// The server's ids.
    const DEV: i32 = 7;
    const T_PONG: i32 = 3;
    const T_POS: i32 = 4;

    /// The cookie and the descriptions of `Dev` and its types.
    fn hello() -> Vec<u8> {
        let mut out = cookie().to_vec();
        encode_message(
            &mut out,
            0,
            0,
            DEV,
            SENDER_DESCRIPTION,
            &description_payload("Dev"),
        );
        encode_message(
            &mut out,
            0,
            0,
            T_PONG,
            TYPE_DESCRIPTION,
            &description_payload(PONG),
        );
        encode_message(
            &mut out,
            0,
            0,
            T_POS,
            TYPE_DESCRIPTION,
            &description_payload(POS_QUAT),
        );
        out
    }

    fn report(out: &mut Vec<u8>) {
        let r = PosQuat {
            sensor: 0,
            position: glam::DVec3::new(0.1, 0.2, 0.3),
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        encode_message(out, 1, 0, DEV, T_POS, &encode_pos_quat(&r));
    }

    /// Accepts on `l` within `within` (bounded).
    fn accept(l: &TcpListener, within: Duration) -> TcpStream {
        l.set_nonblocking(true).unwrap();
        let start = Instant::now();
        loop {
            match l.accept() {
                Ok((s, _)) => {
                    s.set_nonblocking(false).unwrap();
                    return s;
                }
                Err(_) => {
                    assert!(start.elapsed() < within, "no connection within {within:?}");
                    std::thread::sleep(Duration::from_millis(5));
                }
            }
        }
    }

    /// Reads what the client sends on `s` until it hangs up or `until`, answering each of
    /// its pings of `Dev` with a pong when `answer`; returns the pings.
    fn read_client(mut s: TcpStream, until: Instant, answer: bool) -> usize {
        s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        let (mut got, mut chunk) = (Vec::new(), [0u8; 4096]);
        let (mut names, mut at, mut pings) = (Names::default(), COOKIE_LEN, 0);
        while Instant::now() < until {
            match s.read(&mut chunk) {
                Ok(0) => break,
                Ok(n) => got.extend_from_slice(&chunk[..n]),
                Err(_) => continue,
            }
            while got.len() >= at {
                let Ok(Some((m, used))) = decode_message(&got[at..]) else {
                    break;
                };
                at += used;
                if names.observe(&m).unwrap() {
                    continue;
                }
                if names.kind(m.kind) == Some(PING) && names.sender(m.sender) == Some("Dev") {
                    pings += 1;
                    if answer {
                        let mut pong = Vec::new();
                        encode_message(&mut pong, 0, 0, DEV, T_PONG, &[]);
                        s.write_all(&pong).unwrap();
                    }
                }
            }
        }
        pings
    }

    /// A server on `listener`: its first connection gets the descriptions and a report,
    /// then `then` (given the connection and when the report went) has it while the
    /// client gives it up; the second connection gets the same and is held until `stop`
    /// (5 s at most). Gives the time from the report to the second connection, and what
    /// `then` returned.
    fn serve_twice<T: Send + 'static>(
        listener: TcpListener,
        stop: &Arc<AtomicBool>,
        then: impl FnOnce(TcpStream, Instant) -> T + Send + 'static,
    ) -> std::thread::JoinHandle<(Duration, T)> {
        let stop = Arc::clone(stop);
        std::thread::spawn(move || {
            let mut first = accept(&listener, Duration::from_secs(5));
            let mut out = hello();
            report(&mut out);
            first.write_all(&out).unwrap();
            let quiet_from = Instant::now();
            let during = then(first, quiet_from);
            let mut second = accept(&listener, Duration::from_secs(15));
            let gap = quiet_from.elapsed();
            second.write_all(&out).unwrap();
            let start = Instant::now();
            while !stop.load(Ordering::Relaxed) && start.elapsed() < Duration::from_secs(5) {
                std::thread::sleep(Duration::from_millis(10));
            }
            (gap, during)
        })
    }

    /// The client of `Dev` at `addr` until it has two reports (then it sets `stop`):
    /// its figures and its log.
    fn two_reports(
        addr: std::net::SocketAddr,
        stop: &AtomicBool,
    ) -> (VrpnStats, common::LogCapture) {
        let log = common::LogCapture::default();
        let stats = VrpnStats::default();
        let mut reports = 0;
        tracing::subscriber::with_default(log.subscriber(tracing::Level::INFO), || {
            run(addr, "Dev", stop, &stats, &mut |_, _, _| {
                reports += 1;
                if reports == 2 {
                    stop.store(true, Ordering::Relaxed);
                }
            });
        });
        (stats, log)
    }

    /// A server sends a report, then nothing while keeping the connection open: the
    /// client pings it once a second, gives it up after the silence timeout and connects
    /// again within the reconnect interval after that; said once.
    #[test]
    fn a_silent_server_is_given_up_and_connected_again() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let server = serve_twice(listener, &stop, |first, silent_from| {
            std::thread::spawn(move || {
                read_client(first, silent_from + Duration::from_secs(15), false)
            })
        });
        let (stats, log) = two_reports(addr, &stop);
        let (gap, pinger) = server.join().unwrap();
        let pings = pinger.join().unwrap();
        println!(
            "connected again {:.2} s after the server went silent (timeout {SILENCE_TIMEOUT_S} s, reconnect {RECONNECT_S} s); {pings} pings meanwhile; the log:\n{}",
            gap.as_secs_f64(),
            log.lines().join("\n")
        );
        let gap = gap.as_secs_f64();
        assert!(
            (SILENCE_TIMEOUT_S - 0.05..=SILENCE_TIMEOUT_S + RECONNECT_S + 0.5).contains(&gap),
            "{gap:.2} s"
        );
        assert!((3..=5).contains(&pings), "{pings} pings");
        assert_eq!(stats.connections.load(Ordering::Relaxed), 2);
        assert_eq!(stats.silent.load(Ordering::Relaxed), 1);
        assert_eq!(log.count("WARN", "no whole message for"), 1);
    }

    /// A server that sends a report, then trickles one byte of a next message every
    /// 0.9 s (never completing it) is given up as a silent one is, 5 s after its last
    /// whole message, and connected again (bytes alone used to keep it forever).
    #[test]
    fn a_server_that_trickles_bytes_is_given_up() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let trickling = Arc::clone(&stop);
        let server = serve_twice(listener, &stop, move |first, quiet_from| {
            let mut next = Vec::new();
            report(&mut next);
            let mut s = first.try_clone().unwrap();
            let trickle = std::thread::spawn(move || {
                // One byte every 0.9 s, never the whole message.
                for b in &next[..next.len() - 1] {
                    if trickling.load(Ordering::Relaxed) || s.write_all(&[*b]).is_err() {
                        break;
                    }
                    std::thread::sleep(Duration::from_millis(900));
                }
            });
            let reader = std::thread::spawn(move || {
                read_client(first, quiet_from + Duration::from_secs(15), false)
            });
            (trickle, reader)
        });
        let (stats, log) = two_reports(addr, &stop);
        let (gap, (trickle, reader)) = server.join().unwrap();
        trickle.join().unwrap();
        reader.join().unwrap();
        let gap = gap.as_secs_f64();
        println!("connected again {gap:.2} s after the last whole message");
        assert!(
            (SILENCE_TIMEOUT_S - 0.05..=SILENCE_TIMEOUT_S + RECONNECT_S + 0.5).contains(&gap),
            "{gap:.2} s"
        );
        assert_eq!(stats.connections.load(Ordering::Relaxed), 2);
        assert_eq!(stats.silent.load(Ordering::Relaxed), 1);
        assert_eq!(log.count("WARN", "no whole message for"), 1);
    }

    /// A server with nothing to report that answers pings is kept: 6.5 s of quiet, one
    /// connection.
    #[test]
    fn a_quiet_server_that_answers_pings_is_kept() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let server = std::thread::spawn(move || {
            let mut s = accept(&listener, Duration::from_secs(5));
            s.write_all(&hello()).unwrap();
            let quiet = Duration::from_millis(6500);
            let pings = read_client(s.try_clone().unwrap(), Instant::now() + quiet, true);
            let mut out = Vec::new();
            report(&mut out);
            s.write_all(&out).unwrap();
            // Until the client hangs up (bounded).
            read_client(s, Instant::now() + Duration::from_secs(5), false);
            pings
        });
        let stop = AtomicBool::new(false);
        let stats = VrpnStats::default();
        run(addr, "Dev", &stop, &stats, &mut |_, _, _| {
            stop.store(true, Ordering::Relaxed);
        });
        let pings = server.join().unwrap();
        println!("{pings} pings answered over 6.5 s of quiet");
        assert!((5..=7).contains(&pings), "{pings} pings");
        assert_eq!(stats.connections.load(Ordering::Relaxed), 1);
        assert_eq!(stats.silent.load(Ordering::Relaxed), 0);
        assert_eq!(stats.reports.load(Ordering::Relaxed), 1);
    }

    /// Three servers that send a bad cookie and three that send a message of length 2^31:
    /// six drops counted, each kind of reason said once at warning level.
    #[test]
    fn each_kind_of_reason_for_a_drop_is_said_once() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let server = {
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || {
                for k in 0..6 {
                    let mut s = accept(&listener, Duration::from_secs(5));
                    let mut out = [0u8; COOKIE_LEN].to_vec();
                    if k < 3 {
                        out[..11].copy_from_slice(b"not a vrpn!");
                    } else {
                        out.copy_from_slice(&cookie());
                        out.extend_from_slice(&0x8000_0000u32.to_be_bytes());
                        out.extend_from_slice(&[0; 20]);
                    }
                    s.write_all(&out).unwrap();
                    read_client(s, Instant::now() + Duration::from_secs(5), false);
                }
                stop.store(true, Ordering::Relaxed);
            })
        };
        let log = common::LogCapture::default();
        let stats = VrpnStats::default();
        tracing::subscriber::with_default(log.subscriber(tracing::Level::INFO), || {
            run(addr, "Dev", &stop, &stats, &mut |_, _, _| {});
        });
        server.join().unwrap();
        println!("the log:\n{}", log.lines().join("\n"));
        assert_eq!(stats.connections.load(Ordering::Relaxed), 6);
        assert_eq!(stats.errors.load(Ordering::Relaxed), 6);
        assert_eq!(log.count("WARN", "not a VRPN cookie"), 1);
        assert_eq!(log.count("WARN", "message length 2147483648"), 1);
        assert_eq!(log.lines().len(), 2);
    }
}
