//! The OSC input (UDP): receives datagrams on a bound address, decodes them with
//! [`crate::protocol::osc`], and hands each packet's markers to a callback (the daemon
//! turns them into samples for its channel; `rigless listen` prints them). Garbage costs
//! only its own packet, and is counted.

use crate::protocol::osc::{OscFrame, OscMapping};
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::AtomicBool;

/// What an OSC input has seen.
pub type OscStats = super::PacketStats;

/// Binds `addr` for an OSC input ([`super::udp_bind`]).
pub fn bind(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    super::udp_bind(addr)
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
            stats.received(bytes.len(), now);
            match mapping.decode_into(bytes, &mut frame) {
                Ok(()) => on_frame(now, &frame),
                Err(_) => stats.error(),
            }
        },
        &mut |e| {
            tracing::debug!(error = %e, "osc: receive failed");
            stats.error();
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::Ordering;

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
