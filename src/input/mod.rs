//! Input sources that feed marker samples into the daemon's bounded channel.

pub mod glove;
pub mod natnet;
pub mod osc;
pub mod synthetic;
pub mod vrpn;

use crate::markers::MarkerSample;
use crossbeam_channel::{Sender, TrySendError};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// What a running source has done (shared with the status line).
#[derive(Debug, Default)]
pub struct SourceCounters {
    /// Frames sent.
    pub frames: AtomicU64,
    /// Samples sent.
    pub samples: AtomicU64,
    /// Samples dropped because the channel was full.
    pub dropped: AtomicU64,
    /// Set when the session has ended (not looping).
    pub finished: AtomicBool,
    /// When the newest frame arrived, seconds on the source's own clock (`f64` bits).
    last_frame_s: AtomicU64,
    /// The longest interval between consecutive frames since it was last taken, seconds
    /// (`f64` bits; non-negative, so the bits order as the values do).
    longest_interval_s: AtomicU64,
}

impl SourceCounters {
    /// Counts a frame that arrived at `now_s` (seconds on any clock the source keeps
    /// using: only differences are kept).
    pub fn count_frame(&self, now_s: f64) {
        let last = f64::from_bits(self.last_frame_s.swap(now_s.to_bits(), Ordering::Relaxed));
        if self.frames.fetch_add(1, Ordering::Relaxed) > 0 {
            let interval = (now_s - last).max(0.0);
            self.longest_interval_s
                .fetch_max(interval.to_bits(), Ordering::Relaxed);
        }
    }

    /// The longest interval between consecutive frames since the last call, seconds (0
    /// when fewer than two frames arrived).
    pub fn take_longest_interval_s(&self) -> f64 {
        f64::from_bits(self.longest_interval_s.swap(0, Ordering::Relaxed))
    }
}

/// Seconds since the Unix epoch now (0 if the clock is before it): the receive time
/// every input stamps on what it reads.
pub fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

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
    // Best effort: a smaller grant still works, only with less slack.
    let _ = s.set_recv_buffer_size(RECV_BUFFER_BYTES);
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

/// What a packet input has received (monotonic).
#[derive(Debug, Default)]
pub struct PacketStats {
    pub packets: AtomicU64,
    pub bytes: AtomicU64,
    /// Packets that did not decode, and receive errors.
    pub decode_errors: AtomicU64,
    /// f64 bits of the Unix time of the newest packet (0 before any).
    pub last_seen_unix_bits: AtomicU64,
}

impl PacketStats {
    /// Counts one received packet.
    pub fn received(&self, len: usize, unix_s: f64) {
        self.packets.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(len as u64, Ordering::Relaxed);
        self.last_seen_unix_bits
            .store(unix_s.to_bits(), Ordering::Relaxed);
    }

    /// Counts a packet that did not decode, or a receive error.
    pub fn error(&self) {
        self.decode_errors.fetch_add(1, Ordering::Relaxed);
    }

    pub fn last_seen_unix_s(&self) -> f64 {
        f64::from_bits(self.last_seen_unix_bits.load(Ordering::Relaxed))
    }
}

impl std::fmt::Display for PacketStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} packets, {} bytes, {} not decodable",
            self.packets.load(Ordering::Relaxed),
            self.bytes.load(Ordering::Relaxed),
            self.decode_errors.load(Ordering::Relaxed)
        )
    }
}

/// Whether a socket error only means "nothing yet" (a read timeout or an interruption).
pub fn is_wait(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::Interrupted
    )
}

/// Receives datagrams on `socket` (which must have a read timeout) until `stop` is set,
/// calling `on_packet(receive_unix_s, bytes)` for each. Timeouts and interruptions are
/// waits; other receive errors (ICMP from an earlier send and the like) go to
/// `on_error` and the loop carries on. One input, one thread.
pub fn udp_loop(
    socket: &std::net::UdpSocket,
    stop: &AtomicBool,
    on_packet: &mut dyn FnMut(f64, &[u8]),
    on_error: &mut dyn FnMut(&std::io::Error),
) {
    let mut buf = vec![0u8; 65_536];
    while !stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) => {
                on_packet(unix_now(), &buf[..n]);
            }
            Err(e) if is_wait(&e) => {}
            Err(e) => {
                on_error(&e);
                std::thread::sleep(UDP_POLL);
            }
        }
    }
}

/// A source's fixed-rate sending loop: frame `n` (counting across loops) is due at
/// `start_s + n · period_s` on `clock`; `fill(n, t, batch)` makes its samples (stamped
/// `t`), which go out without blocking. It ends after `frames` frames unless `looping`,
/// when `stop` is set, or when the receiver is gone, and marks `counters` finished.
#[allow(clippy::too_many_arguments)]
pub fn play_paced(
    clock: &dyn crate::daemon::clock::Clock,
    start_s: f64,
    period_s: f64,
    frames: usize,
    looping: bool,
    tx: &Sender<MarkerSample>,
    stop: &AtomicBool,
    counters: &SourceCounters,
    fill: &mut dyn FnMut(usize, f64, &mut Vec<MarkerSample>),
) {
    let mut batch = Vec::new();
    let mut n = 0usize;
    while frames > 0 && (looping || n < frames) {
        let t = start_s + n as f64 * period_s;
        clock.sleep_until(t);
        if stop.load(Ordering::Relaxed) {
            break;
        }
        batch.clear();
        fill(n, t, &mut batch);
        if !send_samples(&batch, tx, counters) {
            break;
        }
        counters.count_frame(t);
        n += 1;
    }
    counters.finished.store(true, Ordering::Relaxed);
}

/// Sends one frame's samples without blocking: a full channel drops (and counts) the
/// sample. Returns false once the receiver is gone.
pub fn send_samples(batch: &[MarkerSample], tx: &Sender<MarkerSample>, c: &SourceCounters) -> bool {
    for s in batch {
        match tx.try_send(*s) {
            Ok(()) => {
                c.samples.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Full(_)) => {
                c.dropped.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Disconnected(_)) => return false,
        }
    }
    true
}

/// An input URL, as stage configs and `rigless listen` name inputs.
#[derive(Clone, Debug, PartialEq)]
pub enum InputUrl {
    /// `osc://HOST:PORT`: bind, native schema, address patterns and VMC.
    Osc(std::net::SocketAddr),
    /// `vmc://HOST:PORT`: bind, VMC only.
    Vmc(std::net::SocketAddr),
    /// `natnet://HOST:PORT[?version=M.m&server=IP[:PORT]]`: bind the data port (join the
    /// group when multicast); NatNet 3.0 unless the version says otherwise. With a
    /// server, talk to its command port (1510 by default): connect, take its version and
    /// model definitions, keep a unicast stream alive.
    NatNet(
        std::net::SocketAddr,
        crate::protocol::natnet::Version,
        Option<std::net::SocketAddr>,
    ),
    /// `vrpn://DEVICE@tcp://HOST:PORT` (TCP connection mode) or
    /// `vrpn://DEVICE@HOST[:PORT]` (UDP connection mode; port 3883 by default): a VRPN
    /// server's DEVICE, whose tracker reports are read.
    Vrpn {
        device: String,
        addr: std::net::SocketAddr,
        mode: vrpn::VrpnMode,
    },
    /// `glove:///dev/ttyUSB0[?baud=115200&format=alpha|legacy&max=4095]`: a serial data
    /// glove (8N1; 115200 baud, the alpha encoding and a 4095 full scale by default).
    Glove(glove::GlovePort),
}

/// Parses an input URL, saying what is wrong.
pub fn parse_url(url: &str) -> Result<InputUrl, String> {
    let (scheme, rest) = url.split_once("://").ok_or_else(|| {
        format!("{url:?} is not a URL (expected osc://, vmc://, natnet://HOST:PORT, vrpn://DEVICE@tcp://HOST:PORT or glove:///PORT)")
    })?;
    let (rest, query) = rest.split_once('?').unwrap_or((rest, ""));
    let addr = rest.trim_end_matches('/').parse().map_err(|_| {
        format!("{url:?}: {rest:?} is not HOST:PORT with a numeric host (e.g. 127.0.0.1:9000)")
    });
    match scheme {
        "osc" => Ok(InputUrl::Osc(addr?)),
        "vmc" => Ok(InputUrl::Vmc(addr?)),
        "natnet" => {
            let mut version = crate::protocol::natnet::Version(3, 0);
            let mut server = None;
            for kv in query.split('&').filter(|s| !s.is_empty()) {
                match kv.split_once('=') {
                    Some(("server", v)) => {
                        let with_port = if v.parse::<std::net::SocketAddr>().is_ok() {
                            v.to_owned()
                        } else {
                            format!("{v}:{}", natnet::COMMAND_PORT)
                        };
                        server = Some(with_port.parse().map_err(|_| {
                            format!("{url:?}: server {v:?} is not IP[:PORT] with a numeric IP")
                        })?);
                    }
                    Some(("version", v)) => {
                        let (a, b) = v.split_once('.').unwrap_or((v, "0"));
                        match (a.parse::<u8>(), b.parse::<u8>()) {
                            (Ok(a), Ok(b)) if (3..=4).contains(&a) => {
                                version = crate::protocol::natnet::Version(a, b)
                            }
                            _ => return Err(format!("{url:?}: version {v:?} is not 3.x or 4.x")),
                        }
                    }
                    _ => {
                        return Err(format!(
                        "{url:?}: unknown option {kv:?} (expected version=M.m or server=IP[:PORT])"
                    ))
                    }
                }
            }
            Ok(InputUrl::NatNet(addr?, version, server))
        }
        "vrpn" => {
            let (device, target) = rest.split_once('@').ok_or_else(|| {
                format!("{url:?}: expected vrpn://DEVICE@HOST[:PORT] or vrpn://DEVICE@tcp://HOST:PORT (e.g. vrpn://Tracker0@127.0.0.1)")
            })?;
            if device.is_empty() {
                return Err(format!("{url:?}: no device name before @"));
            }
            let (mode, hp) = match target.strip_prefix("tcp://") {
                Some(hp) => (vrpn::VrpnMode::Tcp, hp.trim_end_matches('/')),
                None => (vrpn::VrpnMode::Udp, target.trim_end_matches('/')),
            };
            let with_port = if hp.parse::<std::net::SocketAddr>().is_ok() {
                hp.to_owned()
            } else {
                format!("{hp}:{}", vrpn::DEFAULT_PORT)
            };
            let addr = with_port
                .parse()
                .map_err(|_| format!("{url:?}: {hp:?} is not HOST[:PORT] with a numeric host"))?;
            Ok(InputUrl::Vrpn {
                device: device.to_owned(),
                addr,
                mode,
            })
        }
        "glove" => {
            use crate::protocol::glove::{GloveFormat, DEFAULT_MAX_VALUE};
            if rest.is_empty() {
                return Err(format!(
                    "{url:?}: no port path (e.g. glove:///dev/ttyUSB0?baud=115200&format=alpha)"
                ));
            }
            let mut port = glove::GlovePort {
                path: rest.into(),
                baud: 115_200,
                format: GloveFormat::Alpha,
                max_value: DEFAULT_MAX_VALUE,
            };
            for kv in query.split('&').filter(|s| !s.is_empty()) {
                match kv.split_once('=') {
                    Some(("baud", v)) => {
                        port.baud = v.parse().ok().filter(|&b| b > 0).ok_or_else(|| {
                            format!("{url:?}: baud {v:?} is not a positive whole number")
                        })?
                    }
                    Some(("format", "alpha")) => port.format = GloveFormat::Alpha,
                    Some(("format", "legacy")) => port.format = GloveFormat::Legacy,
                    Some(("format", v)) => {
                        return Err(format!("{url:?}: format {v:?} is not alpha or legacy"))
                    }
                    Some(("max", v)) => {
                        port.max_value = v.parse().ok().filter(|&m| m > 0).ok_or_else(|| {
                            format!("{url:?}: max {v:?} is not a positive whole number")
                        })?
                    }
                    _ => {
                        return Err(format!(
                            "{url:?}: unknown option {kv:?} (expected baud=, format= or max=)"
                        ))
                    }
                }
            }
            Ok(InputUrl::Glove(port))
        }
        other => Err(format!(
            "{url:?}: unknown scheme {other:?} (expected osc, vmc, natnet, vrpn or glove)"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::natnet::Version;

    #[test]
    fn urls_parse_or_say_why_not() {
        assert_eq!(
            parse_url("osc://127.0.0.1:9000"),
            Ok(InputUrl::Osc("127.0.0.1:9000".parse().unwrap()))
        );
        assert_eq!(
            parse_url("vmc://127.0.0.1:39539/"),
            Ok(InputUrl::Vmc("127.0.0.1:39539".parse().unwrap()))
        );
        assert_eq!(
            parse_url("natnet://239.255.42.99:1511?version=4.1"),
            Ok(InputUrl::NatNet(
                "239.255.42.99:1511".parse().unwrap(),
                Version(4, 1),
                None
            ))
        );
        assert_eq!(
            parse_url("natnet://127.0.0.1:1511?server=10.0.0.5"),
            Ok(InputUrl::NatNet(
                "127.0.0.1:1511".parse().unwrap(),
                Version(3, 0),
                Some("10.0.0.5:1510".parse().unwrap())
            ))
        );
        assert!(parse_url("natnet://127.0.0.1:1511?version=2.9")
            .unwrap_err()
            .contains("3.x or 4.x"));
        assert_eq!(
            parse_url("vrpn://Tracker0@127.0.0.1"),
            Ok(InputUrl::Vrpn {
                device: "Tracker0".into(),
                addr: "127.0.0.1:3883".parse().unwrap(),
                mode: vrpn::VrpnMode::Udp,
            })
        );
        assert_eq!(
            parse_url("vrpn://Spin0@tcp://10.0.0.2:3884"),
            Ok(InputUrl::Vrpn {
                device: "Spin0".into(),
                addr: "10.0.0.2:3884".parse().unwrap(),
                mode: vrpn::VrpnMode::Tcp,
            })
        );
        assert!(parse_url("vrpn://Tracker0@localhost")
            .unwrap_err()
            .contains("numeric host"));
        assert!(parse_url("osc://localhost")
            .unwrap_err()
            .contains("HOST:PORT"));
        assert!(parse_url("ftp://x").unwrap_err().contains("unknown scheme"));
        assert_eq!(
            parse_url("glove:///dev/ttyUSB0?baud=9600&format=legacy&max=1023"),
            Ok(InputUrl::Glove(glove::GlovePort {
                path: "/dev/ttyUSB0".into(),
                baud: 9600,
                format: crate::protocol::glove::GloveFormat::Legacy,
                max_value: 1023,
            }))
        );
        assert_eq!(
            parse_url("glove:///dev/ttyACM1"),
            Ok(InputUrl::Glove(glove::GlovePort {
                path: "/dev/ttyACM1".into(),
                baud: 115_200,
                format: crate::protocol::glove::GloveFormat::Alpha,
                max_value: 4095,
            }))
        );
        assert!(parse_url("glove:///dev/x?format=beta")
            .unwrap_err()
            .contains("not alpha or legacy"));
        assert!(parse_url("glove://").unwrap_err().contains("no port path"));
    }
}
