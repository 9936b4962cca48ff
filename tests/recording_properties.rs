//! Property tests of the recording readers under a memory bound: arbitrary bytes, valid
//! files with arbitrary header values (rates, counts, frame ranges, lengths, numbers of
//! names), and valid files damaged, for C3D, TSV, BVH and session files. Every one reads
//! to `Ok` or `Err` without a panic, within `alloc_meter`'s bounds on the peak of live
//! bytes and on the largest single request (64 MiB + 64 bytes a byte, 32 MiB + 32 bytes
//! a byte), and a recording read has a rate within the limits and one position per label
//! in every frame.
//!
//! `RIGLESS_ALLOC_REPORT=1` prints each case's figures. The kept fuzz corpus is read too.

mod alloc_meter;

use alloc_meter::measure;
use proptest::prelude::*;
use proptest::test_runner::Config;
use rigless::replay::recording::{rate_in_range, Recording, RecordingError};
use rigless::replay::session::{crc32, MAGIC, VERSION};

/// Cases per property: the five properties take a few seconds each in release.
const CASES: u32 = 96;

fn config() -> Config {
    Config {
        cases: CASES,
        failure_persistence: None,
        ..Config::default()
    }
}

/// Reads `bytes` with `read` under the meter and checks the bounds and what was read.
fn check(kind: &str, bytes: &[u8], read: impl FnOnce(&[u8]) -> Result<Recording, RecordingError>) {
    let (r, u) = measure(|| read(bytes));
    if std::env::var_os("RIGLESS_ALLOC_REPORT").is_some() {
        let frames = r.as_ref().map_or(0, |r| r.frames.len());
        eprintln!(
            "{kind}: {} bytes, ok {}, frames {frames}, peak {} B, largest {} B",
            bytes.len(),
            r.is_ok(),
            u.peak,
            u.largest
        );
    }
    u.assert_within(bytes.len(), kind);
    if let Ok(rec) = r {
        assert!(rate_in_range(rec.rate_hz), "{kind}: rate {}", rec.rate_hz);
        assert!(!rec.frames.is_empty());
        assert!(rec.frames.iter().all(|f| f.len() == rec.labels.len()));
        assert!(rec.duration_secs().is_finite());
    }
}

/// An f32's bits: anything, or a plausible rate, or an edge.
fn f32_bits() -> impl Strategy<Value = u32> {
    prop_oneof![
        1 => any::<u32>(),
        2 => (0.5f32..2000.0).prop_map(f32::to_bits),
        1 => prop::sample::select(vec![
            0u32,
            1,
            0x8000_0001,
            f32::MAX.to_bits(),
            f32::INFINITY.to_bits(),
            f32::NAN.to_bits(),
            (-1.0f32).to_bits(),
            0.1f32.to_bits(),
            1e6f32.to_bits(),
        ]),
    ]
}

/// A 16-bit count: anything, or small.
fn count16() -> impl Strategy<Value = i16> {
    prop_oneof![1 => any::<i16>(), 2 => 0i16..12]
}

/// A C3D file's header values and data.
#[derive(Clone, Debug)]
struct C3dSpec {
    mips: bool,
    /// Header words 1-4: points, analog values per frame, first and last frame.
    words: [u16; 4],
    header_scale: u32,
    header_rate: u32,
    /// The header's data block: `None` for the block after the parameters.
    data_block: Option<u16>,
    point_used: Option<i16>,
    point_rate: Option<u32>,
    point_scale: Option<u32>,
    point_frames: Option<i16>,
    data_start: Option<i16>,
    analog_used: Option<i16>,
    analog_rate: Option<u32>,
    trial: Option<[i16; 4]>,
    /// POINT:LABELS dimensions (width, count).
    labels: Option<(u8, u8)>,
    data: Vec<u8>,
}

fn c3d_spec() -> impl Strategy<Value = C3dSpec> {
    let header = (
        any::<bool>(),
        prop_oneof![
            1 => any::<[u16; 4]>(),
            3 => (0u16..12, 0u16..12, 0u16..3, 0u16..200).prop_map(|(a, b, c, d)| [a, b, c, d])
        ],
        f32_bits(),
        f32_bits(),
        prop::option::weighted(0.2, any::<u16>()),
    );
    let point = (
        prop::option::of(count16()),
        prop::option::of(f32_bits()),
        prop::option::of(f32_bits()),
        prop::option::of(prop_oneof![any::<i16>(), 0i16..200]),
        prop::option::weighted(0.2, any::<i16>()),
    );
    let rest = (
        prop::option::of(count16()),
        prop::option::of(f32_bits()),
        prop::option::weighted(0.2, any::<[i16; 4]>()),
        prop::option::of((any::<u8>(), any::<u8>())),
        prop::collection::vec(any::<u8>(), 0..6000),
    );
    (header, point, rest).prop_map(|(h, p, r)| C3dSpec {
        mips: h.0,
        words: h.1,
        header_scale: h.2,
        header_rate: h.3,
        data_block: h.4,
        point_used: p.0,
        point_rate: p.1,
        point_scale: p.2,
        point_frames: p.3,
        data_start: p.4,
        analog_used: r.0,
        analog_rate: r.1,
        trial: r.2,
        labels: r.3,
        data: r.4,
    })
}

/// The file of a [`C3dSpec`], built byte by byte (Intel or MIPS order).
fn c3d_file(s: &C3dSpec) -> Vec<u8> {
    let u16b = |v: u16| {
        if s.mips {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let u32b = |v: u32| {
        if s.mips {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let mut b = vec![0u8; 512];
    b[0] = 2;
    b[1] = 0x50;
    for (i, w) in s.words.iter().enumerate() {
        b[2 + 2 * i..4 + 2 * i].copy_from_slice(&u16b(*w));
    }
    b[12..16].copy_from_slice(&u32b(s.header_scale));
    b[20..24].copy_from_slice(&u32b(s.header_rate));
    let mut p = vec![1u8, 0x50, 0, if s.mips { 86 } else { 84 }];
    for (id, name) in [(1u8, "POINT"), (2, "ANALOG"), (3, "TRIAL")] {
        p.extend([name.len() as u8, id.wrapping_neg()]);
        p.extend(name.bytes());
        p.extend(u16b(3));
        p.push(0);
    }
    let mut param = |id: u8, name: &str, kind: i8, dims: &[u8], data: &[u8]| {
        p.extend([name.len() as u8, id]);
        p.extend(name.bytes());
        p.extend(u16b((5 + dims.len() + data.len()) as u16));
        p.extend([kind as u8, dims.len() as u8]);
        p.extend(dims);
        p.extend(data);
        p.push(0);
    };
    let int = |v: i16| u16b(v as u16);
    if let Some(v) = s.point_used {
        param(1, "USED", 2, &[], &int(v));
    }
    if let Some(v) = s.point_rate {
        param(1, "RATE", 4, &[], &u32b(v));
    }
    if let Some(v) = s.point_scale {
        param(1, "SCALE", 4, &[], &u32b(v));
    }
    if let Some(v) = s.point_frames {
        param(1, "FRAMES", 2, &[], &int(v));
    }
    if let Some(v) = s.data_start {
        param(1, "DATA_START", 2, &[], &int(v));
    }
    if let Some(v) = s.analog_used {
        param(2, "USED", 2, &[], &int(v));
    }
    if let Some(v) = s.analog_rate {
        param(2, "RATE", 4, &[], &u32b(v));
    }
    if let Some(t) = s.trial {
        let data: Vec<u8> = [t[0], t[1]].iter().flat_map(|v| int(*v)).collect();
        param(3, "ACTUAL_START_FIELD", 2, &[2], &data);
        let data: Vec<u8> = [t[2], t[3]].iter().flat_map(|v| int(*v)).collect();
        param(3, "ACTUAL_END_FIELD", 2, &[2], &data);
    }
    if let Some((w, n)) = s.labels {
        let data: Vec<u8> = (0..w as usize * n as usize)
            .map(|i| b'A' + (i % 26) as u8)
            .collect();
        param(1, "LABELS", -1, &[w, n], &data);
    }
    p.extend([0; 4]);
    let blocks = p.len().div_ceil(512);
    p[2] = blocks as u8;
    p.resize(blocks * 512, 0);
    b.extend(p);
    let data_block = s.data_block.unwrap_or(2 + blocks as u16);
    b[16..18].copy_from_slice(&u16b(data_block));
    b.extend(&s.data);
    b
}

/// Marker positions' text for TSV cells, chosen by `seed`: numbers, NaN, empty.
fn tsv_cell(seed: u64) -> String {
    match seed % 7 {
        0 => "NaN".into(),
        1 => String::new(),
        2 => "0.000".into(),
        3 => format!("-{}.5", seed % 5000),
        _ => format!("{}.{:03}", seed % 3000, seed % 1000),
    }
}

/// A TSV export: header lines with the given FREQUENCY and NO_OF_FRAMES text, `markers`
/// names, and `lines` frame lines (with `extra` more or fewer columns on one of them).
fn tsv_text(
    freq: &str,
    frames_text: &str,
    markers: usize,
    lines: usize,
    frame_time: bool,
    extra: i8,
    seed: u64,
) -> String {
    let mut t =
        format!("NO_OF_FRAMES\t{frames_text}\nNO_OF_MARKERS\t{markers}\nFREQUENCY\t{freq}\n");
    t += "MARKER_NAMES";
    for k in 0..markers {
        t += &format!("\tm{k}");
    }
    t += "\n";
    if frame_time {
        t += "Frame\tTime\n";
    }
    let mut x = seed | 1;
    for f in 0..lines {
        let mut cells: Vec<String> = Vec::new();
        if frame_time {
            cells.push(format!("{}", f + 1));
            cells.push(format!("{:.3}", f as f64 * 0.01));
        }
        let mut n = 3 * markers;
        if f == lines / 2 {
            n = (n as i64 + extra as i64).max(0) as usize;
        }
        for _ in 0..n {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            cells.push(tsv_cell(x));
        }
        t += &cells.join("\t");
        t += "\n";
    }
    t
}

/// A TSV's marker count: few, or about the limit, with few lines then.
fn tsv_shape() -> impl Strategy<Value = (usize, usize)> {
    prop_oneof![(0usize..40, 0usize..200), (9_990usize..10_010, 0usize..4)]
}

/// A number's text: anything, plausible, or not a number.
fn number_text() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<f64>().prop_map(|f| format!("{f}")),
        any::<f64>().prop_map(|f| format!("{f:e}")),
        (0.5f64..2000.0).prop_map(|f| format!("{f}")),
        prop::sample::select(vec![
            "0", "-1", "1e300", "1e-300", "5e-324", "inf", "NaN", "", "x"
        ])
        .prop_map(str::to_owned),
    ]
}

/// A BVH joint: its parent (an earlier joint), its channels' text, an end site.
#[derive(Clone, Debug)]
struct BvhJoint {
    parent: usize,
    channels: String,
    end_site: bool,
}

fn channels_text() -> impl Strategy<Value = String> {
    let names = [
        "Xposition",
        "Yposition",
        "Zposition",
        "Zrotation",
        "Xrotation",
        "Yrotation",
    ];
    prop_oneof![
        30 => (0usize..=6).prop_map(move |n| format!("{n} {}", names[..n].join(" "))),
        1 => prop::sample::select(vec!["7", "-1", "1e300", "2.5", "x"]).prop_map(str::to_owned),
    ]
}

fn bvh_joints() -> impl Strategy<Value = Vec<BvhJoint>> {
    let joint =
        |channels: BoxedStrategy<String>| (any::<prop::sample::Index>(), channels, any::<bool>());
    // Many joints mostly without channels: the positions a value makes multiply.
    let mostly_none = prop_oneof![9 => Just("0".to_owned()), 1 => channels_text()].boxed();
    prop_oneof![
        4 => prop::collection::vec(joint(channels_text().boxed()), 1..30),
        1 => prop::collection::vec(joint(mostly_none), 900..1100),
    ]
    .prop_map(|js| {
        js.into_iter()
            .enumerate()
            .map(|(i, (p, channels, end_site))| BvhJoint {
                parent: if i == 0 { 0 } else { p.index(i) },
                channels,
                end_site,
            })
            .collect()
    })
}

/// A BVH file's text: the joints (nested by parent), then the motion header and
/// `values` numbers.
fn bvh_text(joints: &[BvhJoint], frames: &str, frame_time: &str, values: usize) -> String {
    fn joint(t: &mut String, joints: &[BvhJoint], j: usize) {
        t.push_str(&format!(
            "{} j{j}\n{{\nOFFSET 1 2 3\nCHANNELS {}\n",
            if j == 0 { "ROOT" } else { "JOINT" },
            joints[j].channels
        ));
        for c in (j + 1..joints.len()).filter(|c| joints[*c].parent == j) {
            joint(t, joints, c);
        }
        if joints[j].end_site {
            t.push_str("End Site\n{\nOFFSET 0 1 0\n}\n");
        }
        t.push_str("}\n");
    }
    let mut t = String::from("HIERARCHY\n");
    joint(&mut t, joints, 0);
    t += &format!("MOTION\nFrames: {frames}\nFrame Time: {frame_time}\n");
    for v in 0..values {
        t += &format!("{}.{} ", v % 90, v % 10);
        if v % 12 == 11 {
            t += "\n";
        }
    }
    t
}

/// A session: marker count, rate text (JSON), samples `(marker, time)` and how they are
/// split into records.
#[derive(Clone, Debug)]
struct SessionSpec {
    markers: usize,
    rate: String,
    samples: Vec<(u32, f64)>,
    records: usize,
}

fn session_spec() -> impl Strategy<Value = SessionSpec> {
    let rate = prop_oneof![
        1 => any::<f64>().prop_map(|f| format!("{f:?}")),
        3 => (1.0f64..2000.0).prop_map(|f| format!("{f:?}")),
        1 => prop::sample::select(vec!["0", "-100", "1e9", "5e-324", "1e5", "0.1", "120"])
            .prop_map(str::to_owned),
    ];
    let markers = prop_oneof![4 => 0usize..40, 1 => 9_995usize..10_005];
    // Samples within a few seconds, and in some files a few anywhere in time or of a
    // marker not listed.
    let sample = (0u32..40, 0.0f64..5.0);
    let outlier = (
        prop_oneof![0u32..40, any::<u32>()],
        prop_oneof![
            any::<f64>(),
            prop::sample::select(vec![800_000.0, 1e15, -1e308, 1e308, f64::NAN]),
        ],
    );
    (
        markers,
        rate,
        prop::collection::vec(sample, 0..300),
        prop_oneof![3 => Just(vec![]), 1 => prop::collection::vec(outlier, 1..3)],
        1usize..6,
    )
        .prop_map(|(markers, rate, mut samples, outliers, records)| {
            samples.extend(outliers);
            SessionSpec {
                markers,
                rate,
                samples,
                records,
            }
        })
}

fn record(out: &mut Vec<u8>, kind: u8, payload: &[u8]) {
    out.extend((payload.len() as u32).to_le_bytes());
    let mut body = vec![kind];
    body.extend(payload);
    out.extend(&body);
    out.extend(crc32(&body).to_le_bytes());
}

fn session_file(s: &SessionSpec) -> Vec<u8> {
    let mut b = MAGIC.to_vec();
    b.extend(VERSION.to_le_bytes());
    let names: Vec<String> = (0..s.markers).map(|k| format!("\"m{k}\"")).collect();
    let header = format!(
        r#"{{"marker_names":[{}],"rate_hz":{},"started_unix_s":1.7e9,"inputs":["replay"]}}"#,
        names.join(","),
        s.rate
    );
    record(&mut b, 1, header.as_bytes());
    let per = s.samples.len().div_ceil(s.records).max(1);
    for chunk in s.samples.chunks(per) {
        let mut p = (chunk.len() as u32).to_le_bytes().to_vec();
        for &(marker, t) in chunk {
            p.extend(marker.to_le_bytes());
            p.extend(t.to_le_bytes());
            p.extend(t.to_le_bytes());
            for c in [0.1f32, 0.2, 0.3] {
                p.extend(c.to_le_bytes());
            }
            p.push((marker % 3 == 0) as u8);
        }
        record(&mut b, 2, &p);
    }
    b
}

/// Flips, cuts and inserts: `(where, what)` pairs applied to a valid file.
fn damage(mut b: Vec<u8>, edits: &[(prop::sample::Index, u8, u8)]) -> Vec<u8> {
    for (at, how, v) in edits {
        if b.is_empty() {
            break;
        }
        let i = at.index(b.len());
        match how % 4 {
            0 | 1 => b[i] ^= v | 1,
            2 => b.truncate(i),
            _ => b
                .splice(i..i, std::iter::repeat_n(*v, (*v as usize % 40) + 1))
                .for_each(drop),
        }
    }
    b
}

fn edits() -> impl Strategy<Value = Vec<(prop::sample::Index, u8, u8)>> {
    prop::collection::vec(
        (any::<prop::sample::Index>(), any::<u8>(), any::<u8>()),
        0..4,
    )
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn arbitrary_bytes_in_every_format(b in prop::collection::vec(any::<u8>(), 0..4096)) {
        check("c3d bytes", &b, |b| Recording::from_c3d("p.c3d", b));
        check("tsv bytes", &b, |b| Recording::from_tsv("p.tsv", b));
        check("bvh bytes", &b, |b| Recording::from_bvh("p.bvh", b, 0.01));
        check("session bytes", &b, |b| Recording::from_session_bytes("p.rlsession", b));
        // The same bytes after each format's opening, to get past the first check.
        let mut c3d = vec![2u8, 0x50];
        c3d.extend(&b);
        if c3d.len() > 515 {
            c3d[515] = 84;
        }
        check("c3d bytes after a key", &c3d, |b| Recording::from_c3d("p.c3d", b));
        let mut s = MAGIC.to_vec();
        s.extend(VERSION.to_le_bytes());
        s.extend(&b);
        check("session bytes after the magic", &s, |b| Recording::from_session_bytes("p.rlsession", b));
        let mut t = b"HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 1 Xposition\n}\nMOTION\n".to_vec();
        t.extend(&b);
        check("bvh bytes after a hierarchy", &t, |b| Recording::from_bvh("p.bvh", b, 0.01));
    }

    #[test]
    fn c3d_with_arbitrary_header_values(spec in c3d_spec(), e in edits()) {
        let b = c3d_file(&spec);
        check("c3d", &b, |b| Recording::from_c3d("p.c3d", b));
        let d = damage(b, &e);
        check("c3d damaged", &d, |b| Recording::from_c3d("p.c3d", b));
    }

    #[test]
    fn tsv_with_arbitrary_header_values(
        freq in prop_oneof![1 => number_text(), 3 => (1.0f64..2000.0).prop_map(|f| f.to_string())],
        frames_text in number_text(),
        (markers, lines) in tsv_shape(),
        frame_time in any::<bool>(),
        extra in prop_oneof![3 => Just(0i8), 1 => -4i8..4],
        seed in any::<u64>(),
        e in edits(),
    ) {
        let t = tsv_text(&freq, &frames_text, markers, lines, frame_time, extra, seed);
        check("tsv", t.as_bytes(), |b| Recording::from_tsv("p.tsv", b));
        let d = damage(t.into_bytes(), &e);
        check("tsv damaged", &d, |b| Recording::from_tsv("p.tsv", b));
    }

    #[test]
    fn bvh_with_arbitrary_header_values(
        joints in bvh_joints(),
        frames in prop_oneof![
            1 => number_text(),
            1 => any::<u64>().prop_map(|n| n.to_string()),
            3 => (0u32..500).prop_map(|n| n.to_string()),
        ],
        frame_time in prop_oneof![1 => number_text(), 3 => (0.001f64..0.1).prop_map(|f| f.to_string())],
        values in 0usize..4000,
        e in edits(),
    ) {
        let t = bvh_text(&joints, &frames, &frame_time, values);
        check("bvh", t.as_bytes(), |b| Recording::from_bvh("p.bvh", b, 0.01));
        let d = damage(t.into_bytes(), &e);
        check("bvh damaged", &d, |b| Recording::from_bvh("p.bvh", b, 0.01));
    }

    #[test]
    fn sessions_with_arbitrary_header_values(spec in session_spec(), e in edits()) {
        let b = session_file(&spec);
        check("session", &b, |b| Recording::from_session_bytes("p.rlsession", b));
        let d = damage(b, &e);
        check("session damaged", &d, |b| Recording::from_session_bytes("p.rlsession", b));
    }
}

#[test]
fn a_plausible_file_of_each_kind_reads() {
    // The generators' plausible corner, fixed: each reader returns frames.
    let c3d = C3dSpec {
        mips: false,
        words: [2, 0, 1, 10],
        header_scale: (-1f32).to_bits(),
        header_rate: 100f32.to_bits(),
        data_block: None,
        point_used: None,
        point_rate: None,
        point_scale: None,
        point_frames: None,
        data_start: None,
        analog_used: None,
        analog_rate: None,
        trial: None,
        labels: Some((2, 2)),
        data: vec![0; 10 * 32],
    };
    let r = Recording::from_c3d("p.c3d", &c3d_file(&c3d)).unwrap();
    assert_eq!((r.frames.len(), r.labels.len(), r.rate_hz), (10, 2, 100.0));
    let t = tsv_text("100", "5", 3, 5, true, 0, 7);
    let r = Recording::from_tsv("p.tsv", t.as_bytes()).unwrap();
    assert_eq!((r.frames.len(), r.labels.len()), (5, 3));
    let joints = vec![
        BvhJoint {
            parent: 0,
            channels: "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation".into(),
            end_site: false,
        },
        BvhJoint {
            parent: 0,
            channels: "3 Zrotation Xrotation Yrotation".into(),
            end_site: true,
        },
    ];
    let t = bvh_text(&joints, "4", "0.01", 36);
    let r = Recording::from_bvh("p.bvh", t.as_bytes(), 0.01).unwrap();
    assert_eq!((r.frames.len(), r.labels.len(), r.rate_hz), (4, 3, 100.0));
    let s = SessionSpec {
        markers: 2,
        rate: "100".into(),
        samples: vec![(0, 1.0), (1, 1.02)],
        records: 2,
    };
    let r = Recording::from_session_bytes("p.rlsession", &session_file(&s)).unwrap();
    assert_eq!((r.frames.len(), r.labels.len()), (3, 2));
}

/// The kept fuzz corpus (`fuzz/corpus/<target>/`: the crafted files of
/// `tests/hostile_recordings.rs` and whatever a fuzzing run found and was kept) reads
/// within the same bounds, through the same entry points as the fuzz targets.
#[test]
fn the_kept_fuzz_corpus_reads_within_bounds() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus");
    let mut read = 0;
    for kind in ["c3d", "tsv", "bvh", "session"] {
        let dir = root.join(kind);
        let mut paths: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        paths.sort();
        assert!(!paths.is_empty(), "{}: no seed", dir.display());
        for path in paths {
            let b = std::fs::read(&path).unwrap();
            let name = path.display().to_string();
            match kind {
                "c3d" => check(&name, &b, |b| Recording::from_c3d("p.c3d", b)),
                "tsv" => check(&name, &b, |b| Recording::from_tsv("p.tsv", b)),
                "bvh" => check(&name, &b, |b| Recording::from_bvh("p.bvh", b, 0.01)),
                _ => check(&name, &b, |b| {
                    Recording::from_session_bytes("p.rlsession", b)
                }),
            }
            read += 1;
        }
    }
    println!("{read} corpus files read within bounds");
}
