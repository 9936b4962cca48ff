//! Socket helpers shared by the network inputs and the replay senders.

/// Whether a socket error only means "nothing yet" (a read timeout, a non-blocking socket
/// with nothing to read, or an interruption), not a failure.
pub fn is_wait(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::Interrupted
    )
}

/// The local address a datagram to `peer` leaves from (the interface that reaches it:
/// 127.0.0.1 for a server on loopback), found by connecting a UDP socket, which sends
/// nothing. Sockets that talk to one known peer bind there rather than to every
/// interface.
pub fn local_ip_towards(peer: std::net::SocketAddr) -> std::io::Result<std::net::IpAddr> {
    let any: std::net::SocketAddr = if peer.is_ipv4() {
        ([0, 0, 0, 0], 0).into()
    } else {
        (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
    };
    let probe = std::net::UdpSocket::bind(any)?;
    probe.connect(peer)?;
    Ok(probe.local_addr()?.ip())
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_loopback_peer_is_reached_from_loopback() {
        let ip = super::local_ip_towards("127.0.0.1:1510".parse().unwrap()).unwrap();
        assert_eq!(ip, std::net::IpAddr::from([127, 0, 0, 1]));
    }
}
