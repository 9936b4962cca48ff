//! `rigless demo`: the embedded default. A synthetic session of a procedural character
//! played live through the marker buffer, the solver thread and the vertex stream.

use anyhow::{bail, Context, Result};
use rigless::character::body::BodyMotion;
use rigless::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params, Motion};
use rigless::daemon::clock::{Clock, SystemClock};
use rigless::daemon::pipeline::{run_loop, topology, LoopParams, LoopStatus, Pipeline};
use rigless::daemon::slot::LatestSlot;
use rigless::input::synthetic::{play, SourceCounters, SyntheticParams, SyntheticSession};
use rigless::markers::buffer::{BufferConfig, MarkerBuffer};
use rigless::output::stream::{StreamServer, StreamStats};
use rigless::rig::bind::Rig;
use rigless::solve::frame::{Solver, SolverParams};
use std::io::{IsTerminal, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Solver rate of the demo, Hz.
const RATE_HZ: f64 = 120.0;
/// Share of the frame period the solve may use before it stops at its deadline.
const DEADLINE_FRACTION: f64 = 0.8;
/// Capacity of the input channel, samples (a second of the body's 36 markers at 120 Hz).
const CHANNEL_CAPACITY: usize = 4096;

pub enum Which {
    Hand,
    Body(BodyMotion),
}

pub struct DemoArgs {
    pub character: Which,
    pub session_secs: f64,
    pub seconds: Option<f64>,
    pub looping: bool,
    pub stream: std::net::SocketAddr,
    pub noise_mm: f64,
    pub gap_percent: f64,
    pub json: bool,
}

pub fn run(a: DemoArgs) -> Result<()> {
    let mut problems = Vec::new();
    if !(a.session_secs.is_finite() && a.session_secs > 0.0) {
        problems.push(format!(
            "--session-secs must be a positive number of seconds, got {}",
            a.session_secs
        ));
    }
    if let Some(s) = a.seconds {
        if !(s.is_finite() && s > 0.0) {
            problems.push(format!(
                "--seconds must be a positive number of seconds, got {s}"
            ));
        }
    }
    if !(a.noise_mm.is_finite() && a.noise_mm >= 0.0) {
        problems.push(format!(
            "--noise-mm must be zero or more millimetres, got {}",
            a.noise_mm
        ));
    }
    if !(a.gap_percent.is_finite() && (0.0..=90.0).contains(&a.gap_percent)) {
        problems.push(format!(
            "--gap-percent must be between 0 and 90, got {}",
            a.gap_percent
        ));
    }
    if !problems.is_empty() {
        bail!("{}", problems.join("\n"));
    }
    let (ch, bind, motion) = match a.character {
        Which::Hand => (demo_hand(), hand_bind_params(), Motion::FingerPlay),
        Which::Body(m) => (demo_body(), body_bind_params(), Motion::Body(m)),
    };
    let t0 = Instant::now();
    let rig = Arc::new(
        Rig::bind(&ch, &bind).with_context(|| format!("binding the procedural {}", ch.name))?,
    );
    let name = ch.name.clone();
    if !a.json {
        println!(
            "procedural {name}: {} mesh vertices, {} markers, {} control vertices; bound in {:.2} s",
            ch.vertices.len(),
            ch.markers.len(),
            rig.stats.control_vertices,
            t0.elapsed().as_secs_f64()
        );
    }
    let session = SyntheticSession::new(
        Arc::new(ch),
        motion,
        SyntheticParams {
            rate_hz: RATE_HZ,
            duration_secs: a.session_secs,
            noise_m: a.noise_mm * 1e-3,
            gap_fraction: a.gap_percent / 100.0,
            ..SyntheticParams::default()
        },
    );

    let slot = Arc::new(LatestSlot::new());
    let server = StreamServer::start(a.stream, &topology(&rig, &name, RATE_HZ), Arc::clone(&slot))
        .with_context(|| format!("starting the vertex stream on {}", a.stream))?;
    let stream_stats = Arc::clone(server.stats());
    // Tests and scripts read this line to find the port.
    println!("vertex stream listening on tcp://{}", server.local_addr());
    let _ = std::io::stdout().flush();

    let (tx, rx) = crossbeam_channel::bounded(CHANNEL_CAPACITY);
    let buffer = MarkerBuffer::new(BufferConfig::default(), &rig.marker_rest, &rig.marker_joint);
    let solver = Solver::new(Arc::clone(&rig), SolverParams::default());
    let mut pipeline = Pipeline::new(solver, buffer, rx, vec![slot]);

    let clock = Arc::new(SystemClock::new());
    let stop = Arc::new(AtomicBool::new(false));
    let status = Arc::new(LatestSlot::<LoopStatus>::new());
    let start_s = 0.05;
    let end_s = match (a.seconds, a.looping) {
        (Some(s), _) => Some(start_s + s),
        (None, false) => Some(start_s + a.session_secs),
        (None, true) => None,
    };

    let counters = Arc::new(SourceCounters::default());
    let source = {
        let (clock, stop, counters) =
            (Arc::clone(&clock), Arc::clone(&stop), Arc::clone(&counters));
        let looping = a.looping;
        std::thread::Builder::new()
            .name("synthetic-source".into())
            .spawn(move || play(session, &*clock, start_s, looping, &tx, &stop, &counters))?
    };
    let solver_thread = {
        let (clock, stop, status) = (Arc::clone(&clock), Arc::clone(&stop), Arc::clone(&status));
        std::thread::Builder::new()
            .name("solver".into())
            .spawn(move || {
                clock.sleep_until(start_s);
                let deadline_clock = Arc::clone(&clock);
                run_loop(
                    &mut pipeline,
                    &*clock,
                    LoopParams {
                        rate_hz: RATE_HZ,
                        deadline_fraction: DEADLINE_FRACTION,
                        end_s,
                        status_interval_s: 1.0,
                    },
                    &stop,
                    &status,
                    &move |t| deadline_clock.instant_at(t),
                )
            })?
    };
    {
        let stop = Arc::clone(&stop);
        // Ctrl-C: stop the loop; everything after it shuts down in order.
        std::thread::Builder::new()
            .name("ctrl-c".into())
            .spawn(move || {
                let rt = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build();
                if let Ok(rt) = rt {
                    if rt.block_on(tokio::signal::ctrl_c()).is_ok() {
                        stop.store(true, Ordering::Relaxed);
                    }
                }
            })?;
    }

    let tty = std::io::stdout().is_terminal() && !a.json;
    while !solver_thread.is_finished() {
        std::thread::sleep(Duration::from_millis(50));
        if let Some(st) = status.take() {
            print_status(&st, &stream_stats, a.json, tty);
        }
    }
    let last = solver_thread
        .join()
        .map_err(|_| anyhow::anyhow!("the solver thread panicked"))?;
    stop.store(true, Ordering::Relaxed);
    let _ = source.join();
    let reason = if a.looping || a.seconds.is_some() {
        "demo stopped"
    } else {
        "session ended"
    };
    server.shutdown(reason);
    if tty {
        println!();
    }
    print_summary(&last, &stream_stats, &counters, a.json)?;
    Ok(())
}

fn print_status(st: &LoopStatus, stream: &StreamStats, json: bool, tty: bool) {
    let clients = stream.clients.load(Ordering::Relaxed);
    if json {
        let v = serde_json::json!({ "status": st, "clients": clients });
        println!("{v}");
        return;
    }
    let [m, p, r, h] = st.fill_now;
    let line = format!(
        "frame {:>6}  {:>5.1} Hz  frame ms p50 {:.2} p99 {:.2}  iters {:>4.1}  markers: {m} measured, {p} predicted, {r} rigid, {h} held  clients {clients}",
        st.frames, st.frame_rate_hz, st.frame_ms_p50, st.frame_ms_p99, st.iterations_mean
    );
    if tty {
        print!("\r{line}   ");
        let _ = std::io::stdout().flush();
    } else {
        println!("{line}");
    }
}

fn print_summary(
    st: &LoopStatus,
    stream: &StreamStats,
    source: &SourceCounters,
    json: bool,
) -> Result<()> {
    let b = &st.buffer;
    let total: u64 = b.filled.iter().sum::<u64>().max(1);
    let pct = |i: usize| 100.0 * b.filled[i] as f64 / total as f64;
    let stream_json = serde_json::json!({
        "connections": stream.connections.load(Ordering::Relaxed),
        "frames_sent": stream.frames_sent.load(Ordering::Relaxed),
        "frames_skipped": stream.frames_skipped.load(Ordering::Relaxed),
        "write_errors": stream.write_errors.load(Ordering::Relaxed),
    });
    if json {
        let v = serde_json::json!({
            "summary": st,
            "stream": stream_json,
            "source_samples": source.samples.load(Ordering::Relaxed),
            "source_dropped": source.dropped.load(Ordering::Relaxed),
        });
        println!("{v}");
        return Ok(());
    }
    println!(
        "done: {} frames, frame ms p50 {:.2} p99 {:.2}, {} deadline stops, {} overruns",
        st.frames, st.frame_ms_p50, st.frame_ms_p99, st.deadline_stops, st.overruns
    );
    println!(
        "markers: {:.1} % measured, {:.1} % predicted, {:.1} % rigid-filled, {:.1} % held; {} samples, {} occluded, {} gated ({} label swaps), {} re-acquired",
        pct(0), pct(1), pct(2), pct(3), b.accepted + b.occluded, b.occluded, b.gate_rejected, b.label_swaps, b.reacquired
    );
    println!("stream: {stream_json}");
    Ok(())
}
