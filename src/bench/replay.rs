//! The `replay` suite: the send-time jitter of `rigless replay` (the bundled hand session
//! at 120 Hz, looping, to a loopback socket that reads nothing) against the file's clock.

use super::BenchError;
use crate::replay::bundled::bundled;
use crate::replay::recording::Recording;
use crate::replay::sender::{replay, ReplayOptions, Target};
use crate::runtime::clock::SystemClock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// The suite: one case of `seconds`.
pub fn suite(seconds: f64, json: bool, out: &mut dyn std::io::Write) -> Result<(), BenchError> {
    let name = "hand_finger_play";
    let bytes = bundled(name)
        .ok_or_else(|| BenchError::case(name, std::io::Error::other("not a bundled session")))?;
    let rec = Recording::from_c3d(name, bytes).map_err(|e| BenchError::case(name, e))?;
    // A receiving socket that reads nothing: the kernel drops what overflows.
    let sink = std::net::UdpSocket::bind("127.0.0.1:0")?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        std::thread::Builder::new()
            .name("bench-timer".into())
            .spawn(move || {
                std::thread::sleep(std::time::Duration::from_secs_f64(seconds));
                stop.store(true, Ordering::Relaxed);
            })?;
    }
    let opts = ReplayOptions {
        looping: true,
        ..ReplayOptions::default()
    };
    let st = replay(
        &rec,
        Target::Osc(sink.local_addr()?),
        &opts,
        &SystemClock::new(),
        0.01,
        &stop,
    )
    .map_err(|e| BenchError::case(name, e))?;
    if json {
        super::json_line(
            out,
            &serde_json::json!({"suite": "replay", "rate_hz": rec.rate_hz, "seconds": seconds, "stats": st}),
        )?;
    } else {
        writeln!(
            out,
            "replay at {} Hz for {seconds} s: {} packets; send-time jitter ms p50 {:.3} p99 {:.3} max {:.3}",
            rec.rate_hz, st.packets, st.jitter_ms_p50, st.jitter_ms_p99, st.jitter_ms_max
        )?;
    }
    Ok(())
}
