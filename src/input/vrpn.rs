//! The VRPN tracker input, TCP connection mode (`vrpn://DEVICE@tcp://HOST:PORT`):
//! connects, exchanges cookies (checking the major version), describes this side's
//! sender and types, reads the device's position reports, answers the server's pings,
//! and reconnects after a drop. Each report becomes a marker named `DEVICE_SENSOR`
//! (stage configs map those names to the character's markers).
//!
//! The codec is [`crate::protocol::vrpn`]; this module owns the socket.

use crate::protocol::vrpn::{
    cookie, decode_message, description_payload, encode_message, parse_cookie, parse_pos_quat,
    Names, PosQuat, COOKIE_LEN, PING, PONG, POS_QUAT, SENDER_DESCRIPTION, TYPE_DESCRIPTION,
};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// What a VRPN input has seen (monotonic).
#[derive(Debug, Default)]
pub struct VrpnStats {
    pub connections: AtomicU64,
    pub messages: AtomicU64,
    pub bytes: AtomicU64,
    pub reports: AtomicU64,
    pub pings_answered: AtomicU64,
    /// Connection attempts that failed, and dropped or broken connections.
    pub errors: AtomicU64,
}

/// Wait between reconnection attempts.
const RECONNECT: Duration = Duration::from_millis(500);
const POLL: Duration = Duration::from_millis(100);

/// This side's ids for its own sender and types (it names them in descriptions).
const OUR_SENDER: i32 = 0;
const OUR_PING: i32 = 0;
const OUR_PONG: i32 = 1;
const OUR_POS_QUAT: i32 = 2;

fn unix_now() -> (f64, u32, u32) {
    let d = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap_or_default();
    (d.as_secs_f64(), d.as_secs() as u32, d.subsec_micros())
}

/// The descriptions this side sends after its cookie.
fn hello(device: &str) -> Vec<u8> {
    let mut out = cookie().to_vec();
    let (_, s, us) = unix_now();
    encode_message(
        &mut out,
        s,
        us,
        OUR_SENDER,
        SENDER_DESCRIPTION,
        &description_payload(device),
    );
    for (id, name) in [(OUR_PING, PING), (OUR_PONG, PONG), (OUR_POS_QUAT, POS_QUAT)] {
        encode_message(
            &mut out,
            s,
            us,
            id,
            TYPE_DESCRIPTION,
            &description_payload(name),
        );
    }
    out
}

/// Serves one connection until it drops or `stop` is set; returns whether to reconnect.
fn session(
    mut sock: TcpStream,
    device: &str,
    stop: &AtomicBool,
    stats: &VrpnStats,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) -> std::io::Result<()> {
    sock.set_read_timeout(Some(POLL))?;
    sock.set_nodelay(true)?;
    sock.write_all(&hello(device))?;
    let mut buf: Vec<u8> = Vec::with_capacity(1 << 16);
    let mut chunk = vec![0u8; 1 << 16];
    let mut cookie_seen = false;
    let mut names = Names::default();
    while !stop.load(Ordering::Relaxed) {
        match sock.read(&mut chunk) {
            Ok(0) => return Ok(()),
            Ok(n) => {
                stats.bytes.fetch_add(n as u64, Ordering::Relaxed);
                buf.extend_from_slice(&chunk[..n]);
            }
            Err(e) if super::is_wait(&e) => continue,
            Err(e) => return Err(e),
        }
        let mut at = 0;
        if !cookie_seen {
            if buf.len() < COOKIE_LEN {
                continue;
            }
            let c: &[u8; COOKIE_LEN] = buf[..COOKIE_LEN].try_into().expect("24 bytes");
            parse_cookie(c).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
            cookie_seen = true;
            at = COOKIE_LEN;
        }
        let mut replies = Vec::new();
        loop {
            let msg = decode_message(&buf[at..])
                .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
            let Some((m, used)) = msg else { break };
            at += used;
            stats.messages.fetch_add(1, Ordering::Relaxed);
            if names
                .observe(&m)
                .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?
            {
                continue;
            }
            let from_device = names.sender(m.sender) == Some(device);
            match names.kind(m.kind) {
                Some(POS_QUAT) if from_device => {
                    if let Some(r) = parse_pos_quat(m.payload) {
                        stats.reports.fetch_add(1, Ordering::Relaxed);
                        let source_s = m.seconds as f64 + m.microseconds as f64 * 1e-6;
                        on_report(unix_now().0, source_s, &r);
                    }
                }
                Some(PING) if from_device => {
                    let (_, s, us) = unix_now();
                    encode_message(&mut replies, s, us, OUR_SENDER, OUR_PONG, &[]);
                    stats.pings_answered.fetch_add(1, Ordering::Relaxed);
                }
                _ => {}
            }
        }
        buf.drain(..at);
        if !replies.is_empty() {
            sock.write_all(&replies)?;
        }
    }
    Ok(())
}

/// Connects to `addr` and serves `device` until `stop` is set, reconnecting after
/// failures and drops; calls `on_report(receive_unix_s, source_unix_s, report)` for
/// every position report of the device. Runs on the calling thread.
pub fn run(
    addr: SocketAddr,
    device: &str,
    stop: &AtomicBool,
    stats: &VrpnStats,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) {
    while !stop.load(Ordering::Relaxed) {
        match TcpStream::connect_timeout(&addr, Duration::from_secs(2)) {
            Ok(sock) => {
                stats.connections.fetch_add(1, Ordering::Relaxed);
                if let Err(e) = session(sock, device, stop, stats, on_report) {
                    tracing::debug!(error = %e, "vrpn: connection lost");
                    stats.errors.fetch_add(1, Ordering::Relaxed);
                }
            }
            Err(e) => {
                tracing::debug!(error = %e, "vrpn: connect failed");
                stats.errors.fetch_add(1, Ordering::Relaxed);
            }
        }
        let until = std::time::Instant::now() + RECONNECT;
        while !stop.load(Ordering::Relaxed) && std::time::Instant::now() < until {
            std::thread::sleep(POLL.min(RECONNECT));
        }
    }
}

/// The marker name of a device's sensor.
pub fn sensor_name(device: &str, sensor: i32) -> String {
    format!("{device}_{sensor}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::vrpn::Message;

    /// A server that describes `Dev` and its types, sends a ping and one report, and
    /// returns what the client sent back.
    #[test]
    fn pings_are_answered_and_reports_delivered() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let server = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().unwrap();
            let mut out = cookie().to_vec();
            encode_message(
                &mut out,
                0,
                0,
                7,
                SENDER_DESCRIPTION,
                &description_payload("Dev"),
            );
            encode_message(
                &mut out,
                0,
                0,
                3,
                TYPE_DESCRIPTION,
                &description_payload(PING),
            );
            encode_message(
                &mut out,
                0,
                0,
                4,
                TYPE_DESCRIPTION,
                &description_payload(POS_QUAT),
            );
            encode_message(&mut out, 1, 0, 7, 3, &[]);
            let r = PosQuat {
                sensor: 3,
                position: glam::DVec3::new(1.0, 2.0, 3.0),
                rotation: [0.0, 0.0, 0.0, 1.0],
            };
            encode_message(
                &mut out,
                2,
                500_000,
                7,
                4,
                &crate::protocol::vrpn::encode_pos_quat(&r),
            );
            s.write_all(&out).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            let mut got = Vec::new();
            let mut chunk = [0u8; 4096];
            // Read until the pong has arrived (bounded by the timeout).
            loop {
                let n = s.read(&mut chunk).unwrap_or(0);
                if n == 0 {
                    break;
                }
                got.extend_from_slice(&chunk[..n]);
                let mut names = Names::default();
                let mut at = COOKIE_LEN.min(got.len());
                let mut pong = false;
                while let Ok(Some((m, used))) = decode_message(&got[at..]) {
                    let m: Message = m;
                    let _ = names.observe(&m);
                    pong |=
                        names.kind(m.kind) == Some(PONG) && names.sender(m.sender) == Some("Dev");
                    at += used;
                }
                if pong {
                    return true;
                }
            }
            false
        });
        let stop = AtomicBool::new(false);
        let stats = VrpnStats::default();
        let mut reports = Vec::new();
        run(addr, "Dev", &stop, &stats, &mut |_, source, r| {
            reports.push((source, *r));
            stop.store(true, Ordering::Relaxed);
        });
        assert_eq!(reports.len(), 1);
        assert_eq!(reports[0].0, 2.5);
        assert_eq!(reports[0].1.sensor, 3);
        assert_eq!(stats.pings_answered.load(Ordering::Relaxed), 1);
        assert!(server.join().unwrap(), "the server got a pong from Dev");
    }
}
