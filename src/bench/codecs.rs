//! The `codecs` suite: cost of decoding one packet of each input format for a 50-marker
//! frame (target below 5 µs), median and spread over batches.

use super::Spread;
use crate::protocol::natnet::{self, Version};
use crate::protocol::osc::{encode_native, OscMapping};
use glam::DVec3;
use std::time::{Duration, Instant};

/// One codec's figures.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CodecRecord {
    pub suite: &'static str,
    pub codec: &'static str,
    pub markers: usize,
    pub packet_bytes: usize,
    /// Per-packet decode time over batches of `BATCH` packets, µs.
    pub decode_us_median: f64,
    pub decode_us_p10: f64,
    pub decode_us_p90: f64,
}

const BATCH: u32 = 1000;
const BATCHES: usize = 200;

fn time(mut f: impl FnMut()) -> Spread {
    for _ in 0..BATCH {
        f();
    }
    let batches: Vec<Duration> = (0..BATCHES)
        .map(|_| {
            let t = Instant::now();
            for _ in 0..BATCH {
                f();
            }
            t.elapsed() / BATCH
        })
        .collect();
    Spread::of(&batches)
}

/// Runs the suite.
pub fn run() -> Vec<CodecRecord> {
    let n = 50;
    let names: Vec<String> = (0..n).map(|k| format!("M{k:02}")).collect();
    let markers: Vec<(&str, DVec3)> = names
        .iter()
        .enumerate()
        .map(|(k, s)| (s.as_str(), DVec3::splat(k as f64 * 0.01)))
        .collect();
    let osc = encode_native(1, (0, 1), &markers);
    let mapping = OscMapping::default();
    let nat = natnet::example_frame(n);
    let mut out = Vec::new();
    let mut rec = |codec, markers: usize, bytes: usize, s: Spread| {
        out.push(CodecRecord {
            suite: "codecs",
            codec,
            markers,
            packet_bytes: bytes,
            decode_us_median: s.median_ms * 1e3,
            decode_us_p10: s.p10_ms * 1e3,
            decode_us_p90: s.p90_ms * 1e3,
        })
    };
    let mut frame = crate::protocol::osc::OscFrame::default();
    let s = time(|| {
        mapping
            .decode_into(std::hint::black_box(&osc), &mut frame)
            .expect("valid");
        assert_eq!(frame.markers().len(), n);
    });
    rec("osc_native", n, osc.len(), s);
    let s = time(|| {
        let m = natnet::decode(std::hint::black_box(&nat), Version(3, 0)).expect("valid");
        std::hint::black_box(m);
    });
    rec("natnet_3_0", n, nat.len(), s);
    // A glove line with every key (curls, 20 joint curls, splay, joystick, trigger,
    // buttons): its 20 posed joints count as markers.
    use crate::protocol::glove::{decode_line, encode_alpha, GloveFormat, GloveReading};
    let full = GloveReading {
        curl: [Some(4095); 5],
        joint_curl: [[Some(1234); 4]; 5],
        splay: [Some(2047); 5],
        joystick: [Some(2047); 2],
        trigger: Some(100),
        buttons: 0xff,
        unknown_keys: 0,
    };
    let mut line = String::new();
    encode_alpha(&full, &mut line);
    let mut reading = GloveReading::default();
    let s = time(|| {
        decode_line(
            std::hint::black_box(line.as_bytes()),
            GloveFormat::Alpha,
            4095,
            &mut reading,
        )
        .expect("valid");
        assert_eq!(reading, full);
    });
    rec("glove_alpha", 20, line.len(), s);
    out
}

/// The suite: one line per codec.
pub fn suite(json: bool, out: &mut dyn std::io::Write) -> Result<(), super::BenchError> {
    for r in run() {
        if json {
            super::json_line(out, &r)?;
        } else {
            writeln!(
                out,
                "{:<12} {:>3} markers {:>5} bytes  decode µs median {:.2} (p10 {:.2}, p90 {:.2})",
                r.codec,
                r.markers,
                r.packet_bytes,
                r.decode_us_median,
                r.decode_us_p10,
                r.decode_us_p90
            )?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_benchmark_natnet_frame_decodes_to_what_was_written() {
        let b = natnet::example_frame(50);
        let natnet::Message::Frame(f) = natnet::decode(&b, Version(3, 0)).unwrap() else {
            panic!("a frame")
        };
        assert_eq!(f.frame, 1234);
        assert_eq!(f.labeled.len(), 50);
        assert_eq!(f.marker_sets[0].1.len(), 50);
        assert_eq!(f.labeled[49].member_id, 50);
        assert_eq!(f.timestamp_s, 12.5);
    }
}
