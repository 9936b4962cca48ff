//! Crafted recordings from the issue on hostile input, built byte by byte: each one used
//! to panic, abort, or take hundreds of megabytes to gigabytes; each is now refused with
//! an error naming the field and its value (or read, for a damaged session), within a
//! small, measured allocation. Only the readers' long-standing entry points are used, so
//! the same tests run against the readers before the fix (where they fail).

mod alloc_meter;

use alloc_meter::measure;
use rigless::replay::bvh::parse_bvh;
use rigless::replay::c3d::read_c3d;
use rigless::replay::recording::Recording;
use rigless::replay::session::{crc32, read_session, MAGIC, VERSION};
use rigless::replay::tsv::parse_tsv;

/// What a refused file may allocate: 1 MiB (the files here are at most 3 MB and are
/// refused on a header value, before any frame table).
const REFUSED: usize = 1 << 20;

/// Writes a crafted file to `$RIGLESS_WRITE_CRAFTED/name` when that is set, so the
/// command line can be measured on it (`rigless info`, peak memory in docs/robustness.md).
fn keep(name: &str, bytes: &[u8]) {
    if let Some(dir) = std::env::var_os("RIGLESS_WRITE_CRAFTED") {
        let dir = std::path::Path::new(&dir);
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join(name), bytes).unwrap();
    }
}

/// A C3D parameter: group id (1 POINT, 2 ANALOG), name, type, data.
type C3dParam<'a> = (u8, &'a str, i8, Vec<u8>);

/// An Intel C3D file: the header (1 point, frames 1..=`last`, the header scale and a rate
/// of the smallest subnormal), groups POINT and ANALOG with `params` (scalars), and
/// `frames` frames of one point from block 3, floats or 16-bit integers by the scale.
fn c3d(scale: f32, last: u16, params: &[C3dParam], frames: usize) -> Vec<u8> {
    let mut b = vec![0u8; 512];
    b[0] = 2;
    b[1] = 0x50;
    for (word, v) in [(1, 1u16), (2, 0), (3, 1), (4, last), (8, 3)] {
        b[2 * word..2 * word + 2].copy_from_slice(&v.to_le_bytes());
    }
    b[12..16].copy_from_slice(&scale.to_le_bytes());
    b[20..24].copy_from_slice(&1u32.to_le_bytes());
    let mut p = vec![1u8, 0x50, 1, 84];
    for (id, name) in [(1u8, "POINT"), (2, "ANALOG")] {
        p.extend([name.len() as u8, id.wrapping_neg()]);
        p.extend(name.bytes());
        p.extend(3i16.to_le_bytes());
        p.push(0);
    }
    for (id, name, kind, data) in params {
        p.extend([name.len() as u8, *id]);
        p.extend(name.bytes());
        p.extend((5 + data.len() as i16).to_le_bytes());
        p.extend([*kind as u8, 0]);
        p.extend(data);
        p.push(0);
    }
    p.extend([0; 4]);
    p.resize(512, 0);
    b.extend(p);
    for _ in 0..frames {
        if scale < 0.0 {
            for v in [1.0f32, 2.0, 3.0, 0.0] {
                b.extend(v.to_le_bytes());
            }
        } else {
            for v in [1i16, 2, 3, 0] {
                b.extend(v.to_le_bytes());
            }
        }
    }
    b
}

/// The issue's C3D: POINT:RATE the smallest subnormal, ANALOG:USED 3, ANALOG:RATE 1; the
/// header promises 40 frames, the data holds 10 (the wrapped 4-byte frame made it 40).
fn subnormal_rate_c3d(scale: f32) -> Vec<u8> {
    let params = [
        (1, "USED", 2, 1i16.to_le_bytes().to_vec()),
        (1, "SCALE", 4, scale.to_le_bytes().to_vec()),
        (1, "RATE", 4, 1u32.to_le_bytes().to_vec()),
        (2, "USED", 2, 3i16.to_le_bytes().to_vec()),
        (2, "RATE", 4, 1f32.to_le_bytes().to_vec()),
    ];
    c3d(scale, 40, &params, if scale < 0.0 { 10 } else { 20 })
}

#[test]
fn c3d_with_a_subnormal_point_rate_is_refused_in_float_and_integer_storage() {
    let subnormal = f32::from_bits(1) as f64;
    for scale in [-1.0f32, 0.1] {
        let b = subnormal_rate_c3d(scale);
        keep(&format!("subnormal-rate-scale{scale}.c3d"), &b);
        assert!((1000..1300).contains(&b.len()), "{}", b.len());
        let (r, u) = measure(|| read_c3d(&b));
        let e = r.expect_err("a subnormal rate is no rate").to_string();
        assert!(e.contains(&format!("POINT:RATE {subnormal:?} Hz")), "{e}");
        assert!(u.peak < REFUSED, "{u:?}");
    }
}

#[test]
fn c3d_with_a_huge_analog_rate_is_refused() {
    // The same saturation from the other side: ANALOG:RATE 3e38 over a 100 Hz POINT:RATE.
    let params = [
        (1, "USED", 2, 1i16.to_le_bytes().to_vec()),
        (1, "SCALE", 4, (-1f32).to_le_bytes().to_vec()),
        (1, "RATE", 4, 100f32.to_le_bytes().to_vec()),
        (2, "USED", 2, 3i16.to_le_bytes().to_vec()),
        (2, "RATE", 4, 3e38f32.to_le_bytes().to_vec()),
    ];
    let b = c3d(-1.0, 40, &params, 10);
    keep("huge-analog-rate.c3d", &b);
    let (r, u) = measure(|| read_c3d(&b));
    let e = r
        .expect_err("no analog board samples at 3e38 Hz")
        .to_string();
    assert!(
        e.contains(&format!("ANALOG:RATE {:?} Hz", 3e38f32 as f64)),
        "{e}"
    );
    assert!(u.peak < REFUSED, "{u:?}");
}

/// The issue's BVH: one joint with `CHANNELS 0`, so a frame needs no values.
fn no_channels_bvh(frames: &str) -> String {
    format!(
        "HIERARCHY\nROOT Hips\n{{\n  OFFSET 0 0 0\n  CHANNELS 0\n}}\nMOTION\nFrames: {frames}\n\
         Frame Time: 0.0083333\n"
    )
}

#[test]
fn bvh_without_channels_is_refused_whatever_its_frame_count() {
    // 1e300 panicked (capacity overflow), 1000000000 aborted asking for 24 GB, 1000000
    // took 93 MB for a 117-byte file.
    for frames in ["1e300", "1000000000", "1000000"] {
        let text = no_channels_bvh(frames);
        assert!(text.len() < 120);
        keep(&format!("no-channels-{frames}-frames.bvh"), text.as_bytes());
        let (r, u) = measure(|| parse_bvh(&text, 0.01));
        let e = r.expect_err("no channel, no motion").to_string();
        assert!(e.contains("no joint has a channel"), "{frames}: {e}");
        assert!(u.peak < REFUSED, "{frames}: {u:?}");
    }
}

#[test]
fn bvh_joints_without_channels_cannot_multiply_the_motion() {
    // 1000 joints and a single channel: each 2-byte value made 1000 positions, so 600 KB
    // of motion asked for 7.2 GB.
    let mut text = String::from("HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 1 Xposition\n");
    for i in 0..999 {
        text += &format!("JOINT j{i}\n{{\nOFFSET 1 0 0\n}}\n");
    }
    text += "}\nMOTION\nFrames: 300000\nFrame Time: 0.01\n";
    text += &"1\n".repeat(300_000);
    keep("1000-joints-1-channel.bvh", text.as_bytes());
    let (r, u) = measure(|| parse_bvh(&text, 0.01));
    let e = r.expect_err("too many positions for the file").to_string();
    assert!(e.contains("300000 frames × 1000 joints"), "{e}");
    assert!(u.peak < REFUSED, "{u:?}");
}

#[test]
fn bvh_and_tsv_rates_are_range_checked() {
    let bvh = "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 1 Xposition\n}\nMOTION\nFrames: 1\n\
               Frame Time: 1e-300\n0\n";
    let e = parse_bvh(bvh, 0.01).expect_err("1e300 Hz").to_string();
    assert!(e.contains("Frame Time: 1e-300 s"), "{e}");
    keep("frame-time-1e-300.bvh", bvh.as_bytes());
    let tsv = "FREQUENCY\t1e-300\nMARKER_NAMES\ta\n1\t2\t3\n";
    keep("frequency-1e-300.tsv", tsv.as_bytes());
    let e = parse_tsv(tsv)
        .expect_err("a frame every 1e300 s")
        .to_string();
    assert!(e.contains("FREQUENCY 1e-300 Hz"), "{e}");
}

/// A framed record: `u32 len`, `u8 kind`, payload, `u32 crc32(kind, payload)`.
fn record(out: &mut Vec<u8>, kind: u8, payload: &[u8]) {
    out.extend((payload.len() as u32).to_le_bytes());
    let mut body = vec![kind];
    body.extend(payload);
    out.extend(&body);
    out.extend(crc32(&body).to_le_bytes());
}

/// A session file with a header record and one samples record per entry of `records`
/// (each sample `(marker, time)`, at (0.1, 0.2, 0.3) m).
fn session(names_json: &str, rate_hz: &str, records: &[&[(u32, f64)]]) -> Vec<u8> {
    let mut b = MAGIC.to_vec();
    b.extend(VERSION.to_le_bytes());
    let header = format!(
        r#"{{"marker_names":{names_json},"rate_hz":{rate_hz},"started_unix_s":1.7e9,"inputs":["x"]}}"#
    );
    record(&mut b, 1, header.as_bytes());
    for samples in records {
        let mut p = (samples.len() as u32).to_le_bytes().to_vec();
        for &(marker, t) in *samples {
            p.extend(marker.to_le_bytes());
            p.extend(t.to_le_bytes());
            p.extend(t.to_le_bytes());
            for c in [0.1f32, 0.2, 0.3] {
                p.extend(c.to_le_bytes());
            }
            p.push(0);
        }
        record(&mut b, 2, &p);
    }
    b
}

/// Loads `bytes` as a `.rlsession` file, measuring the load.
fn load_session(bytes: &[u8]) -> (Result<Recording, String>, alloc_meter::Usage) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hostile.rlsession");
    std::fs::write(&path, bytes).unwrap();
    measure(|| Recording::load(&path).map_err(|e| e.to_string()))
}

#[test]
fn session_samples_far_apart_are_refused() {
    // Two samples 800,000 s apart at 120 Hz: 96 million frames (1.8 GB asked for, 8 GB
    // resident) from a file of about 200 bytes.
    let b = session(r#"["a","b"]"#, "120.0", &[&[(0, 0.0), (1, 800_000.0)]]);
    assert!(b.len() < 240, "{}", b.len());
    keep("samples-800000s-apart.rlsession", &b);
    let (r, u) = load_session(&b);
    let e = r.expect_err("96 million frames for 2 samples").to_string();
    assert!(
        e.contains("96000001.0 frames at 120.0 Hz, × 2 markers"),
        "{e}"
    );
    assert!(u.peak < REFUSED, "{u:?}");
}

#[test]
fn session_rates_out_of_range_are_refused() {
    // 1e9 Hz asked for 3.8 GB and ran for over a minute; 0 Hz read as "inf s", -100 Hz
    // as "-0.01 s".
    for (rate, shown) in [
        ("1e9", "1000000000.0"),
        ("0", "0.0"),
        ("-100", "-100.0"),
        ("5e-324", "5e-324"),
    ] {
        let b = session(r#"["a","b"]"#, rate, &[&[(0, 0.0), (1, 0.1)]]);
        keep(&format!("rate-{rate}.rlsession"), &b);
        let (r, u) = measure(|| read_session(&b));
        let e = r.expect_err("no such solver rate").to_string();
        assert!(e.contains(&format!("rate_hz {shown}")), "{rate}: {e}");
        assert!(u.peak < REFUSED, "{u:?}");
        let (r, u) = load_session(&b);
        assert!(r.is_err(), "{rate}");
        assert!(u.peak < REFUSED, "{u:?}");
    }
}

#[test]
fn session_with_200000_marker_names_is_refused() {
    // A 2.3 MB header: with samples 1000 frames apart its frame table took 4 GB.
    let names: Vec<String> = (0..200_000).map(|i| format!("\"m{i:07}\"")).collect();
    let names = format!("[{}]", names.join(","));
    let b = session(&names, "120.0", &[&[(0, 0.0), (1, 1000.0 / 120.0)]]);
    assert!((2_000_000..2_500_000).contains(&b.len()), "{}", b.len());
    keep("200000-names.rlsession", &b);
    let (r, u) = measure(|| read_session(&b));
    let e = r.expect_err("200,000 markers").to_string();
    assert!(e.contains("200000 marker_names"), "{e}");
    // The names kept before the count is known: at most the limit's (10,000 of them).
    assert!(u.peak < 4 * REFUSED, "{u:?}");
    let (r, u) = load_session(&b);
    assert!(r.is_err());
    // The file itself (2.3 MB) is read into memory; nothing else of note.
    assert!(u.peak < b.len() + 4 * REFUSED, "{u:?}");
}

#[test]
fn a_session_resynchronises_after_a_flipped_byte() {
    let recs: Vec<Vec<(u32, f64)>> = (0..5)
        .map(|r| {
            (0..3)
                .map(|i| (i % 2, r as f64 + i as f64 * 0.01))
                .collect()
        })
        .collect();
    let refs: Vec<&[(u32, f64)]> = recs.iter().map(Vec::as_slice).collect();
    let b = session(r#"["a","b"]"#, "120.0", &refs);
    let header_end = session(r#"["a","b"]"#, "120.0", &[]).len();
    let record_len = (b.len() - header_end) / 5;
    let third = header_end + 2 * record_len;
    let mut d = b.clone();
    d[third + 30] ^= 0x08;
    keep("flipped-byte.rlsession", &d);
    let s = read_session(&d).expect("the header is intact");
    // Records 1, 2, 4 and 5: everything after the damage is kept.
    assert_eq!(s.samples.len(), 12);
    let times: Vec<f64> = s.samples.iter().map(|x| x.time_s).collect();
    assert_eq!(times[6..9], [3.0, 3.01, 3.02]);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    let w = &s.warnings[0];
    assert!(w.contains(&format!("at byte {third}")), "{w}");
    assert!(w.contains(&format!("skipped {record_len} bytes")), "{w}");
    // And the recording made of it spans all five records.
    let (r, _) = load_session(&d);
    let rec = r.unwrap();
    // 4.02 s at 120 Hz: frames 0..=482.
    assert_eq!(rec.frames.len(), 483);
    assert_eq!(rec.warnings, s.warnings);
}
