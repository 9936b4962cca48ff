//! The NatNet input (OptiTrack Motive's data stream, UDP): binds the data port (joining the
//! group when the address is multicast), decodes frames of mocap data with
//! [`crate::protocol::natnet`], and hands each frame's markers to a callback. With the
//! server's address it also talks to the command port ([`CommandClient`]): connects,
//! learns the server's NatNet version, asks for the model definitions (marker names), and
//! keeps a unicast stream alive.
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
    MocapFrame, ServerInfo, Version,
};
use crate::protocol::url::Endpoint;
use crate::runtime::clock::{unix_now, Clock};
use crate::runtime::net::is_wait;
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
        Ok(format!(
            "{}; {} frames, {} other messages",
            stats.packets,
            stats.frames.load(Ordering::Relaxed),
            stats.other.load(Ordering::Relaxed)
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
        for m in &f.labeled {
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
    last_connect_s: f64,
    last_request_s: f64,
    last_keepalive_s: f64,
}

impl CommandClient {
    pub fn new(version: Version, unicast: bool) -> Self {
        Self {
            version,
            unicast,
            server: None,
            names: None,
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

    /// Takes in a message from the server; true when it changed what the client knows.
    pub fn on_message(&mut self, m: &Message) -> bool {
        match m {
            Message::ServerInfo(info) => {
                if (3..=4).contains(&info.natnet.0) {
                    self.version = info.natnet;
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

    /// Forgets the server (after it went quiet): connect again.
    pub fn reset(&mut self) {
        *self = Self::new(self.version, self.unicast);
    }
}

/// Seconds without any packet from the server after which the command client connects
/// again (a restarted Motive forgets its unicast clients).
pub const SERVER_SILENCE_S: f64 = 5.0;

/// [`run`] with the command port of the server at `server` (usually port 1510): frames
/// are decoded with the version the server states and named by its model definitions;
/// a unicast stream is kept alive. Frames may arrive on the data socket or, as some
/// servers send unicast data, on the command socket. `on_frame(receive_unix_s, frame,
/// names)`.
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
    let empty = ModelNames::default();
    let mut buf = vec![0u8; 65_536];
    let mut last_heard = unix_now();
    while !stop.load(Ordering::Relaxed) {
        let now = unix_now();
        if client.server.is_some() && now - last_heard > SERVER_SILENCE_S {
            tracing::warn!(
                "natnet: server {server} silent for {SERVER_SILENCE_S} s; connecting again"
            );
            client.reset();
            last_heard = now;
        }
        if let Some(p) = client.poll(now) {
            if let Err(e) = command.send_to(&p, server) {
                tracing::debug!(error = %e, "natnet: command send");
            }
        }
        // The command socket (answers, and unicast data from some servers), then the
        // data socket (waits briefly).
        for sock in [command, data] {
            let (n, _) = match sock.recv_from(&mut buf) {
                Ok(x) => x,
                Err(e) if is_wait(&e) => continue,
                Err(e) => {
                    tracing::debug!(error = %e, "natnet: receive failed");
                    stats.packets.error();
                    continue;
                }
            };
            let now = unix_now();
            last_heard = now;
            stats.packets.received(n, now);
            match decode(&buf[..n], client.version) {
                Ok(Message::Frame(f)) => {
                    stats.frames.fetch_add(1, Ordering::Relaxed);
                    on_frame(now, &f, client.names.as_ref().unwrap_or(&empty));
                }
                Ok(m) => {
                    stats.other.fetch_add(1, Ordering::Relaxed);
                    if client.on_message(&m) {
                        match &m {
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
                            Message::ModelDef(d) => {
                                tracing::info!("natnet: {} model definitions", d.len())
                            }
                            _ => {}
                        }
                    }
                }
                Err(_) => stats.packets.error(),
            }
        }
    }
    Ok(())
}

/// A socket for talking to the command port of `server` (any local port, non-blocking).
pub fn command_socket(server: SocketAddr) -> std::io::Result<UdpSocket> {
    let any: SocketAddr = if server.is_ipv4() {
        ([0, 0, 0, 0], 0).into()
    } else {
        (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
    };
    let command = UdpSocket::bind(any)?;
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
    super::udp::udp_loop(
        socket,
        stop,
        &mut |now, bytes| {
            stats.packets.received(bytes.len(), now);
            match decode(bytes, version) {
                Ok(Message::Frame(f)) => {
                    stats.frames.fetch_add(1, Ordering::Relaxed);
                    on_frame(now, &f);
                }
                Ok(_) => {
                    stats.other.fetch_add(1, Ordering::Relaxed);
                }
                Err(_) => stats.packets.error(),
            }
        },
        &mut |e| {
            tracing::debug!(error = %e, "natnet: receive failed");
            stats.packets.error();
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

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
