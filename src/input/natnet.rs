//! The NatNet input (OptiTrack Motive's data stream, UDP): binds the data port (joining the
//! group when the address is multicast), decodes frames of mocap data with
//! [`crate::protocol::natnet`], and hands each frame's markers to a callback.
//!
//! Marker names: a marker set's markers are `SET_1`, `SET_2`, ... in the set's order (the
//! names Motive itself gives the members of its `all` set); the `all` set is skipped as a
//! duplicate; a frame without marker sets names its labelled markers `ASSET_MEMBER`. A
//! member is occluded when a labelled marker at its very position is flagged
//! occluded (Motive repeats the member's position there).

use crate::protocol::natnet::{decode, Message, MocapFrame, Version};
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

/// Binds the data port `addr` ([`super::udp_bind`]: a multicast address joins the
/// group).
pub fn bind(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    super::udp_bind(addr)
}

/// The named markers of a frame, appended to `out`. Without marker sets (Motive can
/// stream labelled markers only), the labelled markers come out as `ASSET_MEMBER` by
/// their ids.
pub fn markers_of(f: &MocapFrame, out: &mut Vec<NamedMarker>) {
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
                name: format!("{set}_{}", k + 1),
                position_m: if occluded { DVec3::NAN } else { p.as_dvec3() },
                occluded,
            });
        }
    }
    if out.len() == start {
        for m in &f.labeled {
            out.push(NamedMarker {
                name: format!("{}_{}", m.asset_id, m.member_id),
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

/// Receives on `socket` until `stop` is set; calls `on_frame(receive_unix_s, frame)` for
/// every frame of mocap data.
pub fn run(
    socket: &UdpSocket,
    version: Version,
    stop: &AtomicBool,
    stats: &NatNetStats,
    on_frame: &mut dyn FnMut(f64, &MocapFrame),
) {
    super::udp_loop(
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
    fn marker_sets_are_named_by_member_and_all_is_skipped() {
        let b = crate::bench::codecs::natnet_frame(3);
        let Message::Frame(f) = decode(&b, Version(3, 0)).unwrap() else {
            panic!("a frame")
        };
        let mut out = Vec::new();
        markers_of(&f, &mut out);
        let names: Vec<&str> = out.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["Body_1", "Body_2", "Body_3"]);
        assert!((out[1].position_m - DVec3::new(0.03, 0.04, 0.05)).length() < 1e-6);
    }
}
