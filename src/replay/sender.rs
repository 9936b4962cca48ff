//! `rigless replay FILE --to URL`: sends a recording as live traffic with its own timing,
//! to an OSC receiver (native schema, `osc://`) or a VMC receiver (`vmc://`, markers as
//! trackers), over UDP. Options: speed, loop, a time window, a marker subset, injected
//! dropouts and noise. Send times are measured against the file's clock (jitter).

use super::recording::Recording;
use crate::protocol::osc::{encode_native, time_tag_of_unix};
use crate::protocol::url::{Endpoint, UrlError};
use crate::runtime::clock::Clock;
use crate::runtime::rng::Rng;
use crate::runtime::stats::percentile;
use glam::DVec3;
use rosc::{OscBundle, OscMessage, OscPacket, OscTime, OscType};
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};

/// Where to send.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    Osc(SocketAddr),
    Vmc(SocketAddr),
    /// Act as a VRPN tracker server named `device` on `bind` (TCP and UDP, the same port
    /// number, as VRPN servers do): each marker is a sensor, in the recording's label
    /// order; unmodified VRPN clients read it in either connection mode
    /// (`vrpn_print_devices DEVICE@tcp://HOST:PORT` or `DEVICE@HOST:PORT`, which asks for
    /// a call back over UDP and then gets the reports as datagrams). Missing samples are
    /// not sent (VRPN has no occlusion flag).
    Vrpn {
        device: String,
        bind: SocketAddr,
    },
    /// Act as a NatNet 3.0 server (OptiTrack Motive): frames of mocap data go to `data`
    /// (a client's data port, or a multicast group), the recording's markers as one
    /// marker set named [`NATNET_SET`] (a missing sample as NaN). With `command`, that
    /// address is the server's command port: clients connect there for the server info
    /// and the model definitions that name the markers (`SET:LABEL`).
    NatNet {
        data: SocketAddr,
        command: Option<SocketAddr>,
    },
}

/// The marker set a NatNet replay sends.
pub const NATNET_SET: &str = "replay";

/// Why a URL is not somewhere a recording can be sent.
#[derive(Debug, thiserror::Error)]
pub enum TargetError {
    #[error(transparent)]
    Url(#[from] UrlError),
    #[error(
        "{url:?}: a recording holds markers, not glove readings: it cannot replay to glove://"
    )]
    Glove { url: String },
}

impl Target {
    /// The target a URL names (`osc://`, `vmc://`, `vrpn://` or `natnet://`).
    pub fn parse(url: &str) -> Result<Self, TargetError> {
        match crate::protocol::url::parse(url)? {
            Endpoint::Osc(a) => Ok(Target::Osc(a)),
            Endpoint::Vmc(a) => Ok(Target::Vmc(a)),
            Endpoint::NatNet { data, server, .. } => Ok(Target::NatNet {
                data,
                command: server,
            }),
            Endpoint::Glove(_) => Err(TargetError::Glove {
                url: url.to_owned(),
            }),
            Endpoint::Vrpn { device, addr, .. } => Ok(Target::Vrpn { device, bind: addr }),
        }
    }
}

/// How to replay.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayOptions {
    /// Playback speed (1 = the file's own timing).
    pub speed: f64,
    pub looping: bool,
    /// Window of the file to play, seconds from its first frame.
    pub start_s: f64,
    pub end_s: Option<f64>,
    /// Only these labels (all when `None`).
    pub markers: Option<Vec<String>>,
    /// Share of samples dropped at random (sent as occluded), 0..1.
    pub dropout: f64,
    /// Uniform noise amplitude per axis, metres.
    pub noise_m: f64,
    pub seed: u64,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            speed: 1.0,
            looping: false,
            start_s: 0.0,
            end_s: None,
            markers: None,
            dropout: 0.0,
            noise_m: 0.0,
            seed: 1,
        }
    }
}

/// What a replay did, with its send-time jitter against the file's clock.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ReplayStats {
    pub packets: u64,
    pub bytes: u64,
    pub send_errors: u64,
    /// NatNet command replies (server info, model definitions) that could not be sent;
    /// the client asks again.
    pub reply_errors: u64,
    pub samples_dropped: u64,
    /// |actual − scheduled| send time per packet: median, 99th percentile, max, ms.
    pub jitter_ms_p50: f64,
    pub jitter_ms_p99: f64,
    pub jitter_ms_max: f64,
}

fn encode_vmc(t_s: f64, markers: &[(&str, DVec3)]) -> Vec<u8> {
    let mut content: Vec<OscPacket> = markers
        .iter()
        .map(|(name, p)| {
            // Unity's left-handed frame: negate Z; identity rotation.
            OscPacket::Message(OscMessage {
                addr: "/VMC/Ext/Tra/Pos".into(),
                args: vec![
                    OscType::String((*name).to_owned()),
                    OscType::Float(p.x as f32),
                    OscType::Float(p.y as f32),
                    OscType::Float(-p.z as f32),
                    OscType::Float(0.0),
                    OscType::Float(0.0),
                    OscType::Float(0.0),
                    OscType::Float(1.0),
                ],
            })
        })
        .collect();
    content.push(OscPacket::Message(OscMessage {
        addr: "/VMC/Ext/T".into(),
        args: vec![OscType::Float(t_s as f32)],
    }));
    rosc::encoder::encode(&OscPacket::Bundle(OscBundle {
        timetag: OscTime {
            seconds: 0,
            fractional: 1,
        },
        content,
    }))
    .expect("a bundle of messages always encodes")
}

/// VRPN ids this server gives its one sender and one type.
const VRPN_SENDER: i32 = 0;
const VRPN_POS_QUAT: i32 = 0;

/// One frame as VRPN position messages, one per present marker (sensor = its index).
fn encode_vrpn(unix_s: f64, markers: &[(&str, DVec3)]) -> Vec<u8> {
    use crate::protocol::vrpn::{encode_message, encode_pos_quat, PosQuat};
    let (secs, usecs) = (
        unix_s.floor() as u32,
        ((unix_s - unix_s.floor()) * 1e6) as u32,
    );
    let mut out = Vec::with_capacity(markers.len() * 96);
    for (k, (_, p)) in markers.iter().enumerate() {
        if p.is_finite() {
            let r = PosQuat {
                sensor: k as i32,
                position: *p,
                rotation: [0.0, 0.0, 0.0, 1.0],
            };
            encode_message(
                &mut out,
                secs,
                usecs,
                VRPN_SENDER,
                VRPN_POS_QUAT,
                &encode_pos_quat(&r),
            );
        }
    }
    out
}

/// Largest datagram of low-latency messages sent to a UDP-mode VRPN client, bytes
/// (Ethernet's MTU less the IP and UDP headers, as VRPN's own buffer).
const VRPN_DATAGRAM_BYTES: usize = 1472;

/// A VRPN client of the replay server.
struct VrpnClient {
    tcp: std::net::TcpStream,
    /// What it sent: its cookie, then messages (descriptions).
    reader: crate::protocol::vrpn::StreamReader,
    /// Where its UDP description asks for low-latency messages to go.
    udp_dest: Option<SocketAddr>,
}

impl VrpnClient {
    /// Reads what the client sent without blocking and takes in its UDP description.
    /// Returns false when the client is gone or misbehaves.
    fn poll(&mut self) -> bool {
        use crate::protocol::vrpn::{parse_udp_description, VrpnError, UDP_DESCRIPTION};
        use std::io::Read;
        let mut chunk = [0u8; 4096];
        if self.tcp.set_nonblocking(true).is_err() {
            return false;
        }
        let alive = loop {
            match self.tcp.read(&mut chunk) {
                Ok(0) => break false,
                Ok(n) => {
                    let udp_dest = &mut self.udp_dest;
                    let fed = self.reader.feed(&chunk[..n], &mut |m| {
                        if m.kind == UDP_DESCRIPTION {
                            *udp_dest = Some(parse_udp_description(m)?);
                        }
                        Ok::<(), VrpnError>(())
                    });
                    if fed.is_err() {
                        break false;
                    }
                }
                Err(e) => break crate::runtime::net::is_wait(&e),
            }
        };
        alive && self.tcp.set_nonblocking(false).is_ok()
    }
}

/// One frame as a NatNet 3.0 frame of mocap data: one marker set, missing samples as
/// NaN; `file_t_s` is the timestamp.
fn encode_natnet(
    n: usize,
    file_t_s: f64,
    markers: &[(&str, DVec3)],
) -> Result<Vec<u8>, crate::protocol::natnet::NatNetError> {
    use crate::protocol::natnet::{encode_frame, MocapFrame};
    encode_frame(&MocapFrame {
        frame: n as i32,
        marker_sets: vec![(
            NATNET_SET.to_owned(),
            markers.iter().map(|(_, p)| p.as_vec3()).collect(),
        )],
        timestamp_s: file_t_s,
        ..MocapFrame::default()
    })
}

/// Where the bytes go.
enum Sink {
    Udp(UdpSocket, SocketAddr),
    /// A VRPN server: new clients (connecting over TCP, or asking over UDP to be called
    /// back) are taken in at every frame and greeted with the cookie and the
    /// descriptions; a client that cannot keep up or hangs up is dropped.
    Vrpn {
        listener: std::net::TcpListener,
        /// The server's UDP port: connection requests in, low-latency messages out.
        udp: UdpSocket,
        clients: Vec<VrpnClient>,
        greeting: Vec<u8>,
    },
    /// A NatNet server: frames to `data`; the command socket answers connect and
    /// model-definition requests.
    NatNet {
        sock: UdpSocket,
        data: SocketAddr,
        server_info: Vec<u8>,
        model_def: Vec<u8>,
        /// Replies that could not be sent.
        reply_errors: u64,
    },
}

impl Sink {
    /// Opens the sink; `labels` are the markers a frame carries, in order.
    fn open(target: &Target, labels: &[&str]) -> std::io::Result<Self> {
        use crate::protocol::vrpn::{cookie, description_payload, encode_message, POS_QUAT};
        use crate::protocol::vrpn::{SENDER_DESCRIPTION, TYPE_DESCRIPTION};
        Ok(match target {
            Target::Osc(a) | Target::Vmc(a) => {
                let sock = UdpSocket::bind(if a.is_ipv6() { "[::]:0" } else { "0.0.0.0:0" })?;
                Sink::Udp(sock, *a)
            }
            Target::NatNet { data, command } => {
                use crate::protocol::natnet::{
                    encode_model_def, encode_server_info, Description, ServerInfo, Version,
                };
                let any = if data.is_ipv6() {
                    "[::]:0"
                } else {
                    "0.0.0.0:0"
                };
                let sock = match command {
                    Some(c) => UdpSocket::bind(c)?,
                    None => UdpSocket::bind(any)?,
                };
                sock.set_nonblocking(true)?;
                let multicast_group = match data.ip() {
                    std::net::IpAddr::V4(g) if g.is_multicast() => Some(g),
                    _ => None,
                };
                let server_info = encode_server_info(&ServerInfo {
                    app: "rigless".into(),
                    app_version: [0, 1, 0, 0],
                    natnet: Version(3, 0),
                    clock_hz: Some(1_000_000),
                    data_port: Some(data.port()),
                    multicast_group,
                });
                let model_def = encode_model_def(&[Description::MarkerSet {
                    name: NATNET_SET.into(),
                    markers: labels.iter().map(|l| (*l).to_owned()).collect(),
                }])
                .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
                Sink::NatNet {
                    sock,
                    data: *data,
                    server_info,
                    model_def,
                    reply_errors: 0,
                }
            }
            Target::Vrpn { device, bind } => {
                let listener = std::net::TcpListener::bind(bind)?;
                listener.set_nonblocking(true)?;
                // The same port number for UDP (a bind to port 0 takes TCP's).
                let udp = UdpSocket::bind(listener.local_addr()?)?;
                udp.set_nonblocking(true)?;
                let mut greeting = cookie().to_vec();
                encode_message(
                    &mut greeting,
                    0,
                    0,
                    VRPN_SENDER,
                    SENDER_DESCRIPTION,
                    &description_payload(device),
                );
                encode_message(
                    &mut greeting,
                    0,
                    0,
                    VRPN_POS_QUAT,
                    TYPE_DESCRIPTION,
                    &description_payload(POS_QUAT),
                );
                Sink::Vrpn {
                    listener,
                    udp,
                    clients: Vec::new(),
                    greeting,
                }
            }
        })
    }

    /// Sends one frame's bytes; returns the bytes sent (to every client, for VRPN).
    fn send(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        use std::io::Write;
        match self {
            Sink::Udp(sock, dest) => sock.send_to(bytes, *dest),
            Sink::NatNet {
                sock,
                data,
                server_info,
                model_def,
                reply_errors,
            } => {
                use crate::protocol::natnet::{NAT_CONNECT, NAT_REQUEST_MODELDEF};
                let mut request = [0u8; 1024];
                while let Ok((n, from)) = sock.recv_from(&mut request) {
                    if n < 4 {
                        continue;
                    }
                    let reply = match u16::from_le_bytes([request[0], request[1]]) {
                        NAT_CONNECT => &server_info[..],
                        NAT_REQUEST_MODELDEF => &model_def[..],
                        // Keep-alives and anything else: nothing to answer.
                        _ => continue,
                    };
                    // A reply that fails costs only itself: the client repeats its
                    // request until answered.
                    if sock.send_to(reply, from).is_err() {
                        *reply_errors += 1;
                    }
                }
                sock.send_to(bytes, *data)
            }
            Sink::Vrpn {
                listener,
                udp,
                clients,
                greeting,
            } => {
                let mut fresh: Vec<std::net::TcpStream> = Vec::new();
                while let Ok((c, _)) = listener.accept() {
                    fresh.push(c);
                }
                // UDP connection mode: "IP PORT" asks to be called back there.
                let mut request = [0u8; 256];
                while let Ok((n, _)) = udp.recv_from(&mut request) {
                    let Ok(back) = crate::protocol::vrpn::parse_connection_request(&request[..n])
                    else {
                        continue;
                    };
                    // A client repeats its request until called back: once is enough.
                    if clients.iter().any(|c| c.tcp.peer_addr().ok() == Some(back)) {
                        continue;
                    }
                    if let Ok(c) = std::net::TcpStream::connect_timeout(
                        &back,
                        std::time::Duration::from_millis(200),
                    ) {
                        fresh.push(c);
                    }
                }
                for mut c in fresh {
                    // Small messages go out at once where the socket allows.
                    if let Err(e) = c.set_nodelay(true) {
                        tracing::debug!("TCP_NODELAY not set on a VRPN replay client: {e}");
                    }
                    // Without a write timeout a stalled client would stall the replay: a
                    // client whose socket cannot have one is dropped.
                    let ready = c
                        .set_write_timeout(Some(std::time::Duration::from_millis(100)))
                        .and_then(|()| c.set_nonblocking(false));
                    if let Err(e) = ready {
                        tracing::warn!(
                            "a VRPN replay client was dropped: its socket cannot be set up ({e})"
                        );
                    } else if c.write_all(greeting).is_ok() {
                        clients.push(VrpnClient {
                            tcp: c,
                            reader: Default::default(),
                            udp_dest: None,
                        });
                    }
                }
                let mut sent = 0;
                clients.retain_mut(|c| {
                    if !c.poll() {
                        return false;
                    }
                    match c.udp_dest {
                        Some(dest) => {
                            for r in crate::protocol::vrpn::datagrams(bytes, VRPN_DATAGRAM_BYTES) {
                                if let Ok(n) = udp.send_to(&bytes[r], dest) {
                                    sent += n;
                                }
                            }
                            true
                        }
                        None => {
                            let ok = c.tcp.write_all(bytes).is_ok();
                            sent += if ok { bytes.len() } else { 0 };
                            ok
                        }
                    }
                });
                Ok(sent)
            }
        }
    }
}

/// Sends `rec` to `target` on `clock` from `start_at_s`, until it ends (or forever when
/// looping) or `stop` is set.
pub fn replay(
    rec: &Recording,
    target: Target,
    opts: &ReplayOptions,
    clock: &dyn Clock,
    start_at_s: f64,
    stop: &AtomicBool,
) -> std::io::Result<ReplayStats> {
    let chosen_labels: Vec<&str> = (0..rec.labels.len())
        .filter(|k| {
            opts.markers
                .as_ref()
                .is_none_or(|m| m.iter().any(|n| n == &rec.labels[*k]))
        })
        .map(|k| rec.labels[k].as_str())
        .collect();
    let mut sink = Sink::open(&target, &chosen_labels)?;
    let period = 1.0 / rec.rate_hz;
    let first = ((opts.start_s * rec.rate_hz).ceil().max(0.0) as usize).min(rec.frames.len());
    let last = opts.end_s.map_or(rec.frames.len(), |e| {
        ((e * rec.rate_hz).floor() as usize + 1).min(rec.frames.len())
    });
    let chosen: Vec<usize> = (0..rec.labels.len())
        .filter(|k| {
            opts.markers
                .as_ref()
                .is_none_or(|m| m.iter().any(|n| n == &rec.labels[*k]))
        })
        .collect();
    let mut stats = ReplayStats::default();
    if first >= last {
        return Ok(stats);
    }
    let mut rng = Rng::new(opts.seed);
    let mut jitter = Vec::new();
    let mut markers: Vec<(&str, DVec3)> = Vec::with_capacity(chosen.len());
    let mut n = 0usize;
    loop {
        let i = first + n % (last - first);
        if n > 0 && n.is_multiple_of(last - first) && !opts.looping {
            break;
        }
        let file_t = (n as f64) * period;
        let scheduled = start_at_s + file_t / opts.speed;
        clock.sleep_until(scheduled);
        if stop.load(Ordering::Relaxed) {
            break;
        }
        markers.clear();
        for &k in &chosen {
            let mut p = rec.frames[i][k];
            if opts.dropout > 0.0 && rng.next_f64() < opts.dropout {
                p = DVec3::NAN;
                stats.samples_dropped += 1;
            } else if opts.noise_m > 0.0 && p.is_finite() {
                p += (DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * 2.0 - 1.0)
                    * opts.noise_m;
            }
            markers.push((rec.labels[k].as_str(), p));
        }
        let bytes = match &target {
            Target::Osc(_) => encode_native(
                n as i64,
                time_tag_of_unix(clock.unix_s(scheduled)),
                &markers,
            ),
            Target::Vmc(_) => encode_vmc(i as f64 * period, &markers),
            Target::Vrpn { .. } => encode_vrpn(clock.unix_s(scheduled), &markers),
            Target::NatNet { .. } => encode_natnet(n, i as f64 * period, &markers)
                .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?,
        };
        let sent_at = clock.now_s();
        match sink.send(&bytes) {
            Ok(len) => {
                stats.packets += 1;
                stats.bytes += len as u64;
            }
            Err(_) => stats.send_errors += 1,
        }
        jitter.push((sent_at - scheduled).abs() * 1e3);
        n += 1;
    }
    // No packet sent: zero jitter.
    let mut q = |p: f64| {
        if jitter.is_empty() {
            0.0
        } else {
            percentile(&mut jitter, p)
        }
    };
    stats.jitter_ms_p50 = q(0.5);
    stats.jitter_ms_p99 = q(0.99);
    stats.jitter_ms_max = q(1.0);
    if let Sink::NatNet { reply_errors, .. } = sink {
        stats.reply_errors = reply_errors;
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::osc::OscMapping;

    /// VMC is Unity's left-handed frame: the sender negates Z and the OSC input negates it
    /// back. Markers off every axis (values exact in f32) survive the round trip exactly,
    /// and go on the wire with Z negated; either negation missing fails this.
    #[test]
    fn vmc_round_trips_markers_off_every_axis() {
        let p = DVec3::new(0.25, 1.5, -0.75);
        let q = DVec3::new(-0.125, 0.875, 0.375);
        let bytes = encode_vmc(2.5, &[("LeftHand", p), ("Head", q)]);
        let f = OscMapping::default().decode(&bytes).unwrap();
        let got: Vec<(String, DVec3)> = f
            .markers()
            .iter()
            .map(|m| (m.name.clone(), m.position_m))
            .collect();
        assert_eq!(got, vec![("LeftHand".into(), p), ("Head".into(), q)]);
        assert_eq!(f.vmc_time_s, Some(2.5));
        let Ok((_, OscPacket::Bundle(b))) = rosc::decoder::decode_udp(&bytes) else {
            panic!("a VMC bundle");
        };
        let OscPacket::Message(m) = &b.content[0] else {
            panic!("a message first");
        };
        assert_eq!(m.args[1..4], [0.25f32, 1.5, 0.75].map(OscType::Float));
    }
}
