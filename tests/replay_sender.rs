//! `rigless replay FILE --to URL` in-process: a synthetic recording sent over loopback UDP
//! at ten times its speed on the system clock (on a manual clock the sender would outrun
//! the receiver and UDP would drop the excess) and read back with the OSC input's
//! decoder. Covers the VMC round trip on the wire (markers off every axis), and the
//! sender's window, loop, marker subset, dropout and noise options.

use glam::DVec3;
use rigless::protocol::osc::{OscFrame, OscMapping};
use rigless::replay::recording::Recording;
use rigless::replay::sender::{replay, ReplayOptions, ReplayStats, Target};
use rigless::runtime::clock::{Clock, SystemClock};
use std::net::UdpSocket;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// Rate of the synthetic recording, Hz.
const RATE_HZ: f64 = 100.0;

/// Playback speed: 800 frames in 0.8 s.
const SPEED: f64 = 10.0;

/// Marker `k` of frame `i`: distinct on every axis, z never zero (a lost Z negation
/// shows), values exact in f32 only up to rounding (compared within [`F32_M`]).
fn position(k: usize, i: usize) -> DVec3 {
    DVec3::new(
        0.1 * k as f64 + 0.01 * i as f64,
        1.0 + 0.02 * i as f64,
        -0.3 + 0.05 * k as f64 + 0.001 * i as f64,
    )
}

/// f32 rounding of a coordinate of a few metres, with margin.
const F32_M: f64 = 1e-6;

/// Three markers over `frames` frames.
fn recording(frames: usize) -> Recording {
    Recording {
        name: "synthetic".into(),
        rate_hz: RATE_HZ,
        labels: vec!["a".into(), "b".into(), "c".into()],
        frames: (0..frames)
            .map(|i| (0..3).map(|k| position(k, i)).collect())
            .collect(),
        warnings: Vec::new(),
        file_units: "m".into(),
        point_groups: Vec::new(),
    }
}

/// Sends `rec` with `opts` as `target` builds it for the loopback receiver, and returns
/// the sender's stats and every packet decoded. `stop_after` packets raise the stop flag
/// (for a looping replay).
fn send(
    rec: &Recording,
    vmc: bool,
    opts: &ReplayOptions,
    stop_after: Option<usize>,
) -> (ReplayStats, Vec<OscFrame>) {
    let rx = UdpSocket::bind("127.0.0.1:0").unwrap();
    rx.set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let addr = rx.local_addr().unwrap();
    let target = if vmc {
        Target::Vmc(addr)
    } else {
        Target::Osc(addr)
    };
    let stop = AtomicBool::new(false);
    let clock = SystemClock::new();
    let opts = &ReplayOptions {
        speed: SPEED,
        ..opts.clone()
    };
    let (stats, frames) = std::thread::scope(|scope| {
        let receiver = scope.spawn(|| {
            let mut frames = Vec::new();
            let mut buf = [0u8; 65_536];
            // Bounded: the replay sends at most a few thousand packets, and a read times
            // out half a second after the last.
            while let Ok(n) = rx.recv(&mut buf) {
                frames.push(OscMapping::default().decode(&buf[..n]).unwrap());
                if stop_after.is_some_and(|s| frames.len() >= s) {
                    stop.store(true, Ordering::Relaxed);
                }
                if frames.len() > 100_000 {
                    break;
                }
            }
            frames
        });
        let stats = replay(rec, target, opts, &clock, clock.now_s(), &stop).unwrap();
        (stats, receiver.join().unwrap())
    });
    assert_eq!(stats.send_errors, 0);
    assert_eq!(
        stats.packets as usize,
        frames.len(),
        "loopback lost packets"
    );
    (stats, frames)
}

/// The positions a packet carried, by label.
fn positions(f: &OscFrame) -> Vec<(String, DVec3)> {
    f.markers()
        .iter()
        .map(|m| (m.name.clone(), m.position_m))
        .collect()
}

fn assert_frame(f: &OscFrame, i: usize, labels: &[usize]) {
    let got = positions(f);
    assert_eq!(got.len(), labels.len(), "{got:?}");
    for ((name, p), &k) in got.iter().zip(labels) {
        assert_eq!(name, ["a", "b", "c"][k]);
        let d = (*p - position(k, i)).abs().max_element();
        assert!(d < F32_M, "frame {i} marker {name}: {p} off by {d} m");
    }
}

/// `replay --to vmc://`: every frame arrives, each marker under its name where the file
/// has it (z included: the sender negates it for Unity's frame, the input negates it
/// back), with the frame's time in the file as `/VMC/Ext/T`.
#[test]
fn vmc_replay_round_trips_through_the_osc_input() {
    let rec = recording(10);
    let (_, frames) = send(&rec, true, &ReplayOptions::default(), None);
    assert_eq!(frames.len(), 10);
    for (i, f) in frames.iter().enumerate() {
        assert_frame(f, i, &[0, 1, 2]);
        let t = f.vmc_time_s.expect("a VMC time");
        assert!((t - i as f64 / RATE_HZ).abs() < 1e-6, "frame {i} at {t} s");
    }
}

/// `--start 0.03 --end 0.06`: frames 3 to 6 of the file, numbered from 0 as sent.
#[test]
fn a_window_sends_its_frames_only() {
    let rec = recording(10);
    let opts = ReplayOptions {
        start_s: 0.03,
        end_s: Some(0.06),
        ..ReplayOptions::default()
    };
    let (_, frames) = send(&rec, false, &opts, None);
    assert_eq!(frames.len(), 4);
    for (n, f) in frames.iter().enumerate() {
        assert_eq!(f.frame, Some(n as i64));
        assert_frame(f, 3 + n, &[0, 1, 2]);
    }
}

/// `--loop`: after the last frame the file starts again (frame numbers go on), until
/// stopped.
#[test]
fn a_loop_plays_the_file_again_until_stopped() {
    let rec = recording(10);
    let opts = ReplayOptions {
        looping: true,
        ..ReplayOptions::default()
    };
    let (_, frames) = send(&rec, false, &opts, Some(25));
    // The stop is seen at the next frame: a few more may be on their way (1 ms apart).
    assert!((25..=30).contains(&frames.len()), "{}", frames.len());
    for (n, f) in frames.iter().enumerate() {
        assert_eq!(f.frame, Some(n as i64));
        assert_frame(f, n % 10, &[0, 1, 2]);
    }
}

/// `--markers c,a`: only those labels, in the file's order.
#[test]
fn a_marker_subset_sends_those_labels_only() {
    let rec = recording(10);
    let opts = ReplayOptions {
        markers: Some(vec!["c".into(), "a".into()]),
        ..ReplayOptions::default()
    };
    let (_, frames) = send(&rec, false, &opts, None);
    assert_eq!(frames.len(), 10);
    for (i, f) in frames.iter().enumerate() {
        assert_frame(f, i, &[0, 2]);
    }
}

/// `--dropout 0.3`: about 30 % of the samples go out occluded (2,400 samples: the share
/// within 0.05, four standard deviations), each counted; the rest are exact.
#[test]
fn dropout_occludes_its_share_of_samples() {
    let rec = recording(800);
    let opts = ReplayOptions {
        dropout: 0.3,
        ..ReplayOptions::default()
    };
    let (stats, frames) = send(&rec, false, &opts, None);
    assert_eq!(frames.len(), 800);
    let mut occluded = 0;
    for (i, f) in frames.iter().enumerate() {
        for (k, m) in f.markers().iter().enumerate() {
            if m.occluded {
                occluded += 1;
                assert!(!m.position_m.is_finite());
            } else {
                assert!((m.position_m - position(k, i)).abs().max_element() < F32_M);
            }
        }
    }
    assert_eq!(occluded as u64, stats.samples_dropped);
    let share = occluded as f64 / 2400.0;
    assert!((share - 0.3).abs() < 0.05, "{share}");
}

/// `--noise 0.002`: every coordinate within 2 mm of the file's, and spread as a uniform
/// noise of that amplitude (standard deviation 2/√3 mm, within 10 % over 2,400 samples
/// × 3 axes); without the option, none.
#[test]
fn noise_stays_within_its_amplitude() {
    let rec = recording(800);
    let amplitude_m = 0.002;
    let opts = ReplayOptions {
        noise_m: amplitude_m,
        ..ReplayOptions::default()
    };
    let (_, frames) = send(&rec, false, &opts, None);
    let (mut sum2, mut n) = (0.0, 0);
    for (i, f) in frames.iter().enumerate() {
        for (k, m) in f.markers().iter().enumerate() {
            let d = m.position_m - position(k, i);
            assert!(d.abs().max_element() <= amplitude_m + F32_M, "{d}");
            sum2 += d.length_squared();
            n += 3;
        }
    }
    let sd = (sum2 / n as f64).sqrt();
    let want = amplitude_m / 3f64.sqrt();
    assert!(
        (sd / want - 1.0).abs() < 0.1,
        "noise sd {sd} m, want {want} m"
    );
}
