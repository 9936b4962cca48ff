//! The OSC input (UDP, `osc://` and `vmc://`): receives datagrams on a bound address,
//! decodes them with [`crate::protocol::osc`] (units and up axis converted there), and
//! hands each packet's markers, names resolved, to the input's sink. Garbage costs only
//! its own packet, and is counted; each kind of problem is said once.

use super::config::{endpoint_of, OscInputConfig, OSC_SCHEMES};
use super::{InputError, InputFrame, InputSink};
use crate::markers::index::MarkerIndex;
use crate::markers::MarkerSample;
use crate::protocol::osc::{OscFrame, OscMapping};
use crate::protocol::url::Endpoint;
use crate::runtime::clock::Clock;
use crate::runtime::said::SaidOnce;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};

/// What an OSC input has seen.
pub type OscStats = super::PacketStats;

/// Binds `addr` for an OSC input ([`super::udp::udp_bind`]).
pub fn bind(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    super::udp::udp_bind(addr)
}

/// An opened OSC input.
pub struct OscInput {
    socket: UdpSocket,
    mapping: OscMapping,
    index: MarkerIndex,
}

impl OscInput {
    /// Binds the address of `cfg.url`: `osc://` with the config's patterns, scale and up
    /// axis (VMC messages too), `vmc://` for VMC only.
    pub fn open(cfg: &OscInputConfig, index: MarkerIndex) -> Result<Self, InputError> {
        let url_error = |source| InputError::Url {
            url: cfg.url.clone(),
            source,
        };
        let (addr, mapping) = match endpoint_of(&cfg.url, OSC_SCHEMES).map_err(url_error)? {
            Endpoint::Vmc(a) => (
                a,
                OscMapping {
                    patterns: Vec::new(),
                    ..OscMapping::default()
                },
            ),
            Endpoint::Osc(a) => (
                a,
                OscMapping {
                    patterns: cfg.patterns.clone(),
                    scale: cfg.scale,
                    z_up: cfg.up.eq_ignore_ascii_case("z"),
                    vmc: true,
                },
            ),
            _ => unreachable!("endpoint_of checked the scheme"),
        };
        let socket = bind(addr).map_err(|source| InputError::Bind {
            url: cfg.url.clone(),
            source,
        })?;
        Ok(Self {
            socket,
            mapping,
            index,
        })
    }

    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.socket.local_addr().ok()
    }

    /// `osc input listening on udp://ADDR` (scripts and tests read this line).
    pub fn opened(&self) -> String {
        match self.local_addr() {
            Some(a) => format!("osc input listening on udp://{a}"),
            None => "osc input listening".into(),
        }
    }

    /// Receives until `stop` is set; returns what it received.
    pub fn run(mut self, clock: &dyn Clock, stop: &AtomicBool, sink: &mut dyn InputSink) -> String {
        let stats = OscStats::default();
        let mut batch = Vec::new();
        run(&self.socket, &self.mapping, stop, &stats, &mut |recv, f| {
            let t = clock.now_s();
            let source = f.source_time_s();
            batch.clear();
            for m in f.markers() {
                if let Some(k) = self.index.resolve(&m.name) {
                    batch.push(MarkerSample {
                        marker: k,
                        time_s: t,
                        source_time_s: source.unwrap_or(t),
                        position_m: m.position_m,
                        occluded: m.occluded,
                    });
                }
            }
            let frame = InputFrame {
                time_s: t,
                receive_unix_s: recv,
                source_time_s: source,
                frame: f.frame,
                samples: &batch,
                names: self.index.names(),
            };
            if !sink.frame(&frame) {
                stop.store(true, Ordering::Relaxed);
            }
        });
        super::with_refused(stats.to_string(), &self.index)
    }
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
    // Each kind of problem is said once; the rest are counted.
    let said = std::cell::RefCell::new(SaidOnce::default());
    super::udp::udp_loop(
        socket,
        stop,
        &mut |now, from, bytes| {
            stats.received(bytes.len(), now);
            match mapping.decode_into(bytes, &mut frame) {
                Ok(()) => on_frame(now, &frame),
                Err(e) => {
                    stats.error();
                    if said.borrow_mut().first(Ok(std::mem::discriminant(&e))) {
                        tracing::warn!("osc: a packet from {from} did not decode: {e} (said once per kind of problem; the rest are counted as not decodable)");
                    }
                }
            }
        },
        &mut |e| {
            stats.error();
            if said.borrow_mut().first(Err(e.kind())) {
                tracing::warn!(
                    "osc: receiving failed: {e} (said once; the rest are counted as not decodable)"
                );
            }
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
