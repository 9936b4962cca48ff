//! The NatNet input (OptiTrack Motive's data stream, UDP): binds the data port (joining the
//! group when the address is multicast), decodes frames of mocap data with
//! [`crate::protocol::natnet`], and hands each frame's markers to a callback. With the
//! server's address it also talks to the command port ([`CommandClient`]): connects,
//! learns the server's NatNet version, asks for the model definitions (marker names), and
//! keeps a unicast stream alive.
//!
//! What comes from the network is checked before it changes anything: server info and
//! model definitions are believed only from the server's command port, on the command
//! socket (bound to the interface that reaches the server); a version the server states
//! is on trial until a frame decodes with it, and frames that decode only with the
//! version before send the client back to that one, said once. Every other problem is
//! said once per kind and counted.
//!
//! Marker names: with model definitions, a marker set's markers are `SET:NAME` and a
//! labelled marker of a rigid body is `BODY:NAME` (its marker set's names, by member);
//! without them a marker set's markers are `SET_1`, `SET_2`, ... in the set's order (the
//! names Motive itself gives the members of its `all` set) and labelled markers
//! `ASSET_MEMBER`. The `all` set is skipped as a duplicate; a frame without marker sets
//! gives its labelled markers. A member is occluded when a labelled marker at its very
//! position is flagged occluded (Motive repeats the member's position there).

use super::config::{endpoint_of, NatNetInputConfig, NATNET_SCHEMES};
use super::{InputError, InputFrame, InputSink};
use crate::markers::index::MarkerIndex;
use crate::markers::MarkerSample;
use crate::protocol::natnet::{
    decode, encode_connect, encode_keepalive, encode_request_modeldef, Description, Message,
    MocapFrame, NatNetError, ServerInfo, Version,
};
use crate::protocol::url::Endpoint;
use crate::runtime::clock::{unix_now, Clock};
use crate::runtime::net::{is_wait, local_ip_towards};
use crate::runtime::said::SaidOnce;
use glam::DVec3;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// What a NatNet input has seen (monotonic).
#[derive(Debug, Default)]
pub struct NatNetStats {
    pub packets: super::PacketStats,
    /// Frames of mocap data among them.
    pub frames: AtomicU64,
    /// Packets of other kinds (model definitions, server info, pings).
    pub other: AtomicU64,
    /// Server info and model definitions that did not come from the server's command
    /// port (ignored), and packets on the command socket from anyone but the server.
    pub foreign: AtomicU64,
    /// With a server given: frames from another sender than the stream's (the first
    /// that sent frames from the server's host), among `frames`; taken, or dropped with
    /// [`CommandClient::strict_source`].
    pub frames_elsewhere: AtomicU64,
}

/// One marker of a frame, named.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedMarker {
    pub name: String,
    pub position_m: DVec3,
    pub occluded: bool,
}

/// Marker names from the server's model definitions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelNames {
    /// Marker set name to its markers' names, in order.
    pub sets: std::collections::HashMap<String, Vec<String>>,
    /// Rigid body (asset) id to its name.
    pub bodies: std::collections::HashMap<i32, String>,
}

impl ModelNames {
    pub fn from_descriptions(d: &[Description]) -> Self {
        let mut n = Self::default();
        for x in d {
            match x {
                Description::MarkerSet { name, markers } => {
                    n.sets.insert(name.clone(), markers.clone());
                }
                Description::RigidBody { name, id, .. } => {
                    n.bodies.insert(*id, name.clone());
                }
                Description::Skeleton { .. } => {}
            }
        }
        n
    }

    /// The name of member `k` (0-based) of marker set `set`, if described.
    fn member(&self, set: &str, k: usize) -> Option<String> {
        self.sets
            .get(set)
            .and_then(|m| m.get(k))
            .map(|m| format!("{set}:{m}"))
    }

    /// The name of a labelled marker (asset id, 1-based member), if described.
    fn labelled(&self, asset: u16, member: u16) -> Option<String> {
        let body = self.bodies.get(&i32::from(asset))?;
        Some(
            self.member(body, usize::from(member).checked_sub(1)?)
                .unwrap_or_else(|| format!("{body}_{member}")),
        )
    }
}

/// Binds the data port `addr` ([`super::udp::udp_bind`]: a multicast address joins the
/// group).
pub fn bind(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    super::udp::udp_bind(addr)
}

/// An opened NatNet input: its data socket, and the server's command port if known.
pub struct NatNetInput {
    url: String,
    socket: UdpSocket,
    data: SocketAddr,
    version: Version,
    /// The server's command port and the socket that talks to it.
    server: Option<(SocketAddr, UdpSocket)>,
    /// Drop frames from any sender but the stream's ([`CommandClient::strict_source`]).
    strict_source: bool,
    index: MarkerIndex,
}

impl NatNetInput {
    /// Binds the data port of `cfg.url` (joining a multicast group).
    pub fn open(cfg: &NatNetInputConfig, index: MarkerIndex) -> Result<Self, InputError> {
        let endpoint = endpoint_of(&cfg.url, NATNET_SCHEMES).map_err(|source| InputError::Url {
            url: cfg.url.clone(),
            source,
        })?;
        let Endpoint::NatNet {
            data,
            version,
            server,
        } = endpoint
        else {
            unreachable!("endpoint_of checked the scheme")
        };
        let socket = bind(data).map_err(|source| InputError::Bind {
            url: cfg.url.clone(),
            source,
        })?;
        let server = match server {
            Some(s) => Some((
                s,
                command_socket(s).map_err(|source| InputError::CommandSocket {
                    url: cfg.url.clone(),
                    source,
                })?,
            )),
            None => None,
        };
        Ok(Self {
            url: cfg.url.clone(),
            socket,
            data,
            version,
            server,
            strict_source: cfg.strict_source,
            index,
        })
    }

    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.socket.local_addr().ok()
    }

    /// `natnet input listening on udp://ADDR (NatNet M.m)`, and the command port.
    pub fn opened(&self) -> String {
        let bound = self
            .local_addr()
            .map_or_else(|| self.data.to_string(), |a| a.to_string());
        let Version(major, minor) = self.version;
        match &self.server {
            Some((server, _)) => format!("natnet input listening on udp://{bound} (NatNet {major}.{minor}); version and marker names from the server's command port {server}"),
            None => format!("natnet input listening on udp://{bound} (NatNet {major}.{minor})"),
        }
    }

    /// Receives until `stop` is set; returns what it received.
    pub fn run(
        mut self,
        clock: &dyn Clock,
        stop: &AtomicBool,
        sink: &mut dyn InputSink,
    ) -> Result<String, InputError> {
        let stats = NatNetStats::default();
        let (mut named, mut batch) = (Vec::new(), Vec::new());
        let index = &mut self.index;
        let mut on_frame = |recv: f64, f: &MocapFrame, names: &ModelNames| {
            let t = clock.now_s();
            named.clear();
            markers_of(f, names, &mut named);
            batch.clear();
            for m in &named {
                if let Some(k) = index.resolve(&m.name) {
                    batch.push(MarkerSample {
                        marker: k,
                        time_s: t,
                        source_time_s: f.timestamp_s,
                        position_m: m.position_m,
                        occluded: m.occluded,
                    });
                }
            }
            let frame = InputFrame {
                time_s: t,
                receive_unix_s: recv,
                source_time_s: Some(f.timestamp_s),
                frame: Some(i64::from(f.frame)),
                samples: &batch,
                names: index.names(),
            };
            if !sink.frame(&frame) {
                stop.store(true, Ordering::Relaxed);
            }
        };
        match &self.server {
            Some((server, command)) => {
                let unicast = !self.data.ip().is_multicast();
                let mut client = CommandClient::new(self.version, unicast);
                client.strict_source = self.strict_source;
                run_with_server(
                    &self.socket,
                    command,
                    *server,
                    &mut client,
                    stop,
                    &stats,
                    &mut on_frame,
                )
                .map_err(|source| InputError::Receive {
                    url: self.url.clone(),
                    source,
                })?;
            }
            None => {
                let empty = ModelNames::default();
                run(&self.socket, self.version, stop, &stats, &mut |recv, f| {
                    on_frame(recv, f, &empty)
                });
            }
        }
        Ok(super::with_refused(
            format!(
                "{}; {} frames ({} from another sender than the stream's), {} other messages, {} ignored (not from the server)",
                stats.packets,
                stats.frames.load(Ordering::Relaxed),
                stats.frames_elsewhere.load(Ordering::Relaxed),
                stats.other.load(Ordering::Relaxed),
                stats.foreign.load(Ordering::Relaxed)
            ),
            &self.index,
        ))
    }
}

/// The named markers of a frame, appended to `out` (names from `names` where they
/// describe it, see the module doc). Without marker sets (Motive can stream labelled
/// markers only), the labelled markers come out.
pub fn markers_of(f: &MocapFrame, names: &ModelNames, out: &mut Vec<NamedMarker>) {
    let start = out.len();
    for (set, ps) in &f.marker_sets {
        if set.eq_ignore_ascii_case("all") {
            continue;
        }
        for (k, p) in ps.iter().enumerate() {
            // Motive repeats an occluded member's position in the labelled list, flagged.
            let occluded =
                f.labeled.iter().any(|m| m.occluded && m.position_m == *p) || !p.is_finite();
            out.push(NamedMarker {
                name: names
                    .member(set, k)
                    .unwrap_or_else(|| format!("{set}_{}", k + 1)),
                position_m: if occluded { DVec3::NAN } else { p.as_dvec3() },
                occluded,
            });
        }
    }
    if out.len() == start {
        // Asset 0 is no asset: Motive lists unlabelled (passive) markers among the
        // labelled ones with model id 0 and a point id (`0_50007`), which changes as
        // points come and go; they are no marker's.
        for m in f.labeled.iter().filter(|m| m.asset_id != 0) {
            out.push(NamedMarker {
                name: names
                    .labelled(m.asset_id, m.member_id)
                    .unwrap_or_else(|| format!("{}_{}", m.asset_id, m.member_id)),
                position_m: if m.occluded {
                    DVec3::NAN
                } else {
                    m.position_m.as_dvec3()
                },
                occluded: m.occluded,
            });
        }
    }
}

/// How often the command client repeats an unanswered request, and sends a unicast
/// keep-alive, seconds.
pub const COMMAND_INTERVAL_S: f64 = 1.0;

/// The client side of the command port, as a state machine with time passed in: which
/// packet to send when, and what the server's answers mean.
#[derive(Clone, Debug)]
pub struct CommandClient {
    /// Ask for this version until the server says which it speaks.
    pub version: Version,
    /// Send keep-alives (the data arrives unicast).
    pub unicast: bool,
    /// The server's answer to the connect request, once it came.
    pub server: Option<ServerInfo>,
    pub names: Option<ModelNames>,
    /// Drop frames from any sender but the stream's (the first to send frames from the
    /// server's host); by default they are taken, counted and said once.
    pub strict_source: bool,
    /// The stream's sender, once a frame came from the server's host.
    sender: Option<SocketAddr>,
    /// While no frame has decoded with the version the server stated: the version
    /// frames were decoded with before it.
    on_trial_from: Option<Version>,
    /// Frames in a row that decoded only with `on_trial_from`.
    misfits: u32,
    /// A stated version frames did not decode with: stating it again changes nothing.
    refused: Option<Version>,
    last_connect_s: f64,
    last_request_s: f64,
    last_keepalive_s: f64,
}

/// Frames in a row that decode only with the version before the one the server stated,
/// after which the client goes back to it for good.
pub const FALLBACK_FRAMES: u32 = 3;

/// The client went back to the version it decoded frames with before the server stated
/// another (see [`CommandClient::decode`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FellBack {
    /// The version the server stated, that frames did not decode with.
    pub stated: Version,
    /// The version frames decode with, used from now on.
    pub kept: Version,
}

impl CommandClient {
    pub fn new(version: Version, unicast: bool) -> Self {
        Self {
            version,
            unicast,
            server: None,
            names: None,
            strict_source: false,
            sender: None,
            on_trial_from: None,
            misfits: 0,
            refused: None,
            last_connect_s: f64::NEG_INFINITY,
            last_request_s: f64::NEG_INFINITY,
            last_keepalive_s: f64::NEG_INFINITY,
        }
    }

    /// What to send at time `now_s`, if anything: a connect request until the server
    /// answers, then a model-definition request until they come, and (unicast) a
    /// keep-alive every [`COMMAND_INTERVAL_S`].
    pub fn poll(&mut self, now_s: f64) -> Option<Vec<u8>> {
        let due = |last: f64| now_s - last >= COMMAND_INTERVAL_S;
        if self.server.is_none() {
            if due(self.last_connect_s) {
                self.last_connect_s = now_s;
                return Some(encode_connect(self.version));
            }
            return None;
        }
        if self.names.is_none() && due(self.last_request_s) {
            self.last_request_s = now_s;
            return Some(encode_request_modeldef().to_vec());
        }
        if self.unicast && due(self.last_keepalive_s) {
            self.last_keepalive_s = now_s;
            return Some(encode_keepalive().to_vec());
        }
        None
    }

    /// Takes in a message from the server's command port (the caller checks where it
    /// came from); true when it changed what the client knows. A stated version other
    /// than the one in use is on trial until a frame decodes with it (see
    /// [`Self::decode`]).
    pub fn on_message(&mut self, m: &Message) -> bool {
        match m {
            Message::ServerInfo(info) => {
                let v = info.natnet;
                if (3..=4).contains(&v.0) && v != self.version && Some(v) != self.refused {
                    self.on_trial_from = match self.on_trial_from {
                        Some(before) if before == v => None,
                        Some(before) => Some(before),
                        None => Some(self.version),
                    };
                    self.version = v;
                    self.misfits = 0;
                }
                let fresh = self.server.as_ref() != Some(info);
                self.server = Some(info.clone());
                fresh
            }
            Message::ModelDef(d) => {
                let n = ModelNames::from_descriptions(d);
                let fresh = self.names.as_ref() != Some(&n);
                self.names = Some(n);
                fresh
            }
            _ => false,
        }
    }

    /// Decodes a packet with the version in use. While a version the server stated is
    /// on trial, a frame that does not decode with it but does with the version before
    /// comes out decoded with that one; [`FALLBACK_FRAMES`] such frames in a row send the
    /// client back to it for good, which is returned once (for the caller to say). The
    /// first frame that decodes with the stated version ends the trial.
    pub fn decode(&mut self, b: &[u8]) -> (Result<Message, NatNetError>, Option<FellBack>) {
        let r = decode(b, self.version);
        let Some(before) = self.on_trial_from else {
            return (r, None);
        };
        match r {
            Ok(Message::Frame(_)) => {
                self.on_trial_from = None;
                self.misfits = 0;
                (r, None)
            }
            Err(e) => match decode(b, before) {
                Ok(m @ Message::Frame(_)) => {
                    self.misfits += 1;
                    if self.misfits < FALLBACK_FRAMES {
                        return (Ok(m), None);
                    }
                    let fell = FellBack {
                        stated: self.version,
                        kept: before,
                    };
                    self.refused = Some(self.version);
                    self.version = before;
                    self.on_trial_from = None;
                    self.misfits = 0;
                    (Ok(m), Some(fell))
                }
                _ => (Err(e), None),
            },
            Ok(m) => (Ok(m), None),
        }
    }

    /// Forgets the server (after it went quiet): connect again. The version in use, and
    /// what was learnt about stated versions, stay.
    pub fn reset(&mut self) {
        *self = Self {
            on_trial_from: self.on_trial_from,
            misfits: self.misfits,
            refused: self.refused,
            strict_source: self.strict_source,
            ..Self::new(self.version, self.unicast)
        };
    }
}

/// Seconds without any packet from the server after which the command client connects
/// again (a restarted Motive forgets its unicast clients).
pub const SERVER_SILENCE_S: f64 = 5.0;

/// [`run`] with the command port of the server at `server` (usually port 1510): frames
/// are decoded with the version the server states and named by its model definitions;
/// a unicast stream is kept alive. Frames may arrive on the data socket or, as some
/// servers send unicast data, on the command socket. Server info and model definitions
/// are believed only from `server` itself on the command socket; anything else the
/// command socket gets from elsewhere is ignored and counted ([`NatNetStats::foreign`]).
/// `on_frame(receive_unix_s, frame, names)`.
pub fn run_with_server(
    data: &UdpSocket,
    command: &UdpSocket,
    server: SocketAddr,
    client: &mut CommandClient,
    stop: &AtomicBool,
    stats: &NatNetStats,
    on_frame: &mut dyn FnMut(f64, &MocapFrame, &ModelNames),
) -> std::io::Result<()> {
    data.set_read_timeout(Some(
        super::udp::UDP_POLL.min(std::time::Duration::from_millis(20)),
    ))?;
    let mut conn = Connection {
        server,
        client,
        stats,
        said: SaidOnce::default(),
        empty: ModelNames::default(),
    };
    let mut buf = vec![0u8; 65_536];
    let mut last_heard = unix_now();
    while !stop.load(Ordering::Relaxed) {
        let now = unix_now();
        if conn.client.server.is_some() && now - last_heard > SERVER_SILENCE_S {
            tracing::warn!(
                "natnet: server {server} silent for {SERVER_SILENCE_S} s; connecting again"
            );
            conn.client.reset();
            last_heard = now;
        }
        if let Some(p) = conn.client.poll(now) {
            if let Err(e) = command.send_to(&p, server) {
                conn.say_once(Said::Send(e.kind()), || {
                    format!("natnet: sending to the server's command port {server} failed: {e} (said once; retried every {COMMAND_INTERVAL_S} s)")
                });
            }
        }
        // The command socket (answers, and unicast data from some servers), then the
        // data socket (waits briefly).
        for (sock, on_command) in [(command, true), (data, false)] {
            let (n, from) = match sock.recv_from(&mut buf) {
                Ok(x) => x,
                Err(e) if is_wait(&e) => continue,
                Err(e) => {
                    conn.say_once(Said::Receive(e.kind()), || {
                        format!("natnet: receiving failed: {e} (said once; the rest are counted as not decodable)")
                    });
                    stats.packets.error();
                    continue;
                }
            };
            let now = unix_now();
            stats.packets.received(n, now);
            if conn.packet(&buf[..n], from, on_command, now, on_frame) {
                last_heard = now;
            }
        }
    }
    Ok(())
}

/// Kinds of problem [`run_with_server`] says once.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Said {
    Send(std::io::ErrorKind),
    Receive(std::io::ErrorKind),
    Decode(std::mem::Discriminant<NatNetError>),
    /// A packet on the command socket from another host.
    ForeignPacket,
    /// Server info or model definitions from anywhere but the server's command port.
    ForeignInfo,
    /// Frames from another sender than the stream's.
    OtherSender,
}

/// What [`run_with_server`] keeps between packets.
struct Connection<'a> {
    server: SocketAddr,
    client: &'a mut CommandClient,
    stats: &'a NatNetStats,
    said: SaidOnce<Said>,
    empty: ModelNames,
}

impl Connection<'_> {
    /// Warns with `line()` the first time a kind of problem comes.
    fn say_once(&mut self, kind: Said, line: impl FnOnce() -> String) {
        if self.said.first(kind) {
            tracing::warn!("{}", line());
        }
    }

    /// Whether a frame from `from` is taken: the stream's sender is the first to send
    /// frames from the server's host; frames from any other are counted and said once,
    /// and dropped when the client is strict.
    fn frame_sender(&mut self, from: SocketAddr) -> bool {
        let server = self.server;
        let sender = match self.client.sender {
            Some(s) => s,
            None if from.ip() == server.ip() => {
                self.client.sender = Some(from);
                return true;
            }
            None => server,
        };
        if from == sender {
            return true;
        }
        self.stats.frames_elsewhere.fetch_add(1, Ordering::Relaxed);
        let strict = self.client.strict_source;
        self.say_once(Said::OtherSender, || {
            format!(
                "natnet: frames from {from}, not the stream's sender {sender} (the server {server}'s host): {} (said once, the rest are counted)",
                if strict { "dropped (strict_source)" } else { "taken; set strict_source = true to drop them" }
            )
        });
        !strict
    }

    /// Takes one packet from `from`, received on the command socket or the data socket;
    /// true when it shows the server is there (a frame, or anything from the server's
    /// command port).
    fn packet(
        &mut self,
        b: &[u8],
        from: SocketAddr,
        on_command: bool,
        now: f64,
        on_frame: &mut dyn FnMut(f64, &MocapFrame, &ModelNames),
    ) -> bool {
        let (server, stats) = (self.server, self.stats);
        let from_server = on_command && from == server;
        // The command socket talks to the server alone (its frames come from its address).
        if on_command && from.ip() != server.ip() {
            stats.foreign.fetch_add(1, Ordering::Relaxed);
            self.say_once(Said::ForeignPacket, || format!("natnet: ignoring packets from {from} on the command socket (only the server {server} is listened to there; said once, the rest are counted)"));
            return false;
        }
        let (decoded, fell_back) = self.client.decode(b);
        if let Some(FellBack { stated, kept }) = fell_back {
            tracing::warn!(
                "natnet: frames from {server} do not decode as NatNet {}.{}, which its server info stated, but do as {}.{}: decoding them as {}.{} from now on",
                stated.0, stated.1, kept.0, kept.1, kept.0, kept.1
            );
        }
        let m = match decoded {
            Ok(m) => m,
            Err(e) => {
                stats.packets.error();
                self.say_once(Said::Decode(std::mem::discriminant(&e)), || {
                    format!("natnet: a packet from {from} did not decode: {e} (said once per kind of problem; the rest are counted as not decodable)")
                });
                return from_server;
            }
        };
        match m {
            Message::Frame(f) => {
                stats.frames.fetch_add(1, Ordering::Relaxed);
                if !self.frame_sender(from) {
                    return false;
                }
                on_frame(now, &f, self.client.names.as_ref().unwrap_or(&self.empty));
                true
            }
            Message::ServerInfo(_) | Message::ModelDef(_) if !from_server => {
                stats.foreign.fetch_add(1, Ordering::Relaxed);
                let what = if matches!(m, Message::ServerInfo(_)) {
                    "server info"
                } else {
                    "model definitions"
                };
                self.say_once(Said::ForeignInfo, || format!("natnet: ignoring {what} from {from}: only the server's command port {server} is believed (said once, the rest are counted)"));
                false
            }
            m => {
                stats.other.fetch_add(1, Ordering::Relaxed);
                if self.client.on_message(&m) {
                    announce(&m, server);
                }
                from_server
            }
        }
    }
}

/// Says what the server's command port taught the client.
fn announce(m: &Message, server: SocketAddr) {
    match m {
        Message::ServerInfo(i) => tracing::info!(
            "natnet: {} {}.{}.{}.{} at {server}, NatNet {}.{}",
            i.app,
            i.app_version[0],
            i.app_version[1],
            i.app_version[2],
            i.app_version[3],
            i.natnet.0,
            i.natnet.1
        ),
        Message::ModelDef(d) => tracing::info!("natnet: {} model definitions", d.len()),
        _ => {}
    }
}

/// A socket for talking to the command port of `server`: bound to the interface that
/// reaches it (127.0.0.1 for a server on loopback; [`local_ip_towards`]), any port,
/// non-blocking, and not connected (some servers send unicast data to it from another
/// port).
pub fn command_socket(server: SocketAddr) -> std::io::Result<UdpSocket> {
    let command = UdpSocket::bind((local_ip_towards(server)?, 0))?;
    command.set_nonblocking(true)?;
    Ok(command)
}

/// The input as a URL describes it: [`run_with_server`] when the server is known (the
/// stream is unicast unless `data` is a multicast group), else [`run`] with no names.
pub fn run_input(
    data: &UdpSocket,
    data_addr: SocketAddr,
    version: Version,
    server: Option<SocketAddr>,
    stop: &AtomicBool,
    stats: &NatNetStats,
    on_frame: &mut dyn FnMut(f64, &MocapFrame, &ModelNames),
) -> std::io::Result<()> {
    match server {
        Some(server) => {
            let command = command_socket(server)?;
            let mut client = CommandClient::new(version, !data_addr.ip().is_multicast());
            run_with_server(data, &command, server, &mut client, stop, stats, on_frame)
        }
        None => {
            let empty = ModelNames::default();
            run(data, version, stop, stats, &mut |now, f| {
                on_frame(now, f, &empty)
            });
            Ok(())
        }
    }
}

/// Receives on `socket` until `stop` is set; calls `on_frame(receive_unix_s, frame)` for
/// every frame of mocap data.
pub fn run(
    socket: &UdpSocket,
    version: Version,
    stop: &AtomicBool,
    stats: &NatNetStats,
    on_frame: &mut dyn FnMut(f64, &MocapFrame),
) {
    let said = std::cell::RefCell::new(SaidOnce::default());
    super::udp::udp_loop(
        socket,
        stop,
        &mut |now, from, bytes| {
            stats.packets.received(bytes.len(), now);
            match decode(bytes, version) {
                Ok(Message::Frame(f)) => {
                    stats.frames.fetch_add(1, Ordering::Relaxed);
                    on_frame(now, &f);
                }
                Ok(_) => {
                    stats.other.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => {
                    stats.packets.error();
                    if said
                        .borrow_mut()
                        .first(Said::Decode(std::mem::discriminant(&e)))
                    {
                        tracing::warn!("natnet: a packet from {from} did not decode as NatNet {}.{}: {e} (said once per kind of problem; the rest are counted as not decodable)", version.0, version.1);
                    }
                }
            }
        },
        &mut |e| {
            stats.packets.error();
            if said.borrow_mut().first(Said::Receive(e.kind())) {
                tracing::warn!("natnet: receiving failed: {e} (said once; the rest are counted as not decodable)");
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A loopback server that answers the first connect request with its info and model
    /// definitions and then falls silent: the client connects again once
    /// [`SERVER_SILENCE_S`] has passed without a packet, and not before.
    #[test]
    fn a_silent_server_is_connected_again_after_five_seconds() {
        use crate::protocol::natnet::{encode_model_def, encode_server_info, NAT_CONNECT};
        let server = UdpSocket::bind("127.0.0.1:0").unwrap();
        server
            .set_read_timeout(Some(std::time::Duration::from_millis(100)))
            .unwrap();
        let server_addr = server.local_addr().unwrap();
        let data = UdpSocket::bind("127.0.0.1:0").unwrap();
        let command = command_socket(server_addr).unwrap();
        let stop = AtomicBool::new(false);
        let stats = NatNetStats::default();
        let mut client = CommandClient::new(Version(3, 0), true);
        let info = encode_server_info(&ServerInfo {
            app: "Motive".into(),
            app_version: [3, 1, 0, 0],
            natnet: Version(3, 0),
            clock_hz: Some(1_000_000),
            data_port: Some(data.local_addr().unwrap().port()),
            multicast_group: None,
        });
        let models = encode_model_def(&[]).unwrap();
        let started = std::time::Instant::now();
        // Seconds from the start at which connect requests arrived.
        let connects = std::thread::scope(|scope| {
            let served = scope.spawn(|| {
                let mut connects: Vec<f64> = Vec::new();
                let mut buf = [0u8; 1024];
                // Bounded: 9 s, enough for a second connect at about 5 s.
                while started.elapsed().as_secs_f64() < 9.0 && connects.len() < 2 {
                    let Ok((n, from)) = server.recv_from(&mut buf) else {
                        continue;
                    };
                    if n >= 2 && u16::from_le_bytes([buf[0], buf[1]]) == NAT_CONNECT {
                        connects.push(started.elapsed().as_secs_f64());
                        if connects.len() == 1 {
                            server.send_to(&info, from).unwrap();
                            server.send_to(&models, from).unwrap();
                        }
                    }
                }
                stop.store(true, Ordering::Relaxed);
                connects
            });
            run_with_server(
                &data,
                &command,
                server_addr,
                &mut client,
                &stop,
                &stats,
                &mut |_, _, _| {},
            )
            .unwrap();
            served.join().unwrap()
        });
        assert_eq!(connects.len(), 2, "{connects:?}");
        let gap = connects[1] - connects[0];
        // The server's answer came a few ms after the first request: silence is counted
        // from it. Half a second of slack for a loaded machine.
        assert!(
            (SERVER_SILENCE_S..SERVER_SILENCE_S + 0.5).contains(&gap),
            "connected again after {gap} s"
        );
    }

    #[test]
    fn the_command_client_connects_asks_for_models_and_keeps_unicast_alive() {
        let mut c = CommandClient::new(Version(3, 0), true);
        // Connect requests every second until the server answers.
        let first = c.poll(0.0).unwrap();
        assert_eq!(first, encode_connect(Version(3, 0)));
        assert_eq!(c.poll(0.5), None);
        assert_eq!(c.poll(1.0), Some(first));
        let info = ServerInfo {
            app: "Motive".into(),
            app_version: [3, 1, 0, 0],
            natnet: Version(4, 1),
            clock_hz: None,
            data_port: Some(1511),
            multicast_group: None,
        };
        assert!(c.on_message(&Message::ServerInfo(info.clone())));
        assert!(!c.on_message(&Message::ServerInfo(info)));
        assert_eq!(
            c.version,
            Version(4, 1),
            "frames decode as the server speaks"
        );
        // Then model definitions until they come, and keep-alives.
        assert_eq!(c.poll(1.1), Some(encode_request_modeldef().to_vec()));
        assert_eq!(c.poll(1.2), Some(encode_keepalive().to_vec()));
        assert_eq!(c.poll(1.5), None);
        assert_eq!(c.poll(2.1), Some(encode_request_modeldef().to_vec()));
        assert!(
            c.on_message(&Message::ModelDef(vec![Description::RigidBody {
                name: "Hand".into(),
                id: 3,
                parent: -1
            }]))
        );
        assert_eq!(c.poll(2.2), Some(encode_keepalive().to_vec()));
        assert_eq!(c.poll(3.1), None);
        assert_eq!(c.poll(3.2), Some(encode_keepalive().to_vec()));
        // A multicast client sends no keep-alives.
        let mut m = CommandClient::new(Version(3, 0), false);
        m.poll(0.0);
        m.on_message(&Message::ModelDef(Vec::new()));
        m.server = Some(ServerInfo {
            app: String::new(),
            app_version: [0; 4],
            natnet: Version(3, 0),
            clock_hz: None,
            data_port: None,
            multicast_group: None,
        });
        assert_eq!(m.poll(10.0), None);
    }

    #[test]
    fn a_stated_version_frames_do_not_decode_with_is_given_up_after_three_frames() {
        let info = |natnet| {
            Message::ServerInfo(ServerInfo {
                app: "Motive".into(),
                app_version: [3, 0, 0, 0],
                natnet,
                clock_hz: None,
                data_port: None,
                multicast_group: None,
            })
        };
        let v3_frame = crate::protocol::natnet::example_frame(3);
        assert!(decode(&v3_frame, Version(4, 1)).is_err(), "the premise");
        let mut c = CommandClient::new(Version(3, 0), true);
        c.on_message(&info(Version(4, 1)));
        assert_eq!(c.version, Version(4, 1));
        // Frames 1 and 2 come out decoded as 3.0; the third also sends the client back.
        for _ in 0..FALLBACK_FRAMES - 1 {
            let (m, fell) = c.decode(&v3_frame);
            assert!(matches!(m, Ok(Message::Frame(_))));
            assert_eq!(fell, None);
        }
        let (m, fell) = c.decode(&v3_frame);
        assert!(matches!(m, Ok(Message::Frame(_))));
        assert_eq!(
            fell,
            Some(FellBack {
                stated: Version(4, 1),
                kept: Version(3, 0)
            })
        );
        assert_eq!(c.version, Version(3, 0));
        // Stating 4.1 again changes nothing, even after a reset; garbage stays garbage.
        c.reset();
        c.on_message(&info(Version(4, 1)));
        assert_eq!(c.version, Version(3, 0));
        assert_eq!(c.decode(&v3_frame).1, None);
        assert!(c.decode(b"junk").0.is_err());
        // A version whose frames do decode ends its trial at the first frame: 4.0 here,
        // whose frames are laid out as 3.0's.
        let mut d = CommandClient::new(Version(3, 0), true);
        d.on_message(&info(Version(4, 0)));
        assert!(matches!(d.decode(&v3_frame), (Ok(Message::Frame(_)), None)));
        assert_eq!(d.on_trial_from, None);
        assert_eq!(d.version, Version(4, 0));
    }

    #[test]
    fn marker_sets_are_named_by_member_and_all_is_skipped() {
        let b = crate::protocol::natnet::example_frame(3);
        let Message::Frame(f) = decode(&b, Version(3, 0)).unwrap() else {
            panic!("a frame")
        };
        let mut out = Vec::new();
        markers_of(&f, &ModelNames::default(), &mut out);
        let names: Vec<&str> = out.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["Body_1", "Body_2", "Body_3"]);
        assert!((out[1].position_m - DVec3::new(0.03, 0.04, 0.05)).length() < 1e-6);
    }
}
