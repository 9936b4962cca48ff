//! The network inputs against hostile or broken peers, on loopback with bounded waits:
//! a spoofed NatNet server info (from another socket, to the command socket and the
//! data port) changes nothing and frames keep decoding; a server whose info states a
//! version its frames are not in is decoded with the version before, said once; a VRPN
//! server that goes silent is given up and reconnected within the silence timeout plus
//! the reconnect interval, and each kind of reason for a drop is said once.

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

/// A loopback NatNet server for `run_for`: answers connect requests with `info` and
/// model-definition requests with `models`, streams a frame every 10 ms to `data` once a
/// client connected, and calls `each(elapsed, client's command address)` every turn.
/// Returns the frames it sent.
fn serve(
    server: &UdpSocket,
    data: SocketAddr,
    info: &[u8],
    models: &[u8],
    run_for: Duration,
    each: &mut dyn FnMut(Duration, SocketAddr),
) -> i32 {
    server
        .set_read_timeout(Some(Duration::from_millis(2)))
        .unwrap();
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
                    server.send_to(models, from).unwrap();
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
    let mut spoofs = 0;
    let sent = serve(
        &server,
        data_addr,
        &server_info(V3, data_addr.port()),
        &models(&["Thumb", "Index", "Middle"]),
        Duration::from_millis(2000),
        &mut |t, command| {
            if t > Duration::from_millis(500) && spoofs < 20 {
                for to in [command, data_addr] {
                    spoofer.send_to(&lie, to).unwrap();
                    spoofer.send_to(&renamed, to).unwrap();
                }
                spoofs += 1;
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

/// The server itself states NatNet 4.1, again every 200 ms, but streams 3.0 frames:
/// every frame is delivered all the same, the client goes back to 3.0 after
/// `FALLBACK_FRAMES` frames, and says so once.
#[test]
fn frames_that_only_decode_with_the_version_before_bring_it_back_once() {
    let server = UdpSocket::bind("127.0.0.1:0").unwrap();
    let server_addr = server.local_addr().unwrap();
    let data = bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let data_addr = data.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let log = common::LogCapture::default();
    let client = {
        let (stop, log) = (Arc::clone(&stop), log.clone());
        std::thread::spawn(move || {
            let command = command_socket(server_addr).unwrap();
            let stats = NatNetStats::default();
            let mut cc = CommandClient::new(V3, true);
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
            (frames, cc.version, stats)
        })
    };
    let lie = server_info(Version(4, 1), data_addr.port());
    let mut next_lie = Duration::from_millis(200);
    let sent = serve(
        &server,
        data_addr,
        &lie,
        &models(&["Thumb", "Index", "Middle"]),
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
    let (frames, version, stats) = client.join().unwrap();
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
