//! The UDP side shared by the packet inputs (OSC, NatNet): binding with a large receive
//! buffer (joining a multicast group when asked) and the receive loop.

use crate::runtime::clock::unix_now;
use crate::runtime::net::is_wait;
use std::sync::atomic::{AtomicBool, Ordering};

/// How often a blocked UDP receive wakes to check its stop flag.
pub const UDP_POLL: std::time::Duration = std::time::Duration::from_millis(100);

/// Receive buffer asked of the OS for UDP inputs, bytes: a second of a 240 Hz, 50-marker
/// sender (each datagram costs the kernel a few KiB of buffer on loopback), so a stalled
/// moment of the receiving thread loses nothing. The OS may grant less (Linux:
/// `net.core.rmem_max`).
pub const RECV_BUFFER_BYTES: usize = 4 << 20;

/// Binds a UDP input on `addr` with a large receive buffer and the read timeout
/// [`udp_loop`] needs; an IPv4 multicast address binds the port on all interfaces and
/// joins the group there.
pub fn udp_bind(addr: std::net::SocketAddr) -> std::io::Result<std::net::UdpSocket> {
    use std::net::{IpAddr, Ipv4Addr, SocketAddr};
    let s = socket2::Socket::new(
        socket2::Domain::for_address(addr),
        socket2::Type::DGRAM,
        Some(socket2::Protocol::UDP),
    )?;
    // A smaller grant still works, only with less slack.
    if let Err(e) = s.set_recv_buffer_size(RECV_BUFFER_BYTES) {
        tracing::debug!(error = %e, "udp {addr}: the receive buffer stays at the OS default");
    }
    match addr.ip() {
        IpAddr::V4(g) if g.is_multicast() => {
            s.set_reuse_address(true)?;
            s.bind(&SocketAddr::from((Ipv4Addr::UNSPECIFIED, addr.port())).into())?;
            s.join_multicast_v4(&g, &Ipv4Addr::UNSPECIFIED)?;
        }
        _ => s.bind(&addr.into())?,
    }
    let s: std::net::UdpSocket = s.into();
    s.set_read_timeout(Some(UDP_POLL))?;
    Ok(s)
}

/// Receives datagrams on `socket` (which must have a read timeout) until `stop` is set,
/// calling `on_packet(receive_unix_s, sender, bytes)` for each. Timeouts and interruptions are
/// waits; other receive errors (ICMP from an earlier send and the like) go to
/// `on_error` and the loop carries on. One input, one thread.
pub fn udp_loop(
    socket: &std::net::UdpSocket,
    stop: &AtomicBool,
    on_packet: &mut dyn FnMut(f64, std::net::SocketAddr, &[u8]),
    on_error: &mut dyn FnMut(&std::io::Error),
) {
    let mut buf = vec![0u8; 65_536];
    while !stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((n, from)) => {
                on_packet(unix_now(), from, &buf[..n]);
            }
            Err(e) if is_wait(&e) => {}
            Err(e) => {
                on_error(&e);
                std::thread::sleep(UDP_POLL);
            }
        }
    }
}
