//! The network codecs and the OBJ reader under an allocation meter: valid packets (and an
//! OBJ file) with up to three header values overwritten by arbitrary or extreme numbers
//! (counts, lengths, ids, sizes: any 1, 2, 4 or 8 bytes, little- or big-endian, at any
//! offset), and arbitrary bytes. Each decodes to `Ok` or `Err` without a panic, with a
//! peak of live bytes of at most 1 MiB plus 64 bytes per input byte: no allocation is
//! sized by a number read from the packet beyond what its own length bounds.

mod alloc_meter;

use alloc_meter::measure;
use glam::{DVec3, Vec3};
use proptest::prelude::*;
use proptest::test_runner::Config;
use rigless::character::mesh::parse_obj;
use rigless::protocol::glove::{decode_line, encode_alpha, GloveFormat, GloveReading};
use rigless::protocol::natnet::{self, LabeledMarker, MocapFrame, RigidBody, Version};
use rigless::protocol::osc::{encode_native, OscMapping};
use rigless::protocol::vertex_stream::{
    self, FrameStatus, FrameView, StopCode, Topology, WirePart,
};
use rigless::protocol::vrpn::{
    cookie, decode_message, description_payload, encode_message, encode_pos_quat, PosQuat,
    SENDER_DESCRIPTION,
};

/// What decoding `len` bytes may hold at its peak.
fn bound(len: usize) -> usize {
    (1 << 20) + 64 * len
}

/// One valid packet (or file) of each kind, as encoded by the library.
fn packets() -> Vec<(&'static str, Vec<u8>)> {
    let natnet = natnet::encode_frame(&MocapFrame {
        frame: 7,
        marker_sets: vec![("hand".into(), vec![Vec3::new(0.1, 0.2, 0.3); 5])],
        unlabeled: vec![Vec3::ONE; 3],
        rigid_bodies: vec![RigidBody {
            id: 1,
            position_m: Vec3::ZERO,
            rotation: [0.0, 0.0, 0.0, 1.0],
            mean_error_m: 0.001,
            tracking_valid: true,
        }],
        labeled: vec![
            LabeledMarker {
                asset_id: 1,
                member_id: 2,
                position_m: Vec3::X,
                size_m: 0.01,
                occluded: false,
                point_cloud_solved: true,
                model_solved: false,
                residual_m: 0.0001,
            };
            4
        ],
        timecode: 0,
        timecode_sub: 0,
        timestamp_s: 12.5,
        params: 0,
    })
    .expect("a frame encodes");
    let osc = encode_native(
        3,
        (1, 0),
        &[("a", DVec3::ONE), ("b", DVec3::ZERO), ("c", DVec3::X)],
    );
    let mut vrpn = cookie().to_vec();
    encode_message(
        &mut vrpn,
        0,
        0,
        5,
        SENDER_DESCRIPTION,
        &description_payload("Tracker0"),
    );
    let report = PosQuat {
        sensor: 2,
        position: DVec3::new(0.1, 0.2, 0.3),
        rotation: [0.0, 0.0, 0.0, 1.0],
    };
    encode_message(&mut vrpn, 1, 2, 5, 3, &encode_pos_quat(&report));
    let mut stream = Vec::new();
    vertex_stream::encode_topology(
        &Topology {
            character: "hand".into(),
            rate_hz: 120.0,
            length_unit: "m".into(),
            up_axis: "+Y".into(),
            handedness: "right".into(),
            vertex_count: 4,
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            marker_names: vec!["m0".into(), "m1".into()],
            joint_names: vec!["a".into(), "b".into()],
            joint_parents: vec![-1, 0],
            parts: vec![
                WirePart {
                    name: "palm".into(),
                    first_vertex: 0,
                    vertex_count: 3,
                    first_triangle: 0,
                    triangle_count: 1,
                },
                WirePart {
                    name: "nail".into(),
                    first_vertex: 0,
                    vertex_count: 4,
                    first_triangle: 1,
                    triangle_count: 1,
                },
            ],
            actor: "Ann".into(),
            actor_index: 1,
            actor_count: 2,
        },
        &mut stream,
    );
    let vertices = [Vec3::ONE; 4];
    let markers = [Vec3::ZERO; 2];
    vertex_stream::encode_frame(
        &FrameView {
            frame: 9,
            actor: 1,
            source_time_s: 1.0,
            publish_time_s: 2.0,
            status: FrameStatus {
                iterations: 3,
                stop: StopCode::Converged,
                solve_ms: 0.4,
                gc_ms: 0.1,
                rrms: 1e-4,
                bone_length_error: 0.0,
                joint_limit_violation_deg: 0.0,
                marker_residual_rms_mm: 0.2,
                marker_residual_max_mm: 0.5,
            },
            marker_states: &[0, 1],
            markers_m: &markers,
            vertices_m: &vertices,
            received_time_s: 1.5,
            joints_m: &[Vec3::Y],
        },
        &mut stream,
    );
    let mut glove = String::new();
    encode_alpha(
        &GloveReading {
            curl: [Some(100); 5],
            ..GloveReading::default()
        },
        &mut glove,
    );
    let obj = b"g body\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n"
        .to_vec();
    vec![
        ("natnet", natnet),
        ("osc", osc),
        ("vrpn", vrpn),
        ("vertex stream", stream),
        ("glove", glove.into_bytes()),
        ("obj", obj),
    ]
}

/// Decodes `b` as `kind` (every message it holds), discarding the result.
fn decode(kind: &str, b: &[u8]) {
    match kind {
        "natnet" => {
            for v in [Version(3, 0), Version(4, 1)] {
                let _ = natnet::decode(b, v);
            }
        }
        "osc" => {
            let _ = OscMapping::default().decode(b);
        }
        "vrpn" => {
            let mut at = b.len().min(24);
            while let Ok(Some((_, used))) = decode_message(&b[at..]) {
                at += used;
            }
        }
        "vertex stream" => {
            let mut at = 0;
            while let Ok((_, used)) = vertex_stream::decode(&b[at..]) {
                at += used.max(1);
                if at >= b.len() {
                    break;
                }
            }
        }
        "glove" => {
            let mut out = GloveReading::default();
            for line in b.split(|&c| c == b'\n') {
                let _ = decode_line(line, GloveFormat::Alpha, 4095, &mut out);
            }
        }
        _ => {
            let _ = parse_obj(b, &[]);
        }
    }
}

/// A header value to write: any, or an edge (0, 1, all ones, the sign bit, the largest).
fn value() -> impl Strategy<Value = u64> {
    prop_oneof![
        2 => any::<u64>(),
        1 => prop::sample::select(vec![0u64, 1, u64::MAX, 1 << 31, 1 << 63, 0x7fff_ffff, 0xffff, 0x8000]),
    ]
}

/// Up to three overwrites: (offset, value, width in bytes, big-endian).
fn edits() -> impl Strategy<Value = Vec<(prop::sample::Index, u64, usize, bool)>> {
    prop::collection::vec(
        (
            any::<prop::sample::Index>(),
            value(),
            prop::sample::select(vec![1usize, 2, 4, 8]),
            any::<bool>(),
        ),
        0..=3,
    )
}

fn apply(mut b: Vec<u8>, edits: &[(prop::sample::Index, u64, usize, bool)]) -> Vec<u8> {
    for (at, v, width, big) in edits {
        let bytes = if *big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        };
        let bytes = if *big {
            &bytes[8 - width..]
        } else {
            &bytes[..*width]
        };
        let start = at.index(b.len().max(1)).min(b.len());
        for (k, x) in bytes.iter().enumerate() {
            if let Some(slot) = b.get_mut(start + k) {
                *slot = *x;
            }
        }
    }
    b
}

fn config() -> Config {
    Config {
        cases: 256,
        failure_persistence: None,
        ..Config::default()
    }
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn packets_with_arbitrary_header_values_decode_within_bounds(e in edits()) {
        for (kind, b) in packets() {
            let b = apply(b, &e);
            let ((), u) = measure(|| decode(kind, &b));
            prop_assert!(u.peak <= bound(b.len()), "{}: {} bytes, peak {}", kind, b.len(), u.peak);
        }
    }

    #[test]
    fn arbitrary_bytes_decode_within_bounds(b in prop::collection::vec(any::<u8>(), 0..2048)) {
        for (kind, _) in packets() {
            let ((), u) = measure(|| decode(kind, &b));
            prop_assert!(u.peak <= bound(b.len()), "{}: {} bytes, peak {}", kind, b.len(), u.peak);
        }
    }
}

#[test]
fn the_packets_are_valid_before_they_are_mutated() {
    for (kind, b) in packets() {
        let ok = match kind {
            "natnet" => natnet::decode(&b, Version(3, 0)).is_ok(),
            "osc" => OscMapping::default().decode(&b).is_ok(),
            "vrpn" => matches!(decode_message(&b[24..]), Ok(Some(_))),
            "vertex stream" => vertex_stream::decode(&b).is_ok(),
            "glove" => {
                let mut out = GloveReading::default();
                decode_line(
                    b.strip_suffix(b"\n").unwrap_or(&b),
                    GloveFormat::Alpha,
                    4095,
                    &mut out,
                )
                .is_ok()
            }
            _ => parse_obj(&b, &[]).is_ok(),
        };
        assert!(ok, "{kind}");
    }
}
