//! The `live` suite: a whole stage in real time on the system clock (the procedural hand
//! fed by a looping synthetic source, the solver thread, the vertex stream, TCP clients on
//! loopback, optionally a Rerun sink saving every frame), measuring latency from a sample
//! entering the input channel to its frame's bytes arriving at a client, missed ticks,
//! and what many clients and Rerun cost the solver.

use super::BenchError;
use crate::config::parse_stage;
use crate::daemon::stage::{Stage, StartOptions};
use crate::protocol::vertex_stream::{decode, decode_header, Message, HEADER_LEN};
use crate::runtime::clock::{unix_now, Clock, SystemClock};
use crate::runtime::stats::percentile;
use std::io::Read;
use std::net::TcpStream;
use std::sync::Arc;
use std::time::Duration;

/// Longest wait for the clients to connect, seconds.
const CONNECT_TIMEOUT_S: f64 = 5.0;

/// One case of the suite.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LiveRecord {
    pub suite: &'static str,
    pub character: String,
    pub rate_hz: f64,
    pub seconds: f64,
    /// Clients connected (one of them measures; `silent_clients` of them never read).
    pub clients: usize,
    pub silent_clients: usize,
    pub frames: u64,
    /// Ticks skipped because the loop fell a period behind.
    pub overruns: u64,
    pub deadline_stops: u64,
    /// Frames the measuring client received, and skipped (it was slower than the loop).
    pub frames_received: usize,
    pub frames_skipped: u64,
    /// Solve (control mesh) and full-mesh update per frame, ms.
    pub solve_ms_p50: f64,
    pub solve_ms_p99: f64,
    pub gc_ms_p50: f64,
    /// Sample entering the channel to the tick that drains it, ms.
    pub wait_ms_p50: f64,
    pub wait_ms_p99: f64,
    /// Sample entering the channel to its frame's last byte read by the client, ms.
    pub latency_ms_p50: f64,
    pub latency_ms_p99: f64,
    /// `latency - solve - gc` per frame (what the pipeline adds to the solver), ms.
    pub overhead_ms_p50: f64,
    pub overhead_ms_p99: f64,
    /// Resident memory of the process after the clients connected and at the end, MiB.
    pub rss_start_mib: f64,
    pub rss_end_mib: f64,
    /// A Rerun sink saved the run to a file: frames it logged, and skipped (it fell
    /// behind the loop).
    pub rerun: bool,
    pub rerun_frames_logged: u64,
    pub rerun_frames_skipped: u64,
}

/// Resident set size of this process, MiB (Linux; 0 elsewhere).
pub fn rss_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}

/// What the measuring client saw of one frame.
struct Seen {
    recv_unix: f64,
    source_time_s: f64,
    solve_ms: f64,
    gc_ms: f64,
}

fn read_one(s: &mut TcpStream, buf: &mut Vec<u8>) -> Option<Message> {
    let mut h = [0u8; HEADER_LEN];
    s.read_exact(&mut h).ok()?;
    let (_, len) = decode_header(&h).ok()?;
    buf.clear();
    buf.extend_from_slice(&h);
    buf.resize(HEADER_LEN + len as usize, 0);
    s.read_exact(&mut buf[HEADER_LEN..]).ok()?;
    decode(buf).ok().map(|(m, _)| m)
}

/// One case of the suite: rate, length, clients, and whether a Rerun sink saves the run.
#[derive(Clone, Debug)]
pub struct LiveCase {
    pub rate_hz: f64,
    pub seconds: f64,
    /// Reading clients besides the measuring one.
    pub readers: usize,
    /// Clients that connect and never read.
    pub silent: usize,
    /// Save every frame to this `.rrd` file with a Rerun sink.
    pub rerun_file: Option<std::path::PathBuf>,
}

/// The stage of a case: the procedural hand, a looping synthetic source with noise and
/// no gaps at the case's rate, the stream on a free loopback port, and a Rerun sink
/// saving every frame when asked.
fn case_stage(case: &LiveCase) -> Result<crate::config::StageConfig, BenchError> {
    let rate = case.rate_hz;
    let mut text = format!(
        "[character]\nprocedural = \"hand\"\n\n[solver]\nrate_hz = {rate:?}\n\n[[inputs]]\ntype = \"synthetic\"\nrate_hz = {rate:?}\ngap_percent = 0.0\nsession_secs = {:?}\nloop = true\n\n[outputs.stream]\ntcp = \"127.0.0.1:0\"\n",
        case.seconds + 5.0
    );
    if let Some(p) = &case.rerun_file {
        let target = toml::Value::String(format!("save={}", p.display()));
        text += &format!("\n[outputs.rerun]\ntarget = {target}\nmesh_every = 1\n");
    }
    parse_stage(&text, "live benchmark case").map_err(|e| BenchError::case("live stage", e))
}

/// Runs one case: the stage for `seconds` with one measuring client, `readers` more
/// clients that read and discard, and `silent` clients that never read.
pub fn run_live(case: &LiveCase) -> Result<LiveRecord, BenchError> {
    let LiveCase {
        rate_hz,
        seconds,
        readers,
        silent,
        ref rerun_file,
    } = *case;
    let cfg = case_stage(case)?;
    let clock = Arc::new(SystemClock::new());
    let stage = Stage::start_with(
        &cfg,
        std::path::Path::new("."),
        Arc::clone(&clock) as Arc<dyn Clock>,
        StartOptions {
            stop_after_secs: Some(seconds),
            ..StartOptions::default()
        },
    )
    .map_err(|e| BenchError::case("live stage", e))?;
    let info = stage.info().clone();
    let addr = info
        .stream_tcp
        .ok_or_else(|| BenchError::case("live stage", std::io::Error::other("no TCP stream")))?;

    // Clients.
    let mut measuring = TcpStream::connect(addr)?;
    measuring.set_read_timeout(Some(Duration::from_secs(10)))?;
    let expected = (seconds * rate_hz) as usize + 16;
    let measurer = std::thread::spawn(move || {
        let mut seen = Vec::with_capacity(expected);
        let mut buf = Vec::new();
        while let Some(m) = read_one(&mut measuring, &mut buf) {
            match m {
                Message::Frame(f) => seen.push(Seen {
                    recv_unix: unix_now(),
                    source_time_s: f.source_time_s,
                    solve_ms: f.status.solve_ms as f64,
                    gc_ms: f.status.gc_ms as f64,
                }),
                Message::Goodbye(_) => break,
                Message::Topology(_) => {}
            }
        }
        seen
    });
    let mut others = Vec::new();
    for _ in 0..readers {
        let mut c = TcpStream::connect(addr)?;
        c.set_read_timeout(Some(Duration::from_secs(10)))?;
        others.push(std::thread::spawn(move || {
            let mut buf = vec![0u8; 1 << 18];
            while matches!(c.read(&mut buf), Ok(n) if n > 0) {}
        }));
    }
    let silent_conns: Vec<TcpStream> = (0..silent)
        .map(|_| TcpStream::connect(addr))
        .collect::<Result<_, _>>()?;
    let connected_by = clock.now_s() + CONNECT_TIMEOUT_S;
    while stage.stream_clients() < (1 + readers + silent) as u64 && clock.now_s() < connected_by {
        std::thread::sleep(Duration::from_millis(2));
    }
    let rss_start_mib = rss_mib();
    let summary = stage
        .join()
        .map_err(|e| BenchError::case("live stage", e))?;
    let rss_end_mib = rss_mib();
    drop(silent_conns);
    let seen = measurer.join().map_err(|_| {
        BenchError::case(
            "live stage",
            std::io::Error::other("the measuring client panicked"),
        )
    })?;
    for o in others {
        if o.join().is_err() {
            tracing::warn!("a reading client of the live benchmark panicked");
        }
    }
    // A frame's newest sample entered the channel when the source sent it: at
    // start_s + source_time on the stage's clock.
    let (mut wait, mut lat, mut over, mut solve, mut gc) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let period = 1.0 / rate_hz;
    for s in &seen {
        let entry_s = info.start_s + s.source_time_s;
        let entry_unix = clock.unix_s(entry_s);
        // The tick that drained it is the first tick at or after its entry.
        let k = ((entry_s - info.loop_start_s) / period).ceil().max(0.0);
        let tick_unix = clock.unix_s(info.loop_start_s + k * period);
        let l = (s.recv_unix - entry_unix) * 1e3;
        wait.push((tick_unix - entry_unix) * 1e3);
        lat.push(l);
        over.push(l - s.solve_ms - s.gc_ms);
        solve.push(s.solve_ms);
        gc.push(s.gc_ms);
    }
    let st = &summary.status;
    let rerun = summary.rerun;
    Ok(LiveRecord {
        suite: "live",
        character: info.character,
        rate_hz,
        seconds,
        clients: 1 + readers + silent,
        silent_clients: silent,
        frames: st.frames,
        overruns: st.overruns,
        deadline_stops: st.deadline_stops,
        frames_received: seen.len(),
        frames_skipped: summary.stream.frames_skipped,
        solve_ms_p50: percentile(&mut solve, 0.5),
        solve_ms_p99: percentile(&mut solve, 0.99),
        gc_ms_p50: percentile(&mut gc, 0.5),
        wait_ms_p50: percentile(&mut wait, 0.5),
        wait_ms_p99: percentile(&mut wait, 0.99),
        latency_ms_p50: percentile(&mut lat, 0.5),
        latency_ms_p99: percentile(&mut lat, 0.99),
        overhead_ms_p50: percentile(&mut over, 0.5),
        overhead_ms_p99: percentile(&mut over, 0.99),
        rss_start_mib,
        rss_end_mib,
        rerun: rerun_file.is_some(),
        rerun_frames_logged: rerun.map_or(0, |r| r.frames_logged),
        rerun_frames_skipped: rerun.map_or(0, |r| r.frames_skipped),
    })
}

/// The suite: 120 Hz with one client, the same with a Rerun sink saving every frame,
/// 240 Hz, and 120 Hz with 50 clients (one never reading); `seconds` each.
pub fn suite(seconds: f64, json: bool, out: &mut dyn std::io::Write) -> Result<(), BenchError> {
    if !json {
        writeln!(
            out,
            "{:<6} {:>6} {:>8} {:>7} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} rerun logged/skipped",
            "char", "rate", "clients", "frames", "overrun", "solve p50", "solve p99", "wait p99",
            "lat p50", "lat p99", "over p50", "over p99", "rss MiB"
        )?;
    }
    let dir = std::env::temp_dir().join(format!("rigless-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let rrd = dir.join("bench-live.rrd");
    // (rate, readers besides the measuring client, silent clients, a Rerun sink saving
    // every frame: the same case with and without it shows what logging costs)
    for (rate_hz, readers, silent, rerun) in [
        (120.0, 0, 0, false),
        (120.0, 0, 0, true),
        (240.0, 0, 0, false),
        (120.0, 48, 1, false),
    ] {
        let r = run_live(&LiveCase {
            rate_hz,
            seconds,
            readers,
            silent,
            rerun_file: rerun.then(|| rrd.clone()),
        })?;
        if json {
            super::json_line(out, &r)?;
            continue;
        }
        writeln!(
            out,
            "{:<6} {:>6.0} {:>8} {:>7} {:>8} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>5.0}->{:<5.0} {}",
            r.character, r.rate_hz, r.clients, r.frames, r.overruns, r.solve_ms_p50, r.solve_ms_p99,
            r.wait_ms_p99, r.latency_ms_p50, r.latency_ms_p99, r.overhead_ms_p50, r.overhead_ms_p99,
            r.rss_start_mib, r.rss_end_mib,
            if r.rerun { format!("{}/{}", r.rerun_frames_logged, r.rerun_frames_skipped) } else { "-".into() }
        )?;
    }
    if let Err(e) = std::fs::remove_dir_all(&dir) {
        tracing::warn!("leaving {}: {e}", dir.display());
    }
    Ok(())
}
