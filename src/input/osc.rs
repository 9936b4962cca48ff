//! The OSC input (UDP): receives datagrams on a bound address, decodes them with
//! [`crate::protocol::osc`], and hands each packet's markers to a callback (the daemon
//! turns them into samples for its channel; `rigless listen` prints them). Garbage costs
//! only its own packet, and is counted.

use crate::protocol::osc::{OscFrame, OscMapping};
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// What an OSC input has seen (monotonic).
#[derive(Debug, Default)]
pub struct OscStats {
    pub packets: AtomicU64,
    pub bytes: AtomicU64,
    pub decode_errors: AtomicU64,
    /// f64 bits of the Unix time of the newest packet (0 before any).
    pub last_seen_unix_bits: AtomicU64,
}

impl OscStats {
    pub fn last_seen_unix_s(&self) -> f64 {
        f64::from_bits(self.last_seen_unix_bits.load(Ordering::Relaxed))
    }
}

/// Receive buffer asked of the OS, bytes: a second of a 240 Hz, 50-marker sender (each
/// datagram costs the kernel a few KiB of buffer on loopback), so a stalled moment of the
/// receiving thread loses nothing. The OS may grant less (Linux: `net.core.rmem_max`).
pub const RECV_BUFFER_BYTES: usize = 4 << 20;

/// Binds `addr` for an OSC input (a multicast or any-address bind is the caller's
/// choice; the stage default is loopback), with a large receive buffer.
pub fn bind(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    let s = socket2::Socket::new(
        socket2::Domain::for_address(addr),
        socket2::Type::DGRAM,
        Some(socket2::Protocol::UDP),
    )?;
    // Best effort: a smaller grant still works, only with less slack.
    let _ = s.set_recv_buffer_size(RECV_BUFFER_BYTES);
    s.bind(&addr.into())?;
    let s: UdpSocket = s.into();
    s.set_read_timeout(Some(super::UDP_POLL))?;
    Ok(s)
}

/// Receives on `socket` until `stop` is set; calls `on_frame(receive_unix_s, frame)` for
/// every packet that decodes. Runs on the calling thread (a blocking receive with a short
/// timeout: one input, one thread, nothing shared with the solver but the channel).
pub fn run(
    socket: &UdpSocket,
    mapping: &OscMapping,
    stop: &AtomicBool,
    stats: &OscStats,
    on_frame: &mut dyn FnMut(f64, &OscFrame),
) {
    let mut frame = OscFrame::default();
    super::udp_loop(
        socket,
        stop,
        &mut |now, bytes| {
            stats.packets.fetch_add(1, Ordering::Relaxed);
            stats.bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
            stats
                .last_seen_unix_bits
                .store(now.to_bits(), Ordering::Relaxed);
            match mapping.decode_into(bytes, &mut frame) {
                Ok(()) => on_frame(now, &frame),
                Err(_) => {
                    stats.decode_errors.fetch_add(1, Ordering::Relaxed);
                }
            }
        },
        &mut |e| {
            tracing::debug!(error = %e, "osc: receive failed");
            stats.decode_errors.fetch_add(1, Ordering::Relaxed);
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_on_loopback_reach_the_callback_and_garbage_is_counted() {
        let sock = bind("127.0.0.1:0".parse().unwrap()).unwrap();
        let addr = sock.local_addr().unwrap();
        let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
        let good = crate::protocol::osc::encode_native(1, (0, 1), &[("A", glam::DVec3::X)]);
        sender.send_to(b"garbage!", addr).unwrap();
        sender.send_to(&good, addr).unwrap();
        let stop = AtomicBool::new(false);
        let stats = OscStats::default();
        let mut got = Vec::new();
        run(&sock, &OscMapping::default(), &stop, &stats, &mut |_, f| {
            got.push(f.clone());
            stop.store(true, Ordering::Relaxed);
        });
        assert_eq!(got.len(), 1);
        assert_eq!(got[0].markers()[0].name, "A");
        assert_eq!(stats.packets.load(Ordering::Relaxed), 2);
        assert_eq!(stats.decode_errors.load(Ordering::Relaxed), 1);
        assert!(stats.last_seen_unix_s() > 1.6e9);
    }
}
