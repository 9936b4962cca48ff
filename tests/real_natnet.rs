//! Golden tests with the real OptiTrack Motive 2.1 / NatNet 3.0 packets in
//! `../shared/data/natnet` (skipped, with the reason printed, when absent). Expected figures
//! were read off the packets independently (a Python struct walk that consumed every byte).

use rigless::protocol::natnet::{decode, Description, Message, Version};

mod common;

fn packet(name: &str) -> Option<Vec<u8>> {
    common::shared_file(&format!("natnet/{name}"))
}

const V3: Version = Version(3, 0);

#[test]
fn frame_of_mocap_data() {
    let Some(b) = packet("mocapframe_packet_v3.bin") else {
        return;
    };
    let Message::Frame(f) = decode(&b, V3).unwrap() else {
        panic!("a frame")
    };
    assert_eq!(f.frame, 162_734);
    assert!(f.marker_sets.is_empty());
    assert_eq!(f.unlabeled.len(), 5);
    assert_eq!(f.rigid_bodies.len(), 1);
    let rb = &f.rigid_bodies[0];
    assert_eq!(rb.id, 2);
    assert!(rb.tracking_valid);
    assert!(
        (rb.position_m - glam::Vec3::new(0.174_446_6, 1.447_131_4, -0.734_304)).length() < 1e-6
    );
    assert_eq!(f.labeled.len(), 6);
    assert_eq!((f.labeled[0].asset_id, f.labeled[0].member_id), (2, 1));
    assert!(f.labeled.iter().all(|m| !m.occluded));
}

#[test]
fn occluded_frame_with_marker_sets() {
    let Some(b) = packet("mocapframe_packet_occluded_v3.bin") else {
        return;
    };
    let Message::Frame(f) = decode(&b, V3).unwrap() else {
        panic!("a frame")
    };
    assert_eq!(f.frame, 269_007);
    let names: Vec<&str> = f.marker_sets.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["FakeTree", "all"]);
    assert!(f.marker_sets.iter().all(|(_, p)| p.len() == 5));
    assert_eq!(f.rigid_bodies[0].id, 7);
    // Member 1 is missing from the labelled markers; member 2 is flagged occluded.
    let members: Vec<u16> = f.labeled.iter().map(|m| m.member_id).collect();
    assert_eq!(members, [2, 3, 4, 5]);
    assert!(f.labeled[0].occluded && f.labeled[0].point_cloud_solved);
    assert!(f.labeled[1..].iter().all(|m| !m.occluded));
    assert_eq!(f.timestamp_s, 8966.9);
}

#[test]
fn model_definitions_and_server_info() {
    if let Some(b) = packet("modeldef_packet_v3.bin") {
        let Message::ModelDef(d) = decode(&b, V3).unwrap() else {
            panic!("model definitions")
        };
        assert_eq!(
            d[0],
            Description::RigidBody {
                name: "RaceQuad".into(),
                id: 2,
                parent: -1
            }
        );
        assert_eq!(
            d[1],
            Description::MarkerSet {
                name: "RaceQuad".into(),
                markers: (1..=5).map(|i| format!("Marker{i}")).collect()
            }
        );
        assert!(
            matches!(&d[2], Description::MarkerSet { name, markers } if name == "all" && markers.len() == 5)
        );
    }
    if let Some(b) = packet("serverinfo_packet_v3.bin") {
        assert_eq!(
            decode(&b, V3).unwrap(),
            Message::ServerInfo {
                app: "Motive".into(),
                natnet: Version(3, 0)
            }
        );
    }
    for (name, id) in [
        ("echoresponse_packet_v3.bin", 13),
        ("echorequest_packet_v3.bin", 12),
        ("connect_packet_v3.bin", 0),
        ("discovery_packet_v3.bin", 14),
        ("requestmodeldef_packet_v3.bin", 4),
    ] {
        if let Some(b) = packet(name) {
            assert_eq!(decode(&b, V3).unwrap(), Message::Other { id }, "{name}");
        }
    }
}

#[test]
fn every_truncation_of_a_real_frame_is_an_error_not_a_panic() {
    let Some(b) = packet("mocapframe_packet_occluded_v3.bin") else {
        return;
    };
    for cut in 0..b.len() {
        assert!(decode(&b[..cut], V3).is_err(), "cut at {cut}");
        // The same cut with its header saying so: the payload itself is short.
        if cut >= 4 {
            let mut c = b[..cut].to_vec();
            c[2..4].copy_from_slice(&((cut - 4) as u16).to_le_bytes());
            assert!(decode(&c, V3).is_err(), "payload cut at {cut}");
        }
    }
}

#[test]
fn the_input_names_markers_and_receives_real_packets_on_loopback() {
    use rigless::input::natnet::{bind, markers_of, run, NatNetStats};
    use std::sync::atomic::{AtomicBool, Ordering};
    let (Some(frame), Some(occluded), Some(modeldef)) = (
        packet("mocapframe_packet_v3.bin"),
        packet("mocapframe_packet_occluded_v3.bin"),
        packet("modeldef_packet_v3.bin"),
    ) else {
        return;
    };
    let sock = bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = sock.local_addr().unwrap();
    let tx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    for b in [&modeldef, &occluded, &b"junk"[..], &frame] {
        tx.send_to(b, addr).unwrap();
    }
    let stop = AtomicBool::new(false);
    let stats = NatNetStats::default();
    let mut frames = Vec::new();
    run(&sock, V3, &stop, &stats, &mut |_, f| {
        let mut named = Vec::new();
        markers_of(f, &mut named);
        frames.push(named);
        if frames.len() == 2 {
            stop.store(true, Ordering::Relaxed);
        }
    });
    assert_eq!(stats.packets.packets.load(Ordering::Relaxed), 4);
    assert_eq!(stats.other.load(Ordering::Relaxed), 1);
    assert_eq!(stats.packets.decode_errors.load(Ordering::Relaxed), 1);
    // The occluded frame: FakeTree's five members, the second occluded; "all" skipped.
    let names: Vec<&str> = frames[0].iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "FakeTree_1",
            "FakeTree_2",
            "FakeTree_3",
            "FakeTree_4",
            "FakeTree_5"
        ]
    );
    assert!(frames[0][1].occluded && !frames[0][1].position_m.is_finite());
    assert!(frames[0].iter().filter(|m| m.occluded).count() == 1);
    // The other frame has no marker sets: its six labelled markers, by asset and member
    // (ids 0x20001..0x20005 and 0xc357, a point-cloud marker of no asset, read off the
    // packet independently).
    let names: Vec<&str> = frames[1].iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["2_1", "2_2", "2_3", "2_4", "2_5", "0_50007"]);
}
