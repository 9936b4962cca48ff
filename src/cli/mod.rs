//! The command line's commands, one file each: their arguments, what they print, their
//! progress bars and their exit codes. This is the only part of rigless that prints to
//! the user or exits; everything it runs is the library's.

pub mod bake;
pub mod bench;
pub mod calibrate;
pub mod demo;
pub mod export_character;
pub mod info;
pub mod listen;
pub mod make_sessions;
pub mod replay;
pub mod run;

use anyhow::{bail, Context, Result};
use rigless::config::StageConfig;
use rigless::daemon::pipeline::LoopStatus;
use rigless::daemon::stage::{Stage, StartOptions, Summary};
use rigless::output::rerun_sink::RerunTarget;
use rigless::rig::bind::BindStage;
use rigless::runtime::clock::SystemClock;
use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// A flag set when the user presses Ctrl-C (a thread waits for the signal).
pub fn ctrl_c_flag() -> Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    let set = Arc::clone(&flag);
    std::thread::Builder::new()
        .name("ctrl-c".into())
        .spawn(move || {
            let rt = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build();
            match rt {
                Ok(rt) => {
                    if rt.block_on(tokio::signal::ctrl_c()).is_ok() {
                        set.store(true, Ordering::Relaxed);
                    }
                }
                Err(e) => tracing::warn!("Ctrl-C will not stop this command: {e}"),
            }
        })
        .context("starting the Ctrl-C thread")?;
    Ok(flag)
}

/// Refuses a `--seconds` that is not a positive number.
pub fn check_seconds(seconds: Option<f64>) -> Result<()> {
    match seconds {
        Some(s) if !(s.is_finite() && s > 0.0) => {
            bail!("--seconds must be a positive number of seconds, got {s}")
        }
        _ => Ok(()),
    }
}

/// Flushes a progress or status line; one that cannot be flushed shows with the next
/// line, so a failure is only logged.
fn flush(out: &mut dyn Write) {
    if let Err(e) = out.flush() {
        tracing::debug!("flushing a progress line: {e}");
    }
}

/// Twenty cells of a progress bar at `pct` per cent (`#` done, `.` to do).
pub fn bar(pct: i64) -> String {
    (0..20)
        .map(|k| if k < pct / 5 { '#' } else { '.' })
        .collect()
}

/// A progress bar on stderr for binding a character (every 5 %), ended by
/// [`end_bind_progress`].
pub fn bind_progress() -> impl FnMut(BindStage, f64) {
    let mut last = (None, -1i64);
    move |stage, f| {
        let pct = (f * 100.0) as i64;
        if (Some(stage), pct / 5) == (last.0, last.1 / 5) {
            return;
        }
        last = (Some(stage), pct);
        let name = match stage {
            BindStage::Lattice => "lattice and binding",
            BindStage::GreenCoordinates => "Green coordinates",
            BindStage::Factorization => "weights and factorization",
        };
        eprint!("\r  binding [{}] {name:<26} {pct:>3}%", bar(pct));
        flush(&mut std::io::stderr());
    }
}

/// Ends a progress bar drawn by [`bind_progress`], if one was drawn.
pub fn end_bind_progress(drawn: bool) {
    if drawn {
        eprintln!("\r  binding [####################] done{:<30}", "");
    }
}

/// The rig of a character named on the command line (`hand`, `body` or a character
/// file, bound or read from its bake cache) and its file's `marker_scale` (1 for a
/// procedural one).
pub fn bound_character(spec: &str) -> Result<(Arc<rigless::rig::bind::Rig>, f64)> {
    use rigless::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params};
    use rigless::rig::bind::Rig;
    let procedural = match spec {
        "hand" => Some((demo_hand(), hand_bind_params())),
        "body" => Some((demo_body(), body_bind_params())),
        _ => None,
    };
    if let Some((ch, params)) = procedural {
        let rig =
            Rig::bind(&ch, &params).with_context(|| format!("binding the procedural {spec}"))?;
        return Ok((Arc::new(rig), 1.0));
    }
    let path = Path::new(spec);
    let loaded = rigless::character::file::load_character(path)?;
    let mut progress = bind_progress();
    let mut drawn = false;
    let (rig, _) = rigless::rig::cache::load_or_bind(path, &loaded, false, &mut |s, f| {
        drawn = true;
        progress(s, f)
    })?;
    end_bind_progress(drawn);
    Ok((Arc::new(rig), loaded.marker_scale))
}

/// How `run`, `demo` and `replay --solve` run their stage.
pub struct LiveOptions {
    /// Stop after this many seconds.
    pub seconds: Option<f64>,
    /// Status and summary as JSON lines.
    pub json: bool,
    /// Overrides `[outputs.rerun] target`.
    pub rerun: Option<RerunTarget>,
    /// `--viewer`: where the browser viewer is served, or off.
    pub viewer: Option<ViewerFlag>,
}

/// `--viewer ADDR|off`: the browser viewer's address (the vertex stream's WebSocket
/// port, which serves the page too), or no viewer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewerFlag {
    Off,
    At(SocketAddr),
}

impl std::str::FromStr for ViewerFlag {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "off" => Ok(ViewerFlag::Off),
            a => a.parse().map(ViewerFlag::At).map_err(|e| {
                format!("{a:?} is neither `off` nor an address such as 127.0.0.1:7879 ({e})")
            }),
        }
    }
}

/// Where the viewer is served when no flag and no `[outputs.stream] websocket` says.
pub const DEFAULT_VIEWER_ADDR: SocketAddr =
    SocketAddr::new(std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST), 7879);

/// Applies `--viewer` to the stage's stream: an address opens the WebSocket there with
/// the page; `off` serves no page (a configured WebSocket stays); no flag serves the page
/// on the configured WebSocket, else on [`DEFAULT_VIEWER_ADDR`] (a free port when
/// another program holds that one, so that two daemons on one machine both start).
fn apply_viewer(
    stream: &mut rigless::output::config::StreamOutputConfig,
    flag: Option<ViewerFlag>,
) {
    match flag {
        Some(ViewerFlag::Off) => stream.viewer = false,
        Some(ViewerFlag::At(a)) => {
            stream.websocket = Some(a);
            stream.viewer = true;
        }
        None if stream.viewer && stream.websocket.is_none() => {
            stream.websocket = Some(DEFAULT_VIEWER_ADDR);
            stream.websocket_any_port_if_taken = true;
        }
        None => {}
    }
}

/// Runs a stage on the system clock until it ends, `--seconds` pass or Ctrl-C: prints
/// what was started, a status line every second and the summary.
pub fn run_stage(mut cfg: StageConfig, base_dir: &Path, opts: &LiveOptions) -> Result<()> {
    apply_viewer(&mut cfg.outputs.stream, opts.viewer);
    // `--rerun save=PATH` is relative to where the command runs, not to the stage.
    let rerun = opts.rerun.clone().map(|t| match t {
        RerunTarget::Save(p) => RerunTarget::Save(std::path::absolute(&p).unwrap_or(p)),
        t => t,
    });
    let mut drawn = false;
    let mut bar = bind_progress();
    let mut progress = |stage, f| {
        if !opts.json {
            drawn = true;
            bar(stage, f);
        }
    };
    if let (Some(s), false) = (cfg.calibration.first_secs, opts.json) {
        eprintln!(
            "listening {s} s to calibrate the markers: stand in the character's rest pose, then move every joint ..."
        );
    }
    let stage = Stage::start_with(
        &cfg,
        base_dir,
        Arc::new(SystemClock::new()),
        StartOptions {
            stop_after_secs: opts.seconds,
            progress: Some(&mut progress),
            frames: None,
            rerun,
            actor_frames: Vec::new(),
            frame_logs: Vec::new(),
        },
    );
    end_bind_progress(drawn);
    let stage = stage?;
    // Until here Ctrl-C ends the process (binding can be long); from here it stops the
    // stage in order.
    let interrupted = ctrl_c_flag()?;
    print_started(&stage, cfg.outputs.stream.viewer, opts.json);
    let tty = std::io::stdout().is_terminal() && !opts.json;
    while !stage.is_finished() {
        std::thread::sleep(Duration::from_millis(50));
        if interrupted.load(Ordering::Relaxed) {
            stage.stop();
        }
        let actors = &stage.info().actors;
        let statuses = stage.actor_statuses();
        for (a, st) in actors.iter().zip(statuses) {
            if let Some(st) = st {
                let name = (actors.len() > 1).then_some(a.name.as_str());
                print_status(&st, name, stage.stream_clients(), opts.json, tty);
            }
        }
    }
    let summary = stage.join()?;
    if tty {
        println!();
    }
    print_summary(&summary, opts.json)?;
    if summary.recording_failed.is_some() {
        // Said when it happened and in the summary; the status tells scripts.
        bail!("the recording stopped part way (see the summary)");
    }
    Ok(())
}

/// What was started. Tests and scripts read the `... listening on` lines for the ports
/// (printed with `--json` too); the Rerun note goes to stderr either way.
fn print_started(stage: &Stage, viewer: bool, json: bool) {
    let i = stage.info();
    if let Some(note) = &i.rerun_note {
        eprintln!("{note}");
    }
    if let Some(a) = i.stream_tcp {
        println!("vertex stream listening on tcp://{a}");
    }
    if let Some(a) = i.stream_ws {
        println!("vertex stream listening on ws://{a}");
        if viewer {
            println!("viewer: open http://{a}/ in a browser");
        }
    }
    // With --json, only the network inputs' lines (a recording's is for people).
    let network = |kind: &str| !matches!(kind, "replay" | "synthetic");
    for input in i.inputs.iter().filter(|input| !json || network(input.kind)) {
        println!("{}", input.opened);
    }
    if let (true, Some(c)) = (json, &i.calibration) {
        let cal = c.calibration.as_ref();
        println!(
            "{}",
            serde_json::json!({ "calibration": {
                "seconds": c.seconds,
                "frames": c.frames,
                "labels": c.labels,
                "calibrated": cal.is_some(),
                "placed": cal.map(|c| c.placed.len()),
                "left_out": cal.map(|c| c.left_out.iter().map(|(l, why)| serde_json::json!({"label": l, "why": why.to_string()})).collect::<Vec<_>>()),
                "scale": cal.map(|c| c.scale),
                "residual_mm_rms": cal.map(|c| c.residual_mm_rms),
                "residual_mm_max": cal.map(|c| c.residual_mm_max),
                "written": c.written.as_ref().map(|p| p.display().to_string()),
            }})
        );
    }
    if !json {
        println!(
            "{}: {} mesh vertices, {} markers, {} control vertices; ready in {:.2} s",
            i.character, i.mesh_vertices, i.markers, i.control_vertices, i.bind_s
        );
        if let Some(source) = &i.rig_source {
            println!("{source}");
        }
        if i.actors.len() > 1 {
            for a in &i.actors {
                println!(
                    "actor {}: the {}, {} markers, {}",
                    a.name,
                    a.character,
                    a.markers,
                    a.claim.as_deref().unwrap_or("its labels")
                );
                if let Some(c) = &a.calibration {
                    println!("  {c}");
                }
            }
            println!(
                "{} actors on {} solver thread{}; the vertex stream, the viewer and Rerun carry them all",
                i.actors.len(),
                i.solver_threads,
                if i.solver_threads == 1 { "" } else { "s" },
            );
        }
        if let (Some(c), 1) = (&i.calibration, i.actors.len()) {
            println!("{}", c.describe());
        }
        for input in &i.inputs {
            for w in &input.warnings {
                println!("  warning: {w}");
            }
        }
        if let Some((path, flush_s)) = &i.recording {
            println!(
                "recording every sample to {} (flushed every {flush_s} s)",
                path.display()
            );
        }
        if i.rerun != RerunTarget::Off {
            println!("rerun: {}", i.rerun);
        }
    }
    // The lines above are what scripts wait for; a pipe must not hold them back.
    flush(&mut std::io::stdout());
}

/// One actor's status line; `actor` names it on a stage of several (whose lines are
/// never redrawn in place: one per actor).
fn print_status(st: &LoopStatus, actor: Option<&str>, clients: u64, json: bool, tty: bool) {
    if json {
        println!(
            "{}",
            serde_json::json!({ "status": st, "actor": actor, "clients": clients })
        );
        return;
    }
    let [m, p, r, h] = st.fill_now;
    let who = actor.map(|a| format!("{a}: ")).unwrap_or_default();
    let mut line = format!(
        "{who}frame {:>6}  {:>5.1} Hz  solve ms p50 {:.2} p99 {:.2} (frame {:.2} / {:.2})  iters {:>4.1}  markers: {m} measured, {p} predicted, {r} rigid, {h} held  clients {clients}",
        st.frames, st.frame_rate_hz, st.solve_ms_p50, st.solve_ms_p99, st.frame_ms_p50, st.frame_ms_p99, st.iterations_mean
    );
    // Only when a sender has sent something impossible (the JSON status always has it).
    let implausible = st.buffer.implausible + st.buffer.implausible_fills;
    if implausible > 0 {
        line.push_str(&format!("  implausible {implausible}"));
    }
    if st.buffer.identity_gated > 0 {
        line.push_str(&format!("  another's {}", st.buffer.identity_gated));
    }
    if st.fill_now[3] == st.fill_now.iter().sum::<usize>() {
        line.push_str("  (no marker in view: holding the last pose)");
    }
    if tty && actor.is_none() {
        print!("\r{line}   ");
        flush(&mut std::io::stdout());
    } else {
        println!("{line}");
    }
}

fn print_summary(s: &Summary, json: bool) -> Result<()> {
    if json {
        let v = serde_json::json!({
            "summary": s.status,
            "stream": s.stream,
            "source_samples": s.source_samples,
            "source_dropped": s.source_dropped,
            "source_clock_jumps": s.source_clock_jumps,
            "source_clock_untrusted": s.source_clock_untrusted,
            "stopped": s.stopped.reason(),
            "inputs": s.inputs,
            "labels_fed": s.labels_fed,
            "labels_ignored": s.labels_ignored,
            "marker_residual_mm_rms": s.status.marker_residual_mm_rms,
            "marker_residual_mm_max": s.status.marker_residual_mm_max,
            "recorded": s.recorded.as_ref().map(|(p, n)| serde_json::json!({"path": p, "samples": n})),
            "recording_failed": s.recording_failed,
            "rerun": s.rerun,
            "actors": s.actors,
        });
        println!("{v}");
        return Ok(());
    }
    if let Some((path, n)) = &s.recorded {
        match &s.recording_failed {
            Some(why) => println!("recording to {} stopped part way: {why}", path.display()),
            None => println!("recorded {n} samples to {}", path.display()),
        }
    }
    if let Some(r) = &s.rerun {
        println!(
            "rerun: {} frames logged, {} skipped (the sink fell behind), {} log errors",
            r.frames_logged, r.frames_skipped, r.log_errors
        );
    }
    let st = &s.status;
    let b = &st.buffer;
    let total: u64 = b.filled.iter().sum::<u64>().max(1);
    let pct = |i: usize| 100.0 * b.filled[i] as f64 / total as f64;
    println!(
        "done ({}): {} frames, frame ms p50 {:.2} p99 {:.2}, {} deadline stops, {} overruns; inputs sent {} samples, {} dropped at a full channel",
        s.stopped.reason(), st.frames, st.frame_ms_p50, st.frame_ms_p99, st.deadline_stops, st.overruns, s.source_samples, s.source_dropped
    );
    println!(
        "markers: {:.1} % measured, {:.1} % predicted, {:.1} % rigid-filled, {:.1} % held; {} samples, {} occluded, {} outside the stage volume, {} gated ({} label swaps), {} re-acquired, {} fills outside the volume held",
        pct(0), pct(1), pct(2), pct(3), b.accepted + b.occluded, b.occluded, b.implausible, b.gate_rejected, b.label_swaps, b.reacquired, b.implausible_fills
    );
    println!(
        "marker residual over the run: RMS {:.2} mm, max {:.2} mm",
        st.marker_residual_mm_rms, st.marker_residual_mm_max
    );
    if let (Some(median), Some(min)) = (st.lowest_vertex_m_median, st.lowest_vertex_m_min) {
        println!(
            "lowest vertex {:+.1} cm from the floor (y = 0) in the median frame, {:+.1} cm at the lowest",
            median * 100.0,
            min * 100.0
        );
    }
    if let Some(share) = st.all_limbs_driven_share {
        println!(
            "every one of the {} limbs driven by a marker in {:.1} % of the frames with markers in view",
            st.limbs,
            share * 100.0
        );
    }
    if let (Some(fed), Some(ignored)) = (s.labels_fed, s.labels_ignored) {
        println!(
            "labels: {fed} fed a marker, {ignored} ignored (no such marker, or another subject's)"
        );
    }
    if s.actors.len() > 1 {
        for a in &s.actors {
            let st = &a.status;
            let b = &st.buffer;
            println!(
                "actor {}: {} frames, frame ms p50 {:.2} p99 {:.2}, {} deadline stops, {} overruns; marker residual RMS {:.2} mm, max {:.2} mm; {} samples, {} gated ({} label swaps), {} another performer's",
                a.name, st.frames, st.frame_ms_p50, st.frame_ms_p99, st.deadline_stops, st.overruns,
                st.marker_residual_mm_rms, st.marker_residual_mm_max, b.accepted + b.occluded, b.gate_rejected, b.label_swaps, b.identity_gated
            );
        }
    }
    println!("stream: {}", serde_json::to_string(&s.stream)?);
    for line in &s.inputs {
        println!("input {line}");
    }
    Ok(())
}
