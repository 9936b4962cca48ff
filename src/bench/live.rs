//! The `live` suite: the whole live pipeline in real time on the system clock (synthetic
//! source thread, solver thread, vertex stream server, TCP clients on loopback), measuring
//! latency from a sample entering the input channel to its frame's bytes arriving at a
//! client, missed ticks, and what many clients cost the solver.

use crate::character::demo::Motion;
use crate::character::procedural::Character;
use crate::daemon::clock::{Clock, SystemClock};
use crate::daemon::pipeline::{run_loop, topology, LoopParams, LoopStatus, Pipeline};
use crate::daemon::slot::LatestSlot;
use crate::input::synthetic::{play, SyntheticParams, SyntheticSession};
use crate::input::{unix_now, SourceCounters};
use crate::markers::buffer::{BufferConfig, MarkerBuffer};
use crate::output::rerun_sink::{
    start as start_rerun, InputSeries, RerunOptions, RerunScene, RerunStats, RerunTarget,
};
use crate::output::stream::StreamServer;
use crate::protocol::vertex_stream::{decode, decode_header, Message, HEADER_LEN};
use crate::rig::bind::Rig;
use crate::solve::frame::{Solver, SolverParams};
use std::io::Read;
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// The loop ticks this long after the source sends each frame (both run at the same
/// rate on the same clock), seconds: a stage sets its phase the same way.
const LOOP_PHASE_S: f64 = 0.0002;
/// Seconds before the first tick (threads and clients start).
const START_S: f64 = 0.5;

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

fn pct(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
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

/// Runs the pipeline for `seconds` at `rate_hz` with one measuring client, `readers`
/// more clients that read and discard, and `silent` clients that never read.
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

pub fn run_live(
    rig: Arc<Rig>,
    ch: Arc<Character>,
    motion: Motion,
    case: &LiveCase,
) -> std::io::Result<LiveRecord> {
    let LiveCase {
        rate_hz,
        seconds,
        readers,
        silent,
        ref rerun_file,
    } = *case;
    let name = ch.name.clone();
    let session = SyntheticSession::new(
        ch,
        motion,
        SyntheticParams {
            rate_hz,
            duration_secs: seconds + 5.0,
            gap_fraction: 0.0,
            ..SyntheticParams::default()
        },
    );
    let (tx, rx) = crossbeam_channel::bounded(4096);
    let slot = Arc::new(LatestSlot::new());
    let buffer = MarkerBuffer::new(BufferConfig::default(), &rig.marker_rest, &rig.marker_joint);
    let solver = Solver::new(Arc::clone(&rig), SolverParams::default());
    let mut slots = vec![Arc::clone(&slot)];
    let rerun_slot = Arc::new(LatestSlot::new());
    let rerun_stop = Arc::new(AtomicBool::new(false));
    let rerun_stats = Arc::new(RerunStats::default());
    let counters = Arc::new(SourceCounters::default());
    let rerun_thread = match rerun_file {
        Some(path) => {
            slots.push(Arc::clone(&rerun_slot));
            start_rerun(
                &RerunOptions {
                    target: RerunTarget::Save(path.clone()),
                    mesh_every: 1,
                    control_mesh: false,
                    harmonic_field: false,
                },
                RerunScene::of_rig(&rig, &name),
                vec![InputSeries {
                    name: "0_synthetic".into(),
                    counters: Arc::clone(&counters),
                }],
                Arc::clone(&rerun_slot),
                Arc::clone(&rerun_stop),
                Arc::clone(&rerun_stats),
            )
            .map_err(std::io::Error::other)?
        }
        None => None,
    };
    let mut pipeline = Pipeline::new(solver, buffer, rx, slots);
    let server = StreamServer::start(
        Some("127.0.0.1:0".parse().expect("loopback address")),
        None,
        &topology(&rig, &name, rate_hz),
        slot,
    )?;
    let addr = server.local_addr().expect("TCP is on");
    let clock = Arc::new(SystemClock::new());
    let stop = Arc::new(AtomicBool::new(false));

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
    while server.stats().clients.load(Ordering::Relaxed) < (1 + readers + silent) as u64
        && clock.now_s() < START_S
    {
        std::thread::sleep(Duration::from_millis(2));
    }
    let rss_start_mib = rss_mib();

    let source = {
        let (clock, stop, counters) =
            (Arc::clone(&clock), Arc::clone(&stop), Arc::clone(&counters));
        std::thread::spawn(move || play(session, &*clock, START_S, true, &tx, &stop, &counters))
    };
    let status = LatestSlot::<LoopStatus>::new();
    let loop_start = START_S + LOOP_PHASE_S;
    clock.sleep_until(loop_start);
    let deadline_clock = Arc::clone(&clock);
    let last = run_loop(
        &mut pipeline,
        &*clock,
        LoopParams {
            rate_hz,
            deadline_fraction: 0.8,
            end_s: Some(loop_start + seconds),
            status_interval_s: 1.0,
        },
        &stop,
        &status,
        &move |t| deadline_clock.instant_at(t),
    );
    stop.store(true, Ordering::Relaxed);
    let _ = source.join();
    rerun_stop.store(true, Ordering::Relaxed);
    if let Some(h) = rerun_thread {
        let _ = h.join();
    }
    let rss_end_mib = rss_mib();
    let frames_skipped = server.stats().frames_skipped.load(Ordering::Relaxed);
    server.shutdown("benchmark over");
    drop(silent_conns);
    let seen = measurer.join().unwrap_or_default();
    for o in others {
        let _ = o.join();
    }
    // A frame's newest sample entered the channel when the source sent it: at
    // START_S + source_time (the source's clock is the daemon's).
    let (mut wait, mut lat, mut over, mut solve, mut gc) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let period = 1.0 / rate_hz;
    for s in &seen {
        let entry_unix = clock.unix_s(START_S + s.source_time_s);
        // The tick that drained it is the first tick at or after its entry.
        let k = ((START_S + s.source_time_s - loop_start) / period)
            .ceil()
            .max(0.0);
        let tick_unix = clock.unix_s(loop_start + k * period);
        let l = (s.recv_unix - entry_unix) * 1e3;
        wait.push((tick_unix - entry_unix) * 1e3);
        lat.push(l);
        over.push(l - s.solve_ms - s.gc_ms);
        solve.push(s.solve_ms);
        gc.push(s.gc_ms);
    }
    Ok(LiveRecord {
        suite: "live",
        character: name,
        rate_hz,
        seconds,
        clients: 1 + readers + silent,
        silent_clients: silent,
        frames: last.frames,
        overruns: last.overruns,
        deadline_stops: last.deadline_stops,
        frames_received: seen.len(),
        frames_skipped,
        solve_ms_p50: pct(&mut solve, 0.5),
        solve_ms_p99: pct(&mut solve, 0.99),
        gc_ms_p50: pct(&mut gc, 0.5),
        wait_ms_p50: pct(&mut wait, 0.5),
        wait_ms_p99: pct(&mut wait, 0.99),
        latency_ms_p50: pct(&mut lat, 0.5),
        latency_ms_p99: pct(&mut lat, 0.99),
        overhead_ms_p50: pct(&mut over, 0.5),
        overhead_ms_p99: pct(&mut over, 0.99),
        rss_start_mib,
        rss_end_mib,
        rerun: rerun_file.is_some(),
        rerun_frames_logged: rerun_stats.frames_logged.load(Ordering::Relaxed),
        rerun_frames_skipped: rerun_slot.dropped(),
    })
}
