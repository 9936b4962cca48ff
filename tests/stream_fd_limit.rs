//! The vertex stream server with few file descriptors, a test binary of its own because
//! it lowers RLIMIT_NOFILE (to 128) for its whole process. The clients are a child
//! process (this binary again, with its own limit raised back) that opens 200 idle
//! WebSocket connections (the upgrade request sent, nothing read) on loopback.
//!
//! - With the default `max_clients` (64) the server never runs out: 64 are served, the
//!   rest told the server is full, and no accept fails.
//! - With `max_clients` above what the descriptors allow, accepts fail: the server waits
//!   between tries (a few dozen failures, not millions), says so at most once a second,
//!   uses little CPU, keeps serving the clients it has, and serves new ones once
//!   descriptors are free again.

use rigless::output::config::StreamOutputConfig;
use rigless::output::frame::DeformedFrame;
use rigless::output::stream::StreamServer;
use rigless::protocol::vertex_stream::{decode, decode_header, Message, HEADER_LEN};
use rigless::runtime::slot::LatestSlot;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

mod common;

/// Set in the child: `ADDR COUNT`, the WebSocket address and how many to open.
const CHILD_ENV: &str = "RIGLESS_FD_LIMIT_CLIENTS";
/// The server's descriptor limit.
const LIMIT: u64 = 128;
const CLIENTS: usize = 200;
/// Bound on every wait.
const TIMEOUT: Duration = Duration::from_secs(20);

fn set_soft_limit(n: u64) -> u64 {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit and setrlimit only read and write the struct passed.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut r), 0);
        r.rlim_cur = n.min(r.rlim_max);
        assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &r), 0);
    }
    r.rlim_cur
}

/// CPU time this process has used, seconds.
fn cpu_s() -> f64 {
    // SAFETY: getrusage writes the struct passed.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    assert_eq!(unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) }, 0);
    let t = |v: libc::timeval| v.tv_sec as f64 + v.tv_usec as f64 * 1e-6;
    t(u.ru_utime) + t(u.ru_stime)
}

/// The child: opens up to `count` connections to `addr`, each sending a WebSocket
/// upgrade request and reading nothing (a connect that takes over 300 ms is counted as
/// failed; five in a row end the opening), prints `clients open: N`, and holds them until its
/// stdin closes.
fn child_clients(spec: &str) {
    let (addr, count) = spec.split_once(' ').unwrap();
    let (addr, count): (SocketAddr, usize) = (addr.parse().unwrap(), count.parse().unwrap());
    set_soft_limit(u64::MAX);
    let request = format!(
        "GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
    );
    let (mut open, mut failed_in_a_row) = (Vec::new(), 0);
    while open.len() < count && failed_in_a_row < 5 {
        match TcpStream::connect_timeout(&addr, Duration::from_millis(300)) {
            Ok(mut s) => {
                let _ = s.write_all(request.as_bytes());
                open.push(s);
                failed_in_a_row = 0;
            }
            Err(_) => failed_in_a_row += 1,
        }
    }
    // On a line of its own: the test harness has begun one with the test's name.
    println!("\nclients open: {}", open.len());
    std::io::stdout().flush().unwrap();
    let mut rest = String::new();
    let _ = std::io::stdin().read_to_string(&mut rest);
}

/// This binary again, as the child, opening `count` connections to `addr`; returns it
/// once it has said how many it opened.
fn spawn_clients(addr: SocketAddr, count: usize) -> (Child, usize) {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "the_stream_server_survives_few_file_descriptors",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, format!("{addr} {count}"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start the client process");
    let out = BufReader::new(child.stdout.take().unwrap());
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in out.lines().map_while(Result::ok) {
            if let Some((_, n)) = line.split_once("clients open: ") {
                let _ = tx.send(n.parse::<usize>().unwrap());
            }
        }
    });
    let n = rx
        .recv_timeout(TIMEOUT)
        .expect("the client process opened its connections");
    (child, n)
}

/// Closes the child's stdin (it then closes its connections and exits) and waits.
fn end_clients(mut child: Child) {
    drop(child.stdin.take());
    child.wait().unwrap();
}

/// A message, or `None` when the server closes the connection before sending one.
fn try_read_message(s: &mut TcpStream) -> Option<Message> {
    let mut h = [0u8; HEADER_LEN];
    match s.read_exact(&mut h) {
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::UnexpectedEof | std::io::ErrorKind::ConnectionReset
            ) =>
        {
            return None
        }
        r => r.expect("header"),
    }
    let (_, len) = decode_header(&h).expect("valid header");
    let mut all = h.to_vec();
    all.resize(HEADER_LEN + len as usize, 0);
    s.read_exact(&mut all[HEADER_LEN..]).expect("payload");
    Some(decode(&all).expect("valid message").0)
}

fn read_message(s: &mut TcpStream) -> Message {
    try_read_message(s).expect("a message before the connection closed")
}

/// Publishes frame `n` of the tiny character.
fn publish(slot: &LatestSlot<DeformedFrame>, n: u64) {
    let mut f = DeformedFrame::with_sizes(2, 3, 0);
    f.frame = n;
    slot.publish(Arc::new(f));
}

/// Publishes frames every 10 ms until the server has no more than `clients` clients
/// (clients that hung up are noticed when written to).
fn publish_until_at_most(server: &StreamServer, slot: &LatestSlot<DeformedFrame>, clients: u64) {
    let start = Instant::now();
    let mut n = 1000;
    while server.stats().clients.load(Ordering::Relaxed) > clients {
        assert!(
            start.elapsed() < TIMEOUT,
            "clients that left were not noticed"
        );
        publish(slot, n);
        n += 1;
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Waits until `done()` (bounded).
fn wait_for(what: &str, done: impl Fn() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < TIMEOUT, "{what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn the_stream_server_survives_few_file_descriptors() {
    if let Ok(spec) = std::env::var(CHILD_ENV) {
        return child_clients(&spec);
    }
    let log = common::LogCapture::default();
    tracing::subscriber::set_global_default(log.subscriber(tracing::Level::INFO)).unwrap();
    assert_eq!(set_soft_limit(LIMIT), LIMIT);

    // The default cap: 64 served, the rest refused, no accept fails.
    let slot = Arc::new(LatestSlot::new());
    let server = common::loopback_stream(StreamOutputConfig::default().max_clients, &slot);
    let stats = Arc::clone(server.stats());
    let (clients, opened) = spawn_clients(server.ws_addr().unwrap(), CLIENTS);
    assert_eq!(opened, CLIENTS);
    wait_for("200 connections served or refused", || {
        stats.clients.load(Ordering::Relaxed) + stats.refused.load(Ordering::Relaxed) >= 200
    });
    // One more is told the server is full. While refusals are still in flight (at most
    // 16 at once, each bounded by a second) a newcomer is closed at once with no
    // goodbye: on a slow machine the first tries may meet that, so try again (bounded).
    let since = Instant::now();
    let mut tries = 0u64;
    let told = loop {
        tries += 1;
        let mut extra = TcpStream::connect(server.local_addr().unwrap()).unwrap();
        extra.set_read_timeout(Some(TIMEOUT)).unwrap();
        match try_read_message(&mut extra) {
            Some(m) => break m,
            None => {
                assert!(since.elapsed() < TIMEOUT, "never told the server is full");
                std::thread::sleep(Duration::from_millis(200));
            }
        }
    };
    assert!(
        matches!(&told, Message::Goodbye(r) if r.starts_with("server full")),
        "one more is told the server is full: {told:?}"
    );
    println!(
        "default cap: {} clients, {} refused, {} accept errors",
        stats.clients.load(Ordering::Relaxed),
        stats.refused.load(Ordering::Relaxed),
        stats.accept_errors.load(Ordering::Relaxed)
    );
    assert_eq!(stats.clients.load(Ordering::Relaxed), 64);
    assert_eq!(stats.refused.load(Ordering::Relaxed), 136 + tries);
    assert_eq!(stats.accept_errors.load(Ordering::Relaxed), 0);
    end_clients(clients);
    publish_until_at_most(&server, &slot, 0);
    server.shutdown("phase over");

    // No effective cap: the descriptors run out.
    let slot = Arc::new(LatestSlot::new());
    let server = common::loopback_stream(10_000, &slot);
    let stats = Arc::clone(server.stats());
    let mut served = TcpStream::connect(server.local_addr().unwrap()).unwrap();
    served.set_read_timeout(Some(TIMEOUT)).unwrap();
    assert!(matches!(read_message(&mut served), Message::Topology(_)));
    let (clients, opened) = spawn_clients(server.ws_addr().unwrap(), CLIENTS);
    wait_for("accepts fail", || {
        stats.accept_errors.load(Ordering::Relaxed) > 0
    });
    let (cpu0, errors0, lines0) = (
        cpu_s(),
        stats.accept_errors.load(Ordering::Relaxed),
        log.count("WARN", "accepting a connection failed"),
    );
    let window = Duration::from_secs(3);
    std::thread::sleep(window);
    let (cpu, errors, lines) = (
        cpu_s() - cpu0,
        stats.accept_errors.load(Ordering::Relaxed) - errors0,
        log.count("WARN", "accepting a connection failed") - lines0,
    );
    println!(
        "out of descriptors: the child opened {opened}; {} clients; over {window:?}: {errors} accept errors, {lines} lines, {cpu:.3} s of CPU",
        stats.clients.load(Ordering::Relaxed)
    );
    assert!((1..=40).contains(&errors), "{errors} accept errors");
    assert!(lines <= 4, "{lines} lines");
    assert!(cpu < 0.3, "{cpu:.3} s of CPU in {window:?}");
    // The client it had is still served meanwhile.
    publish(&slot, 1);
    let got = (0..3).find_map(|_| match read_message(&mut served) {
        Message::Frame(f) => Some(f.frame),
        _ => None,
    });
    assert_eq!(got, Some(1));
    // Descriptors free again: a new client is served within the longest wait.
    end_clients(clients);
    publish_until_at_most(&server, &slot, 1);
    let start = Instant::now();
    let mut fresh = TcpStream::connect(server.local_addr().unwrap()).unwrap();
    fresh.set_read_timeout(Some(TIMEOUT)).unwrap();
    assert!(matches!(read_message(&mut fresh), Message::Topology(_)));
    println!(
        "a new client served {:?} after the descriptors came back",
        start.elapsed()
    );
    server.shutdown("test over");
    let all = log.lines();
    println!("{} log lines:\n{}", all.len(), all.join("\n"));
    assert!(all.len() < 20, "{} log lines", all.len());
}
