//! Golden tests with the real OptiTrack Motive 2.1 / NatNet 3.0 packets in
//! `../shared/data/natnet` (skipped, with the reason printed, when absent). Expected figures
//! were read off the packets independently (a Python struct walk that consumed every byte).

use rigless::protocol::natnet::{
    decode, encode_connect, encode_request_modeldef, Description, Message, ServerInfo, Version,
};

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
        // Motive 2.1 speaking NatNet 3.0, streaming to the default group on 1511.
        assert_eq!(
            decode(&b, V3).unwrap(),
            Message::ServerInfo(ServerInfo {
                app: "Motive".into(),
                app_version: [2, 1, 0, 0],
                natnet: Version(3, 0),
                clock_hz: Some(3_312_787),
                data_port: Some(1511),
                multicast_group: Some(std::net::Ipv4Addr::new(239, 255, 42, 99)),
            })
        );
    }
    // What a client sends, byte for byte as the NatNet SDK's client sent it.
    if let Some(b) = packet("connect_packet_v3.bin") {
        assert_eq!(encode_connect(V3), b);
    }
    if let Some(b) = packet("requestmodeldef_packet_v3.bin") {
        assert_eq!(encode_request_modeldef().to_vec(), b);
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
        markers_of(f, &Default::default(), &mut named);
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
    // The other frame has no marker sets: its labelled markers, by asset and member (ids
    // 0x20001..0x20005 read off the packet independently); the sixth, 0xc357, is a
    // point-cloud marker of no asset (asset 0), no marker's.
    let names: Vec<&str> = frames[1].iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["2_1", "2_2", "2_3", "2_4", "2_5"]);
}

/// The command port with Motive's real answers: a loopback server takes the client's
/// connect request (byte for byte the NatNet SDK's), answers with the real server info
/// and, asked, the real model definitions, then streams the real frame unicast to the
/// client's data port while counting its keep-alives. The labelled markers of asset 2
/// (the rigid body "RaceQuad") get the names of its marker set.
#[test]
fn the_command_port_names_markers_and_keeps_unicast_alive() {
    use rigless::input::natnet::{bind, markers_of, run_input, NatNetStats};
    use rigless::protocol::natnet::{NAT_KEEPALIVE, NAT_REQUEST_MODELDEF};
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    use std::time::{Duration, Instant};
    let (Some(info), Some(models), Some(frame)) = (
        packet("serverinfo_packet_v3.bin"),
        packet("modeldef_packet_v3.bin"),
        packet("mocapframe_packet_v3.bin"),
    ) else {
        return;
    };
    let server = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    server
        .set_read_timeout(Some(Duration::from_millis(20)))
        .unwrap();
    let server_addr = server.local_addr().unwrap();
    let data_addr: std::net::SocketAddr = "127.0.0.1:0".parse().unwrap();
    let data = bind(data_addr).unwrap();
    let data_addr = data.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let client = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let stats = NatNetStats::default();
            let mut frames: Vec<Vec<String>> = Vec::new();
            run_input(
                &data,
                data_addr,
                V3,
                Some(server_addr),
                &stop,
                &stats,
                &mut |_, f, names| {
                    let mut named = Vec::new();
                    markers_of(f, names, &mut named);
                    frames.push(named.into_iter().map(|m| m.name).collect());
                },
            )
            .unwrap();
            frames
        })
    };
    let (mut connects, mut model_requests, mut keepalives) = (0, 0, 0);
    let mut buf = [0u8; 2048];
    let end = Instant::now() + Duration::from_millis(3500);
    let mut next_frame = Instant::now();
    while Instant::now() < end {
        if let Ok((n, from)) = server.recv_from(&mut buf) {
            let id = u16::from_le_bytes([buf[0], buf[1]]);
            if buf[..n] == encode_connect(V3)[..] {
                connects += 1;
                server.send_to(&info, from).unwrap();
            } else if id == NAT_REQUEST_MODELDEF {
                model_requests += 1;
                server.send_to(&models, from).unwrap();
            } else if id == NAT_KEEPALIVE {
                keepalives += 1;
            }
        }
        if connects > 0 && Instant::now() >= next_frame {
            server.send_to(&frame, data_addr).unwrap();
            next_frame += Duration::from_millis(50);
        }
    }
    stop.store(true, Ordering::Relaxed);
    let frames = client.join().unwrap();
    assert_eq!(
        (connects, model_requests),
        (1, 1),
        "each asked once, answered at once"
    );
    // One a second once connected, over about 3.4 s.
    assert!((2..=4).contains(&keepalives), "{keepalives} keep-alives");
    assert!(frames.len() >= 40, "{} frames", frames.len());
    let named: Vec<&str> = frames.last().unwrap().iter().map(String::as_str).collect();
    assert_eq!(
        named,
        [
            "RaceQuad:Marker1",
            "RaceQuad:Marker2",
            "RaceQuad:Marker3",
            "RaceQuad:Marker4",
            "RaceQuad:Marker5"
        ]
    );
}

/// Two assets in one real frame, without model definitions (a client that never got
/// them names a labelled marker `ASSET_MEMBER` from the asset id packed in its id): the
/// real frame's labelled markers of asset 2, and the same again as asset 5, 3 m to the
/// side, re-encoded and decoded. Two actors claiming `2_*` and `5_*` each get their own
/// asset's, member by member, and nothing of the other's. The frame's markers of asset
/// 0 (Motive's unlabelled points, ids 50000 and up) are no asset's: not named at all.
#[test]
fn two_assets_route_by_the_asset_id_without_model_definitions() {
    use rigless::input::natnet::{markers_of, ModelNames};
    use rigless::markers::index::{ActorLabels, Claim, MarkerIndex};
    use rigless::protocol::natnet::encode_frame;
    let Some(b) = packet("mocapframe_packet_v3.bin") else {
        return;
    };
    let Message::Frame(mut f) = decode(&b, V3).unwrap() else {
        panic!("a frame")
    };
    let of_asset_2 = f.labeled.iter().filter(|m| m.asset_id == 2).count();
    assert_eq!(of_asset_2, 5, "the real frame's asset 2 members");
    let unlabelled = f.labeled.iter().filter(|m| m.asset_id == 0).count();
    assert_eq!(unlabelled, 1, "the real frame's unlabelled point");
    let second: Vec<_> = f
        .labeled
        .iter()
        .filter(|m| m.asset_id == 2)
        .map(|m| {
            let mut m = m.clone();
            m.asset_id = 5;
            m.position_m += glam::Vec3::new(3.0, 0.0, 0.0);
            m
        })
        .collect();
    f.labeled.extend(second);
    let Message::Frame(f) = decode(&encode_frame(&f).unwrap(), V3).unwrap() else {
        panic!("a frame")
    };
    let mut named = Vec::new();
    markers_of(&f, &ModelNames::default(), &mut named);
    let names: Vec<&str> = named.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        ["2_1", "2_2", "2_3", "2_4", "2_5", "5_1", "5_2", "5_3", "5_4", "5_5"]
    );
    // Each actor's markers are the asset's members by number.
    let members: Vec<String> = (1..=5).map(|k| k.to_string()).collect();
    let actor = |name: &str, asset: &str| ActorLabels {
        names: members.iter().map(|m| format!("{name}:{m}")).collect(),
        markers: members.clone(),
        claim: Claim::Patterns(vec![format!("{asset}_*")]),
    };
    let mut index = MarkerIndex::for_actors(&[actor("Ann", "2"), actor("Bob", "5")]);
    for m in &named {
        let k = index
            .resolve(&m.name)
            .expect("every named marker is claimed") as usize;
        let (asset, member) = m.name.split_once('_').unwrap();
        // Ann's markers are stage indices 0..5, Bob's 5..10, each member at its number.
        let start = if asset == "2" { 0 } else { 5 };
        assert_eq!(
            k,
            start + member.parse::<usize>().unwrap() - 1,
            "{}",
            m.name
        );
        let x = m.position_m.x;
        assert_eq!(x > 2.0, asset == "5", "{}: x {x}", m.name);
    }
}
