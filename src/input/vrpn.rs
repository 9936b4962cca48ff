//! The VRPN tracker input, in both connection modes of VRPN 07.x:
//!
//! - TCP (`vrpn://DEVICE@tcp://HOST:PORT`): the client connects to the server.
//! - UDP (`vrpn://DEVICE@HOST[:PORT]`): the client listens on a TCP port of its own and
//!   sends `"IP PORT"` datagrams to the server's port until the server calls back; both
//!   sides then describe a UDP port, and the server sends its low-latency messages (the
//!   tracker reports) there as datagrams of whole messages.
//!
//! Either way the client exchanges cookies (checking the major version), describes this
//! side's sender and types, reads the device's position reports, answers the server's
//! pings, and reconnects after a drop. Each report becomes a marker named
//! `DEVICE_SENSOR` (stage configs map those names to the character's markers).
//!
//! A server that has sent nothing for a second is pinged, as VRPN's own clients do, once
//! a second; one that sends no whole message for [`SILENCE_TIMEOUT_S`] (silent, or
//! trickling bytes that never complete one) is given up and connected again. Each
//! kind of reason for a drop (a bad cookie, a message length out of bounds, silence, a
//! refused connect, ...) is said once at warning level, and every drop is counted.
//! Datagrams, and connections to the call-back port, from hosts other than the server's
//! are ignored and counted.
//!
//! The codec is [`crate::protocol::vrpn`]; this module owns the socket.

use super::config::{endpoint_of, VrpnInputConfig, VRPN_SCHEMES};
use super::{InputError, InputFrame, InputSink};
use crate::markers::index::MarkerIndex;
use crate::markers::MarkerSample;
use crate::protocol::url::{Endpoint, VrpnMode};
use crate::protocol::vrpn::{
    cookie, decode_message, description_payload, encode_connection_request, encode_message,
    parse_pos_quat, udp_description, Message, Names, PosQuat, StreamReader, VrpnError, PING, PONG,
    POS_QUAT, SENDER_DESCRIPTION, TYPE_DESCRIPTION, UDP_DESCRIPTION,
};
use crate::runtime::clock::Clock;
use crate::runtime::net::{is_wait, local_ip_towards};
use crate::runtime::said::SaidOnce;
use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, UdpSocket};
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
    /// Connection attempts that failed, and broken connections (a protocol error, a
    /// failed read or write).
    pub errors: AtomicU64,
    /// Connections the server closed.
    pub closed: AtomicU64,
    /// Connections given up because no whole message came for [`SILENCE_TIMEOUT_S`].
    pub silent: AtomicU64,
    /// Datagrams from hosts other than the server's, and connections to the call-back
    /// port from them (ignored).
    pub foreign: AtomicU64,
    /// Datagrams received on the UDP port (UDP connection mode).
    pub datagrams: AtomicU64,
    /// Datagrams that did not hold whole, well-formed messages (dropped).
    pub bad_datagrams: AtomicU64,
    /// f64 bits of the Unix time of the newest bytes from the server (0 before any).
    pub last_seen_unix_bits: AtomicU64,
}

impl VrpnStats {
    /// Counts `n` bytes received now.
    fn received(&self, n: usize) {
        self.bytes.fetch_add(n as u64, Ordering::Relaxed);
        self.last_seen_unix_bits
            .store(unix_now().0.to_bits(), Ordering::Relaxed);
    }

    pub fn last_seen_unix_s(&self) -> f64 {
        f64::from_bits(self.last_seen_unix_bits.load(Ordering::Relaxed))
    }
}

/// Wait between reconnection attempts, seconds.
pub const RECONNECT_S: f64 = 0.5;
const RECONNECT: Duration = Duration::from_millis((RECONNECT_S * 1e3) as u64);
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

/// How often a UDP-mode client repeats its connection request until called back.
const REQUEST_INTERVAL: Duration = Duration::from_millis(1000);

/// How long a UDP-mode session waits on its UDP port before looking at TCP again (TCP
/// carries only descriptions and pings there: this is their latency).
const UDP_WAIT: Duration = Duration::from_millis(2);

/// The cookie and the descriptions this side sends first; in the UDP mode, with the
/// UDP description of `udp_inbound` before them (VRPN's order).
fn hello(device: &str, udp_inbound: Option<SocketAddr>) -> Vec<u8> {
    let mut out = cookie().to_vec();
    let (_, s, us) = unix_now();
    if let Some(a) = udp_inbound {
        let (port, payload) = udp_description(a);
        encode_message(&mut out, s, us, port, UDP_DESCRIPTION, &payload);
    }
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

/// The server's side of one connection as this client reads it: its names, and what to
/// do with each message.
struct Peer<'a> {
    device: &'a str,
    names: Names,
    stats: &'a VrpnStats,
}

impl Peer<'_> {
    /// Handles one message; pongs go to `replies`.
    fn message(
        &mut self,
        m: &Message<'_>,
        replies: &mut Vec<u8>,
        on_report: &mut dyn FnMut(f64, f64, &PosQuat),
    ) -> Result<(), VrpnError> {
        self.stats.messages.fetch_add(1, Ordering::Relaxed);
        if self.names.observe(m)? {
            return Ok(());
        }
        let from_device = self.names.sender(m.sender) == Some(self.device);
        match self.names.kind(m.kind) {
            Some(POS_QUAT) if from_device => {
                if let Some(r) = parse_pos_quat(m.payload) {
                    self.stats.reports.fetch_add(1, Ordering::Relaxed);
                    let source_s = m.seconds as f64 + m.microseconds as f64 * 1e-6;
                    on_report(unix_now().0, source_s, &r);
                }
            }
            Some(PING) if from_device => {
                let (_, s, us) = unix_now();
                encode_message(replies, s, us, OUR_SENDER, OUR_PONG, &[]);
                self.stats.pings_answered.fetch_add(1, Ordering::Relaxed);
            }
            _ => {}
        }
        Ok(())
    }
}

/// Handles one datagram: it holds whole messages; one that does not costs only itself.
fn handle_datagram(
    peer: &mut Peer,
    d: &[u8],
    replies: &mut Vec<u8>,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) {
    let mut at = 0;
    let whole = loop {
        match decode_message(&d[at..]) {
            Ok(Some((m, used))) => {
                at += used;
                if peer.message(&m, replies, on_report).is_err() {
                    break false;
                }
            }
            Ok(None) => break at == d.len(),
            Err(_) => break false,
        }
    };
    if !whole {
        peer.stats.bad_datagrams.fetch_add(1, Ordering::Relaxed);
    }
}

/// Why a VRPN connection ended, or could not be made.
#[derive(Debug, thiserror::Error)]
pub enum VrpnDrop {
    #[error("connecting failed: {source}")]
    Connect { source: std::io::Error },
    #[error("asking the server to call back failed: {source}")]
    Request { source: std::io::Error },
    #[error("the connection failed: {source}")]
    Io { source: std::io::Error },
    #[error("the server broke the protocol: {source}")]
    Protocol { source: VrpnError },
    #[error("the server sent no whole message for {silent_s:.1} s (pings unanswered, or bytes that never complete one)")]
    Silent { silent_s: f64 },
    #[error("the server closed the connection")]
    Closed,
}

/// What makes two [`VrpnDrop`]s the same kind of reason (each kind is said once).
#[derive(Clone, Copy, Debug, PartialEq)]
enum DropKind {
    Connect(std::io::ErrorKind),
    Request(std::io::ErrorKind),
    Io(std::io::ErrorKind),
    Protocol(std::mem::Discriminant<VrpnError>),
    Silent,
    Closed,
    /// A connection from a host other than the server's, to the call-back port.
    Stranger,
}

impl VrpnDrop {
    fn kind(&self) -> DropKind {
        match self {
            VrpnDrop::Connect { source } => DropKind::Connect(source.kind()),
            VrpnDrop::Request { source } => DropKind::Request(source.kind()),
            VrpnDrop::Io { source } => DropKind::Io(source.kind()),
            VrpnDrop::Protocol { source } => DropKind::Protocol(std::mem::discriminant(source)),
            VrpnDrop::Silent { .. } => DropKind::Silent,
            VrpnDrop::Closed => DropKind::Closed,
        }
    }
}

impl From<std::io::Error> for VrpnDrop {
    fn from(source: std::io::Error) -> Self {
        VrpnDrop::Io { source }
    }
}

/// Says each kind of reason for a drop once, at warning level (later ones of a kind at
/// debug level), and counts every one.
struct Reasons<'a> {
    said: SaidOnce<DropKind>,
    device: &'a str,
    addr: SocketAddr,
    stats: &'a VrpnStats,
}

impl<'a> Reasons<'a> {
    fn new(device: &'a str, addr: SocketAddr, stats: &'a VrpnStats) -> Self {
        Self {
            said: SaidOnce::default(),
            device,
            addr,
            stats,
        }
    }

    fn drop(&mut self, e: &VrpnDrop) {
        let counter = match e {
            VrpnDrop::Silent { .. } => &self.stats.silent,
            VrpnDrop::Closed => &self.stats.closed,
            _ => &self.stats.errors,
        };
        counter.fetch_add(1, Ordering::Relaxed);
        let (device, addr) = (self.device, self.addr);
        if self.said.first(e.kind()) {
            tracing::warn!(
                "vrpn {device}@{addr}: {e}; trying again every {} ms (each kind of reason is said once, the rest counted)",
                RECONNECT.as_millis()
            );
        } else {
            tracing::debug!("vrpn {device}@{addr}: {e}");
        }
    }

    /// A connection to the call-back port from `peer`, not the server: closed.
    fn stranger(&mut self, peer: SocketAddr) {
        self.stats.foreign.fetch_add(1, Ordering::Relaxed);
        if self.said.first(DropKind::Stranger) {
            tracing::warn!(
                "vrpn {}@{}: {peer} connected to the call-back port, not the server: closed (said once, the rest counted)",
                self.device,
                self.addr
            );
        }
    }
}

/// How often a client pings a server it has heard nothing from, seconds (as VRPN's own
/// clients do, once a second; a live server answers with a pong).
pub const PING_INTERVAL_S: f64 = 1.0;
/// Seconds without a whole message from the server after which the connection is given
/// up and made again (bytes that do not complete a message do not count: a server that
/// trickles one byte a second is as good as silent).
pub const SILENCE_TIMEOUT_S: f64 = 5.0;

/// What [`Liveness::poll`] says is due.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Due {
    Nothing,
    /// Send the server a ping.
    Ping,
    /// The server has been silent this long: give the connection up.
    Dead {
        silent_s: f64,
    },
}

/// Whether the server at the other end is still there, with time passed in (seconds on
/// a monotonic clock): pinged after [`PING_INTERVAL_S`] of silence and again every
/// interval, given up after [`SILENCE_TIMEOUT_S`].
#[derive(Clone, Debug)]
pub struct Liveness {
    last_heard_s: f64,
    last_ping_s: f64,
}

impl Liveness {
    /// A connection made at `now_s`.
    pub fn new(now_s: f64) -> Self {
        Self {
            last_heard_s: now_s,
            last_ping_s: f64::NEG_INFINITY,
        }
    }

    /// A whole message (or datagram) from the server arrived at `now_s`.
    pub fn heard(&mut self, now_s: f64) {
        self.last_heard_s = now_s;
    }

    pub fn poll(&mut self, now_s: f64) -> Due {
        let silent_s = now_s - self.last_heard_s;
        if silent_s >= SILENCE_TIMEOUT_S {
            Due::Dead { silent_s }
        } else if silent_s >= PING_INTERVAL_S && now_s - self.last_ping_s >= PING_INTERVAL_S {
            self.last_ping_s = now_s;
            Due::Ping
        } else {
            Due::Nothing
        }
    }
}

/// A write to the server that takes longer than this fails the connection.
const WRITE_TIMEOUT: Duration = Duration::from_secs(2);

/// Serves one connection until it drops or `stop` is set (`Ok`). With `udp` (the UDP
/// connection mode) datagrams on that socket are read too, from the server's host only;
/// each must hold whole messages. A server silent for [`SILENCE_TIMEOUT_S`] is given up.
fn session(
    mut sock: TcpStream,
    udp: Option<&UdpSocket>,
    device: &str,
    stop: &AtomicBool,
    stats: &VrpnStats,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) -> Result<(), VrpnDrop> {
    let server_ip = sock.peer_addr()?.ip();
    sock.set_nodelay(true)?;
    sock.set_write_timeout(Some(WRITE_TIMEOUT))?;
    sock.write_all(&hello(device, udp.map(|u| u.local_addr()).transpose()?))?;
    match udp {
        // TCP is only polled; the UDP port is where reports arrive and where we wait.
        Some(u) => {
            sock.set_nonblocking(true)?;
            u.set_read_timeout(Some(UDP_WAIT))?;
        }
        None => sock.set_read_timeout(Some(POLL))?,
    }
    let started = std::time::Instant::now();
    let now_s = || started.elapsed().as_secs_f64();
    let mut alive = Liveness::new(now_s());
    let mut reader = StreamReader::default();
    let mut chunk = vec![0u8; 1 << 16];
    let mut peer = Peer {
        device,
        names: Names::default(),
        stats,
    };
    let mut replies = Vec::new();
    let mut datagram = vec![0u8; 1 << 16];
    // A datagram from the server's host, or `None` (nothing, another host's, an error).
    let from_server = |u: &UdpSocket, d: &mut [u8]| match u.recv_from(d) {
        Ok((n, from)) if from.ip() == server_ip => {
            stats.datagrams.fetch_add(1, Ordering::Relaxed);
            stats.received(n);
            Some(n)
        }
        Ok(_) => {
            stats.foreign.fetch_add(1, Ordering::Relaxed);
            None
        }
        Err(e) if is_wait(&e) => None,
        // ICMP from an earlier send and the like: the datagram is lost.
        Err(e) => {
            tracing::debug!(error = %e, "vrpn: udp receive");
            None
        }
    };
    while !stop.load(Ordering::Relaxed) {
        replies.clear();
        match alive.poll(now_s()) {
            Due::Dead { silent_s } => return Err(VrpnDrop::Silent { silent_s }),
            Due::Ping => {
                let (_, s, us) = unix_now();
                encode_message(&mut replies, s, us, OUR_SENDER, OUR_PING, &[]);
            }
            Due::Nothing => {}
        }
        // Wait on the UDP port (UDP mode) or on TCP.
        let got_datagram = udp.and_then(|u| from_server(u, &mut datagram));
        if got_datagram.is_some() {
            alive.heard(now_s());
        }
        // TCP first: the descriptions a datagram's messages refer to came that way.
        match sock.read(&mut chunk) {
            Ok(0) => {
                // The server hung up: what it sent last over UDP may still be on its way.
                if let Some(u) = udp {
                    if let Some(n) = got_datagram {
                        handle_datagram(&mut peer, &datagram[..n], &mut replies, on_report);
                    }
                    while let Some(n) = from_server(u, &mut datagram) {
                        handle_datagram(&mut peer, &datagram[..n], &mut replies, on_report);
                    }
                }
                return Err(VrpnDrop::Closed);
            }
            Ok(n) => {
                stats.received(n);
                let mut whole = 0usize;
                reader
                    .feed(&chunk[..n], &mut |m| {
                        whole += 1;
                        peer.message(m, &mut replies, on_report)
                    })
                    .map_err(|source| VrpnDrop::Protocol { source })?;
                if whole > 0 {
                    alive.heard(now_s());
                }
            }
            Err(e) if is_wait(&e) => {}
            Err(e) => return Err(e.into()),
        }
        if let Some(n) = got_datagram {
            handle_datagram(&mut peer, &datagram[..n], &mut replies, on_report);
        }
        if !replies.is_empty() {
            if udp.is_some() {
                sock.set_nonblocking(false)?;
                sock.write_all(&replies)?;
                sock.set_nonblocking(true)?;
            } else {
                sock.write_all(&replies)?;
            }
        }
    }
    Ok(())
}

/// A connection made by a [`run`] loop: the TCP stream, and the UDP port of the UDP
/// connection mode.
type Connected = (TcpStream, Option<UdpSocket>);

/// Makes connections with `connect` (`Ok(None)`: `stop` was set while waiting) and
/// serves them until `stop` is set, waiting [`RECONNECT`] after each failure or drop;
/// each kind of reason is said once ([`Reasons`]).
fn reconnecting(
    addr: SocketAddr,
    device: &str,
    stop: &AtomicBool,
    stats: &VrpnStats,
    connect: &mut dyn FnMut(&mut Reasons) -> Result<Option<Connected>, VrpnDrop>,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) {
    let mut reasons = Reasons::new(device, addr, stats);
    while !stop.load(Ordering::Relaxed) {
        let ended = match connect(&mut reasons) {
            Ok(Some((sock, udp))) => {
                stats.connections.fetch_add(1, Ordering::Relaxed);
                session(sock, udp.as_ref(), device, stop, stats, on_report)
            }
            Ok(None) => Ok(()),
            Err(e) => Err(e),
        };
        if let Err(e) = ended {
            reasons.drop(&e);
        }
        let until = std::time::Instant::now() + RECONNECT;
        while !stop.load(Ordering::Relaxed) && std::time::Instant::now() < until {
            std::thread::sleep(POLL.min(RECONNECT));
        }
    }
}

/// Connects to `addr` and serves `device` until `stop` is set, reconnecting after
/// failures, drops and [`SILENCE_TIMEOUT_S`] of silence; calls `on_report(receive_unix_s,
/// source_unix_s, report)` for every position report of the device. Runs on the calling
/// thread.
pub fn run(
    addr: SocketAddr,
    device: &str,
    stop: &AtomicBool,
    stats: &VrpnStats,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) {
    let mut connect = |_: &mut Reasons| match TcpStream::connect_timeout(&addr, CONNECT_TIMEOUT) {
        Ok(sock) => Ok(Some((sock, None))),
        Err(source) => Err(VrpnDrop::Connect { source }),
    };
    reconnecting(addr, device, stop, stats, &mut connect, on_report);
}

/// How long a TCP connect may take.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);

/// [`run`] or [`run_udp`], as `mode` says.
pub fn run_mode(
    mode: VrpnMode,
    addr: SocketAddr,
    device: &str,
    stop: &AtomicBool,
    stats: &VrpnStats,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) {
    match mode {
        VrpnMode::Tcp => run(addr, device, stop, stats, on_report),
        VrpnMode::Udp => run_udp(addr, device, stop, stats, on_report),
    }
}

/// The UDP connection mode: asks the server at `server` (its UDP port, the same number
/// as its TCP port) to call back, serves the connection it makes, and asks again after
/// a drop or silence, until `stop` is set. Reports arrive on this side's UDP port (or
/// over TCP if the server prefers); `on_report` as for [`run`].
pub fn run_udp(
    server: SocketAddr,
    device: &str,
    stop: &AtomicBool,
    stats: &VrpnStats,
    on_report: &mut dyn FnMut(f64, f64, &PosQuat),
) {
    let mut connect = |reasons: &mut Reasons| {
        call_back(server, stop, reasons).map(|c| c.map(|(sock, udp)| (sock, Some(udp))))
    };
    reconnecting(server, device, stop, stats, &mut connect, on_report);
}

/// Opens this side's TCP and UDP ports on the interface that reaches `server`, and sends
/// connection requests every [`REQUEST_INTERVAL`] until the server connects (or `stop`).
/// Connections from other hosts are closed.
fn call_back(
    server: SocketAddr,
    stop: &AtomicBool,
    reasons: &mut Reasons,
) -> Result<Option<(TcpStream, UdpSocket)>, VrpnDrop> {
    let request_failed = |source| VrpnDrop::Request { source };
    // The local address a datagram to the server leaves from is the one it can call back.
    let ip = local_ip_towards(server).map_err(request_failed)?;
    let lob = UdpSocket::bind((ip, 0)).map_err(request_failed)?;
    lob.connect(server).map_err(request_failed)?;
    let listener = TcpListener::bind((ip, 0))?;
    listener.set_nonblocking(true)?;
    let udp = UdpSocket::bind((ip, 0))?;
    let request = encode_connection_request(listener.local_addr()?);
    while !stop.load(Ordering::Relaxed) {
        // A send can fail with the ICMP error of the one before (nobody was on the
        // server's port yet): that consumes the error, so send once more.
        if let Err(source) = lob.send(&request).or_else(|_| lob.send(&request)) {
            reasons.drop(&VrpnDrop::Request { source });
        }
        let until = std::time::Instant::now() + REQUEST_INTERVAL;
        while std::time::Instant::now() < until && !stop.load(Ordering::Relaxed) {
            match listener.accept() {
                Ok((_, peer)) if peer.ip() != server.ip() => reasons.stranger(peer),
                Ok((sock, _)) => {
                    sock.set_nonblocking(false)?;
                    return Ok(Some((sock, udp)));
                }
                Err(e) if is_wait(&e) => std::thread::sleep(Duration::from_millis(10)),
                Err(e) => return Err(e.into()),
            }
        }
    }
    Ok(None)
}

/// The marker name of a device's sensor.
pub fn sensor_name(device: &str, sensor: i32) -> String {
    format!("{device}_{sensor}")
}

/// Most sensors whose marker index a VRPN input remembers (sensor numbers come from the
/// network; beyond this many, names are resolved report by report).
const MAX_CACHED_SENSORS: usize = 1024;

/// An opened VRPN input: a server's tracker device and how sensors name markers.
pub struct VrpnInput {
    device: String,
    addr: SocketAddr,
    mode: VrpnMode,
    sensors: BTreeMap<String, String>,
    index: MarkerIndex,
}

impl VrpnInput {
    /// Reads `cfg.url` (the connection is made when it runs, and made again after a
    /// drop).
    pub fn open(cfg: &VrpnInputConfig, index: MarkerIndex) -> Result<Self, InputError> {
        let endpoint = endpoint_of(&cfg.url, VRPN_SCHEMES).map_err(|source| InputError::Url {
            url: cfg.url.clone(),
            source,
        })?;
        let Endpoint::Vrpn { device, addr, mode } = endpoint else {
            unreachable!("endpoint_of checked the scheme")
        };
        Ok(Self {
            device,
            addr,
            mode,
            sensors: cfg.sensors.clone(),
            index,
        })
    }

    /// `vrpn input connecting to ADDR for DEVICE (...)`.
    pub fn opened(&self) -> String {
        let (addr, device) = (self.addr, &self.device);
        match self.mode {
            VrpnMode::Tcp => {
                format!("vrpn input connecting to {addr} for {device} (reconnects by itself)")
            }
            VrpnMode::Udp => format!(
                "vrpn input asking {addr} (UDP) to call back for {device} (asks again after a drop)"
            ),
        }
    }

    /// The marker index of a sensor: its name from the config's `sensors`, or
    /// `DEVICE_SENSOR` (on a stage of several actors, behind `DEVICE:`).
    fn marker_of(&mut self, sensor: i32) -> Option<u32> {
        let mut name = self
            .sensors
            .get(&sensor.to_string())
            .cloned()
            .unwrap_or_else(|| sensor_name(&self.device, sensor));
        // On a stage of several actors the tracker is the subject (an actor's `subject`
        // names the tracker), unless the sensor's name has its own.
        if self.index.is_for_actors() && !name.contains(':') {
            name = format!("{}:{name}", self.device);
        }
        self.index.resolve(&name)
    }

    /// Reads reports until `stop` is set; returns what it received.
    pub fn run(mut self, clock: &dyn Clock, stop: &AtomicBool, sink: &mut dyn InputSink) -> String {
        let stats = VrpnStats::default();
        let (mode, addr, device) = (self.mode, self.addr, self.device.clone());
        let mut by_sensor: HashMap<i32, Option<u32>> = HashMap::new();
        run_mode(mode, addr, &device, stop, &stats, &mut |recv, source, r| {
            let t = clock.now_s();
            let k = match by_sensor.get(&r.sensor) {
                Some(k) => *k,
                None => {
                    let k = self.marker_of(r.sensor);
                    if by_sensor.len() < MAX_CACHED_SENSORS {
                        by_sensor.insert(r.sensor, k);
                    }
                    k
                }
            };
            let sample = k.map(|marker| MarkerSample {
                marker,
                time_s: t,
                source_time_s: source,
                position_m: r.position,
                occluded: !r.position.is_finite(),
            });
            let frame = InputFrame {
                time_s: t,
                receive_unix_s: recv,
                source_time_s: Some(source),
                frame: None,
                samples: sample.as_slice(),
                names: self.index.names(),
            };
            if !sink.frame(&frame) {
                stop.store(true, Ordering::Relaxed);
            }
        });
        let n = |c: &AtomicU64| c.load(Ordering::Relaxed);
        let summary = format!(
            "{} connections ({} closed by the server, {} given up as silent), {} messages, {} bytes, {} reports, {} pings answered, {} errors, {} datagrams ({} bad), {} ignored (not from the server)",
            n(&stats.connections),
            n(&stats.closed),
            n(&stats.silent),
            n(&stats.messages),
            n(&stats.bytes),
            n(&stats.reports),
            n(&stats.pings_answered),
            n(&stats.errors),
            n(&stats.datagrams),
            n(&stats.bad_datagrams),
            n(&stats.foreign)
        );
        super::with_refused(summary, &self.index)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::vrpn::Message;

    /// A server's greeting: the cookie, sender 7 named `Dev`, type 4 the position
    /// report.
    fn greeting() -> Vec<u8> {
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
            4,
            TYPE_DESCRIPTION,
            &description_payload(POS_QUAT),
        );
        out
    }

    /// Appends `Dev`'s report of `sensor` at `position`, stamped `secs.usecs`.
    fn report(out: &mut Vec<u8>, sensor: i32, position: glam::DVec3, secs: u32, usecs: u32) {
        let r = PosQuat {
            sensor,
            position,
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        encode_message(
            out,
            secs,
            usecs,
            7,
            4,
            &crate::protocol::vrpn::encode_pos_quat(&r),
        );
    }

    /// The greeting and one report of `Dev`'s sensor `sensor`.
    fn greeting_and_report(sensor: i32) -> Vec<u8> {
        let mut out = greeting();
        report(&mut out, sensor, glam::DVec3::new(0.1, 0.2, 0.3), 1, 0);
        out
    }

    /// A server that drops the connection after one report: the client counts the drop,
    /// waits [`RECONNECT_S`], connects again and reads the next connection's report.
    #[test]
    fn a_dropped_server_is_connected_again() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let server = std::thread::spawn(move || {
            for sensor in [1, 2] {
                let (mut s, _) = listener.accept().unwrap();
                s.write_all(&greeting_and_report(sensor)).unwrap();
                // What the client sent (its cookie, its descriptions) is read before the
                // close, which is then an orderly one (unread bytes would make it a reset).
                s.set_read_timeout(Some(Duration::from_millis(200)))
                    .unwrap();
                let mut chunk = [0u8; 4096];
                while matches!(s.read(&mut chunk), Ok(n) if n > 0) {}
                // Closed at the end of the loop body: the drop.
                if sensor == 2 {
                    // Held open until the client has read the report and stopped.
                    std::thread::sleep(Duration::from_millis(500));
                }
            }
        });
        let stop = AtomicBool::new(false);
        let stats = VrpnStats::default();
        let mut sensors = Vec::new();
        let started = std::time::Instant::now();
        run(addr, "Dev", &stop, &stats, &mut |_, _, r| {
            sensors.push(r.sensor);
            if r.sensor == 2 {
                stop.store(true, Ordering::Relaxed);
            }
        });
        server.join().unwrap();
        assert_eq!(sensors, [1, 2]);
        assert_eq!(stats.connections.load(Ordering::Relaxed), 2);
        assert_eq!(stats.closed.load(Ordering::Relaxed), 1);
        assert_eq!(stats.errors.load(Ordering::Relaxed), 0);
        // The second connection waited out the pause after the drop, and no more.
        let took = started.elapsed().as_secs_f64();
        assert!((RECONNECT_S..RECONNECT_S + 3.0).contains(&took), "{took} s");
    }

    /// Time passed in: a ping after a second of silence and every second after, none
    /// while the server talks, and the connection given up at five seconds.
    #[test]
    fn liveness_pings_a_quiet_server_and_gives_up_a_silent_one() {
        let mut l = Liveness::new(10.0);
        assert_eq!(l.poll(10.5), Due::Nothing);
        assert_eq!(l.poll(11.0), Due::Ping);
        assert_eq!(l.poll(11.5), Due::Nothing);
        assert_eq!(l.poll(12.0), Due::Ping);
        l.heard(12.25);
        assert_eq!(l.poll(13.0), Due::Nothing);
        assert_eq!(l.poll(13.25), Due::Ping);
        assert_eq!(l.poll(17.0), Due::Ping);
        assert_eq!(l.poll(17.25), Due::Dead { silent_s: 5.0 });
    }

    /// A server that describes `Dev` and its types, sends a ping and one report, and
    /// returns what the client sent back.
    #[test]
    fn pings_are_answered_and_reports_delivered() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let server = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().unwrap();
            let mut out = greeting();
            encode_message(
                &mut out,
                0,
                0,
                3,
                TYPE_DESCRIPTION,
                &description_payload(PING),
            );
            encode_message(&mut out, 1, 0, 7, 3, &[]);
            report(&mut out, 3, glam::DVec3::new(1.0, 2.0, 3.0), 2, 500_000);
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
                let mut at = crate::protocol::vrpn::COOKIE_LEN.min(got.len());
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
