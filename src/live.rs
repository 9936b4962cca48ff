//! The live daemon's wiring for `rigless run` and `rigless demo`: a stage config in,
//! the character bound, the inputs started, the solver thread at its rate, the vertex
//! stream serving, a status line every second, and an orderly shutdown (loop, inputs,
//! then clients told goodbye). `rigless demo` is `run` with an embedded config.

use anyhow::{Context, Result};
use rigless::character::body::BodyMotion;
use rigless::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params, Motion};
use rigless::config::{InputConfig, StageConfig};
use rigless::daemon::clock::{Clock, SystemClock};
use rigless::daemon::pipeline::{run_loop, topology, LoopParams, LoopStatus, Pipeline};
use rigless::daemon::slot::LatestSlot;
use rigless::daemon::slot::PinSlot;
use rigless::input::glove::{run as run_glove, GloveStats, HandMap};
use rigless::input::natnet::{
    bind as natnet_bind, markers_of as natnet_markers, run_input as run_natnet, NatNetStats,
};
use rigless::input::osc::{bind as osc_bind, run as run_osc, OscStats};
use rigless::input::send_samples;
use rigless::input::synthetic::{play, SyntheticParams, SyntheticSession};
use rigless::input::vrpn::{run_mode as run_vrpn, sensor_name as vrpn_sensor_name, VrpnStats};
use rigless::input::SourceCounters;
use rigless::input::{parse_url, InputUrl};
use rigless::markers::buffer::MarkerBuffer;
use rigless::markers::MarkerSample;
use rigless::output::rerun_sink::{
    start as start_rerun, InputSeries, RerunOptions, RerunScene, RerunStats, RerunTarget,
};
use rigless::output::stream::{StreamServer, StreamStats};
use rigless::protocol::osc::OscMapping;
use rigless::replay::bundled::bundled;
use rigless::replay::player::{play_recording, PlayParams};
use rigless::replay::recording::{map_labels, Recording};
use rigless::replay::session::{run_recorder, SessionHeader, SessionWriter};
use rigless::rig::bind::Rig;
use rigless::solve::frame::{Solver, SolverParams};
use rigless::solve::ik::IkParams;
use std::io::{IsTerminal, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How a run was asked to stop and print.
pub struct RunOptions {
    /// Stop after this many seconds (default: when every non-looping input has ended).
    pub seconds: Option<f64>,
    /// Status and summary as JSON lines.
    pub json: bool,
    /// Record every incoming sample here (overrides `[recorder] path`).
    pub record: Option<std::path::PathBuf>,
    /// Where the Rerun recording goes (overrides `[outputs.rerun] target`).
    pub rerun: Option<RerunTarget>,
}

/// A Rerun target that can be honoured here: `spawn` needs the `rerun` viewer on PATH;
/// without it the recording is saved to `fallback` and the command that opens it is
/// printed.
fn usable_rerun_target(t: RerunTarget, fallback: &std::path::Path) -> RerunTarget {
    let on_path = |exe: &str| {
        std::env::var_os("PATH")
            .is_some_and(|paths| std::env::split_paths(&paths).any(|d| d.join(exe).is_file()))
    };
    match t {
        RerunTarget::Spawn if !on_path("rerun") => {
            println!(
                "no Rerun viewer on PATH: saving to {} instead; open it with: rerun {}",
                fallback.display(),
                fallback.display()
            );
            RerunTarget::Save(fallback.to_path_buf())
        }
        t => t,
    }
}

/// `YYYYmmdd-HHMMSS` (UTC) of a Unix time, for `{time}` in recorder paths.
fn utc_stamp(unix_s: f64) -> String {
    let secs = unix_s.max(0.0) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + (m <= 2) as i64;
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// Seconds between starting the threads and the first tick (lets the sources start).
const START_S: f64 = 0.05;

/// Runs a stage until its inputs end, `seconds` pass, or Ctrl-C. `base_dir` resolves a
/// character path.
pub fn run(cfg: &StageConfig, base_dir: &std::path::Path, opts: &RunOptions) -> Result<()> {
    let t0 = Instant::now();
    let (rig, name, procedural) = bind_character(cfg, base_dir, opts.json)?;
    let rig = Arc::new(rig);
    if !opts.json {
        println!(
            "{name}: {} mesh vertices, {} markers, {} control vertices; ready in {:.2} s",
            rig.mesh_rest.len(),
            rig.n_markers,
            rig.stats.control_vertices,
            t0.elapsed().as_secs_f64()
        );
    }
    let rate_hz = cfg.solver.rate_hz;
    let slot = Arc::new(LatestSlot::new());
    let mut server = None;
    let (tcp, ws) = (cfg.outputs.stream.tcp, cfg.outputs.stream.websocket);
    if tcp.is_some() || ws.is_some() {
        let s = StreamServer::start(tcp, ws, &topology(&rig, &name, rate_hz), Arc::clone(&slot))
            .context("starting the vertex stream")?;
        // Tests and scripts read these lines to find the ports.
        if let Some(a) = s.local_addr() {
            println!("vertex stream listening on tcp://{a}");
        }
        if let Some(a) = s.ws_addr() {
            println!("vertex stream listening on ws://{a}");
        }
        let _ = std::io::stdout().flush();
        server = Some(s);
    }
    let stream_stats = server.as_ref().map_or_else(
        || Arc::new(StreamStats::default()),
        |s| Arc::clone(s.stats()),
    );

    let (tx, rx) = crossbeam_channel::bounded(cfg.solver.channel_capacity);
    let buffer = MarkerBuffer::new(cfg.buffer.clone(), &rig.marker_rest, &rig.marker_joint);
    let solver = Solver::try_new(
        Arc::clone(&rig),
        SolverParams {
            method: cfg.solver.method(),
            max_iterations: cfg.solver.max_iterations,
            tolerance: cfg.solver.tolerance,
            ik: IkParams {
                rest_prior: cfg.solver.rest_prior,
                prev_prior: cfg.solver.prev_prior,
                ..IkParams::default()
            },
            volume_gain: cfg.solver.volume_gain,
        },
    )
    .with_context(|| format!("setting up the {:?} solver for {name}", cfg.solver.method))?;
    let rerun_target = usable_rerun_target(
        opts.rerun
            .clone()
            .unwrap_or_else(|| cfg.outputs.rerun.target(base_dir)),
        &base_dir.join(format!("rigless-{name}.rrd")),
    );
    // The Rerun thread starts once the inputs it plots exist; its slot is in from the
    // start.
    let rerun_slot = Arc::new(LatestSlot::new());
    let rerun_stop = Arc::new(AtomicBool::new(false));
    let rerun_stats = Arc::new(RerunStats::default());
    let mut slots = vec![slot];
    if rerun_target != RerunTarget::Off {
        slots.push(Arc::clone(&rerun_slot));
    }
    let harmonic_tied = solver.harmonic_tied().to_vec();
    let mut pipeline = Pipeline::new(solver, buffer, rx, slots);
    if rerun_target != RerunTarget::Off && cfg.outputs.rerun.control_mesh {
        pipeline = pipeline.with_control_mesh();
    }
    if rerun_target != RerunTarget::Off && cfg.outputs.rerun.harmonic_field {
        pipeline = pipeline.with_harmonic_field();
    }
    let clock = Arc::new(SystemClock::new());
    let record_path = opts
        .record
        .clone()
        .or_else(|| cfg.recorder.path.as_ref().map(|p| base_dir.join(p)))
        .map(|p| {
            let stamped = p
                .to_string_lossy()
                .replace("{time}", &utc_stamp(clock.unix_s(0.0)));
            std::path::PathBuf::from(stamped)
        });
    let mut recorder = None;
    if let Some(path) = &record_path {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        let file = std::fs::File::create(path)
            .with_context(|| format!("creating the session file {}", path.display()))?;
        let header = SessionHeader {
            marker_names: rig.marker_names.clone(),
            rate_hz,
            started_unix_s: clock.unix_s(0.0),
            inputs: cfg.inputs.iter().map(describe_input).collect(),
        };
        let writer = SessionWriter::new(file, &header, cfg.recorder.flush_interval_secs, 0.0)
            .with_context(|| format!("writing {}", path.display()))?;
        let (rec_tx, rec_rx) = crossbeam_channel::bounded(cfg.solver.channel_capacity * 4);
        pipeline = pipeline.with_recorder(rec_tx);
        let rec_clock = Arc::clone(&clock);
        let shown = path.display().to_string();
        recorder = Some((
            shown,
            std::thread::Builder::new()
                .name("recorder".into())
                .spawn(move || run_recorder(writer, &rec_rx, &|| rec_clock.now_s()))?,
        ));
        if !opts.json {
            println!(
                "recording every sample to {} (flushed every {} s)",
                path.display(),
                cfg.recorder.flush_interval_secs
            );
        }
    }

    let stop = Arc::new(AtomicBool::new(false));
    let status = Arc::new(LatestSlot::<LoopStatus>::new());
    let mut sources = Vec::new();
    let mut source_counters: Vec<Arc<SourceCounters>> = Vec::new();
    let mut inputs_end_s: Option<f64> = Some(START_S);
    // Joint angles from the gloves, shared by all of them (each writes its own joints).
    let pin_slot = Arc::new(PinSlot::new(rig.ik.n_params()));
    if cfg
        .inputs
        .iter()
        .any(|i| matches!(i, InputConfig::Glove(_)))
    {
        pipeline = pipeline.with_pins(Arc::clone(&pin_slot));
    }
    for input in &cfg.inputs {
        match input {
            InputConfig::Glove(g) => {
                let InputUrl::Glove(port) = parse_url(&g.url).map_err(anyhow::Error::msg)? else {
                    anyhow::bail!("{}: not a glove:// URL", g.url);
                };
                let map = HandMap::new(
                    &rig.skeleton,
                    &g.joints(),
                    g.calibration(port.max_value),
                    port.max_value,
                )
                .map_err(|errs| {
                    let lines: Vec<String> = errs.iter().map(|e| format!("  {e}")).collect();
                    anyhow::anyhow!(
                        "{}: the glove cannot drive {}:\n{}",
                        g.url,
                        name,
                        lines.join("\n")
                    )
                })?;
                println!(
                    "glove input reading {} ({} baud, {:?})",
                    port.path.display(),
                    port.baud,
                    port.format
                );
                inputs_end_s = None;
                let counters = Arc::new(SourceCounters::default());
                source_counters.push(Arc::clone(&counters));
                let (stop, slot, rig) =
                    (Arc::clone(&stop), Arc::clone(&pin_slot), Arc::clone(&rig));
                sources.push(std::thread::Builder::new().name("glove".into()).spawn(
                    move || {
                        let stats = GloveStats::default();
                        let first = |j: usize| rig.ik.angle_params(j);
                        run_glove(&port, &stop, &stats, &mut |_, r| {
                            slot.write(|pins| map.write_pins(r, &first, pins));
                            counters.count_frame(rigless::input::unix_now());
                        });
                    },
                )?);
            }
            InputConfig::Vrpn(v) => {
                let InputUrl::Vrpn { device, addr, mode } =
                    parse_url(&v.url).map_err(anyhow::Error::msg)?
                else {
                    anyhow::bail!("{}: not a vrpn:// URL", v.url);
                };
                println!("vrpn input connecting to {addr} for {device}");
                inputs_end_s = None;
                let counters = Arc::new(SourceCounters::default());
                source_counters.push(Arc::clone(&counters));
                let (clock, stop, tx) = (Arc::clone(&clock), Arc::clone(&stop), tx.clone());
                let index = MarkerIndex::new(&rig.marker_names);
                // Sensor number -> marker index, resolved once.
                let mut by_sensor: std::collections::HashMap<i32, Option<u32>> = Default::default();
                let sensors = v.sensors.clone();
                sources.push(
                    std::thread::Builder::new()
                        .name("vrpn".into())
                        .spawn(move || {
                            let stats = VrpnStats::default();
                            run_vrpn(mode, addr, &device, &stop, &stats, &mut |_, source, r| {
                                let k = *by_sensor.entry(r.sensor).or_insert_with(|| {
                                    let name = sensors
                                        .get(&r.sensor.to_string())
                                        .cloned()
                                        .unwrap_or_else(|| vrpn_sensor_name(&device, r.sensor));
                                    index.get(&name)
                                });
                                if let Some(k) = k {
                                    let sample = MarkerSample {
                                        marker: k,
                                        time_s: clock.now_s(),
                                        source_time_s: source,
                                        position_m: r.position,
                                        occluded: !r.position.is_finite(),
                                    };
                                    if !send_samples(&[sample], &tx, &counters) {
                                        stop.store(true, Ordering::Relaxed);
                                    }
                                }
                                counters.count_frame(clock.now_s());
                            });
                        })?,
                );
            }
            InputConfig::NatNet(n) => {
                let InputUrl::NatNet(addr, version, server) =
                    parse_url(&n.url).map_err(anyhow::Error::msg)?
                else {
                    anyhow::bail!("{}: not a natnet:// URL", n.url);
                };
                let sock = natnet_bind(addr).with_context(|| format!("binding {}", n.url))?;
                println!("natnet input listening on udp://{}", sock.local_addr()?);
                inputs_end_s = None;
                let counters = Arc::new(SourceCounters::default());
                source_counters.push(Arc::clone(&counters));
                let (clock, stop, tx) = (Arc::clone(&clock), Arc::clone(&stop), tx.clone());
                let index = MarkerIndex::new(&rig.marker_names);
                sources.push(std::thread::Builder::new().name("natnet".into()).spawn(
                    move || {
                        let stats = NatNetStats::default();
                        let (mut named, mut batch) = (Vec::new(), Vec::new());
                        let run = run_natnet(
                            &sock,
                            addr,
                            version,
                            server,
                            &stop,
                            &stats,
                            &mut |_, f, names| {
                                let t = clock.now_s();
                                named.clear();
                                natnet_markers(f, names, &mut named);
                                batch.clear();
                                for m in &named {
                                    if let Some(k) = index.get(&m.name) {
                                        batch.push(MarkerSample {
                                            marker: k,
                                            time_s: t,
                                            source_time_s: f.timestamp_s,
                                            position_m: m.position_m,
                                            occluded: m.occluded,
                                        });
                                    }
                                }
                                if !send_samples(&batch, &tx, &counters) {
                                    stop.store(true, Ordering::Relaxed);
                                }
                                counters.count_frame(t);
                            },
                        );
                        if let Err(e) = run {
                            tracing::error!(
                                "natnet input {addr}: cannot open its command socket: {e}"
                            );
                        }
                    },
                )?);
            }
            InputConfig::Osc(o) => {
                let (addr, mapping) = match parse_url(&o.url).map_err(anyhow::Error::msg)? {
                    InputUrl::NatNet(..) | InputUrl::Vrpn { .. } | InputUrl::Glove(_) => {
                        anyhow::bail!("{}: not an osc:// or vmc:// URL", o.url)
                    }
                    InputUrl::Osc(a) => (
                        a,
                        OscMapping {
                            patterns: o.patterns.clone(),
                            scale: o.scale,
                            z_up: o.up.eq_ignore_ascii_case("z"),
                            vmc: true,
                        },
                    ),
                    InputUrl::Vmc(a) => (
                        a,
                        OscMapping {
                            patterns: Vec::new(),
                            ..OscMapping::default()
                        },
                    ),
                };
                let sock = osc_bind(addr).with_context(|| format!("binding {}", o.url))?;
                // Tests and scripts read this line to find the port.
                println!("osc input listening on udp://{}", sock.local_addr()?);
                inputs_end_s = None;
                let counters = Arc::new(SourceCounters::default());
                source_counters.push(Arc::clone(&counters));
                let (clock, stop, tx) = (Arc::clone(&clock), Arc::clone(&stop), tx.clone());
                let index = MarkerIndex::new(&rig.marker_names);
                sources.push(
                    std::thread::Builder::new()
                        .name("osc".into())
                        .spawn(move || {
                            let stats = OscStats::default();
                            let mut batch = Vec::new();
                            run_osc(&sock, &mapping, &stop, &stats, &mut |_, f| {
                                let t = clock.now_s();
                                let src = f.source_time_s().unwrap_or(t);
                                batch.clear();
                                for m in f.markers() {
                                    if let Some(k) = index.get(&m.name) {
                                        batch.push(MarkerSample {
                                            marker: k,
                                            time_s: t,
                                            source_time_s: src,
                                            position_m: m.position_m,
                                            occluded: m.occluded,
                                        });
                                    }
                                }
                                if !send_samples(&batch, &tx, &counters) {
                                    stop.store(true, Ordering::Relaxed);
                                }
                                counters.count_frame(t);
                            });
                        })?,
                );
            }
            InputConfig::Replay(r) => {
                let rec = match (&r.session, &r.path) {
                    (Some(name), _) => {
                        let bytes = bundled(name).context("no such bundled session")?;
                        Recording::from_c3d(name, bytes)?
                    }
                    (None, Some(p)) => Recording::load_with(&base_dir.join(p), r.bvh_scale)?,
                    (None, None) => anyhow::bail!("a replay input needs a session or a path"),
                };
                let map = map_labels(&rec.labels, &rig.marker_names);
                if map.marker_of_label.iter().all(Option::is_none) {
                    anyhow::bail!(
                        "{}: none of its {} labels is one of the character's markers ({})",
                        rec.name,
                        rec.labels.len(),
                        rig.marker_names.join(", ")
                    );
                }
                if !opts.json {
                    println!(
                        "replaying {}: {} frames at {} Hz ({:.1} s), {} of {} markers fed{}",
                        rec.name,
                        rec.frames.len(),
                        rec.rate_hz,
                        rec.duration_secs(),
                        rig.n_markers - map.unfed_markers.len(),
                        rig.n_markers,
                        if r.looping { ", looping" } else { "" }
                    );
                    for w in &rec.warnings {
                        println!("  warning: {w}");
                    }
                    if !map.unmatched_labels.is_empty() {
                        println!(
                            "  warning: labels ignored (no such marker): {}",
                            map.unmatched_labels.join(", ")
                        );
                    }
                    if !map.unfed_markers.is_empty() {
                        println!(
                            "  warning: markers with no label (held): {}",
                            map.unfed_markers.join(", ")
                        );
                    }
                }
                inputs_end_s = match (inputs_end_s, r.looping) {
                    (_, true) | (None, _) => None,
                    (Some(e), false) => Some(e.max(START_S + rec.duration_secs() / r.speed)),
                };
                let counters = Arc::new(SourceCounters::default());
                source_counters.push(Arc::clone(&counters));
                let (clock, stop, tx) = (Arc::clone(&clock), Arc::clone(&stop), tx.clone());
                let params = PlayParams {
                    start_s: START_S,
                    speed: r.speed,
                    looping: r.looping,
                };
                sources.push(std::thread::Builder::new().name("replay".into()).spawn(
                    move || play_recording(&rec, &map, &*clock, params, &tx, &stop, &counters),
                )?);
            }
            InputConfig::Synthetic(sy) => {
                let ch = procedural
                    .clone()
                    .context("a synthetic input needs a procedural character")?;
                let motion = match (ch.name.as_str(), sy.motion.as_deref()) {
                    ("body", Some("reach")) => Motion::Body(BodyMotion::Reach),
                    ("body", _) => Motion::Body(BodyMotion::Walk),
                    _ => Motion::FingerPlay,
                };
                let session = SyntheticSession::new(
                    ch,
                    motion,
                    SyntheticParams {
                        rate_hz: sy.rate_hz,
                        duration_secs: sy.session_secs,
                        noise_m: sy.noise_mm * 1e-3,
                        gap_fraction: sy.gap_percent / 100.0,
                        seed: sy.seed,
                        ..SyntheticParams::default()
                    },
                );
                inputs_end_s = match (inputs_end_s, sy.looping) {
                    (_, true) | (None, _) => None,
                    (Some(e), false) => Some(e.max(START_S + sy.session_secs)),
                };
                let counters = Arc::new(SourceCounters::default());
                source_counters.push(Arc::clone(&counters));
                let (clock, stop, tx) = (Arc::clone(&clock), Arc::clone(&stop), tx.clone());
                let looping = sy.looping;
                sources.push(
                    std::thread::Builder::new()
                        .name("synthetic-source".into())
                        .spawn(move || {
                            play(session, &*clock, START_S, looping, &tx, &stop, &counters)
                        })?,
                );
            }
        }
    }
    drop(tx);
    let rerun_thread = start_rerun(
        &RerunOptions {
            target: rerun_target.clone(),
            mesh_every: cfg.outputs.rerun.mesh_every,
            control_mesh: cfg.outputs.rerun.control_mesh,
            harmonic_field: cfg.outputs.rerun.harmonic_field,
        },
        RerunScene::of_rig(&rig, &name).with_tied(&harmonic_tied),
        cfg.inputs
            .iter()
            .zip(&source_counters)
            .enumerate()
            .map(|(k, (i, c))| InputSeries {
                name: format!("{k}_{}", input_kind(i)),
                counters: Arc::clone(c),
            })
            .collect(),
        Arc::clone(&rerun_slot),
        Arc::clone(&rerun_stop),
        Arc::clone(&rerun_stats),
    )
    .context("starting the Rerun recording")?;
    if rerun_thread.is_some() && !opts.json {
        println!("rerun: {rerun_target:?}");
    }
    let end_s = match opts.seconds {
        Some(s) => Some(START_S + s),
        None => inputs_end_s,
    };
    let loop_params = LoopParams {
        rate_hz,
        deadline_fraction: cfg.solver.deadline_fraction,
        end_s,
        status_interval_s: 1.0,
    };
    let solver_thread = {
        let (clock, stop, status) = (Arc::clone(&clock), Arc::clone(&stop), Arc::clone(&status));
        std::thread::Builder::new()
            .name("solver".into())
            .spawn(move || {
                clock.sleep_until(START_S);
                let deadline_clock = Arc::clone(&clock);
                let last = run_loop(
                    &mut pipeline,
                    &*clock,
                    loop_params,
                    &stop,
                    &status,
                    &move |t| deadline_clock.instant_at(t),
                );
                pipeline.flush_to_recorder();
                last
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

    let tty = std::io::stdout().is_terminal() && !opts.json;
    while !solver_thread.is_finished() {
        std::thread::sleep(Duration::from_millis(50));
        if let Some(st) = status.take() {
            print_status(&st, &stream_stats, opts.json, tty);
        }
    }
    let last = solver_thread
        .join()
        .map_err(|_| anyhow::anyhow!("the solver thread panicked"))?;
    let interrupted = stop.swap(true, Ordering::Relaxed);
    for s in sources {
        let _ = s.join();
    }
    // The pipeline (and its recorder channel) went with the solver thread.
    if let Some((path, handle)) = recorder {
        let written = handle
            .join()
            .map_err(|_| anyhow::anyhow!("the recorder thread panicked"))?
            .with_context(|| format!("writing {path}"))?;
        if !opts.json {
            println!("recorded {written} samples to {path}");
        }
    }
    let reason = if interrupted {
        "shutting down"
    } else if opts.seconds.is_some() {
        "time limit reached"
    } else {
        "session ended"
    };
    if let Some(s) = server {
        s.shutdown(reason);
    }
    rerun_stop.store(true, Ordering::Relaxed);
    if let Some(h) = rerun_thread {
        h.join()
            .map_err(|_| anyhow::anyhow!("the Rerun thread panicked"))?;
        if !opts.json {
            println!(
                "rerun: {} frames logged, {} skipped (the sink fell behind)",
                rerun_stats.frames_logged.load(Ordering::Relaxed),
                rerun_slot.dropped()
            );
        }
    }
    if tty {
        println!();
    }
    let samples: u64 = source_counters
        .iter()
        .map(|c| c.samples.load(Ordering::Relaxed))
        .sum();
    let dropped: u64 = source_counters
        .iter()
        .map(|c| c.dropped.load(Ordering::Relaxed))
        .sum();
    print_summary(&last, &stream_stats, samples, dropped, reason, opts.json)?;
    Ok(())
}

/// Marker indices by name: exact names, and names without case or a `Subject:` prefix.
struct MarkerIndex {
    exact: std::collections::HashMap<String, u32>,
    loose: std::collections::HashMap<String, u32>,
}

impl MarkerIndex {
    fn bare(s: &str) -> String {
        s.rsplit(':')
            .next()
            .unwrap_or(s)
            .trim()
            .to_ascii_lowercase()
    }

    fn new(names: &[String]) -> Self {
        let mut loose = std::collections::HashMap::new();
        for (k, n) in names.iter().enumerate() {
            loose.entry(Self::bare(n)).or_insert(k as u32);
        }
        Self {
            exact: names
                .iter()
                .enumerate()
                .map(|(k, n)| (n.clone(), k as u32))
                .collect(),
            loose,
        }
    }

    fn get(&self, name: &str) -> Option<u32> {
        self.exact
            .get(name)
            .or_else(|| self.loose.get(&Self::bare(name)))
            .copied()
    }
}

/// How a session file names an input.
/// An input's scheme, as its Rerun series are named.
fn input_kind(i: &InputConfig) -> &'static str {
    match i {
        InputConfig::Osc(_) => "osc",
        InputConfig::NatNet(_) => "natnet",
        InputConfig::Vrpn(_) => "vrpn",
        InputConfig::Glove(_) => "glove",
        InputConfig::Synthetic(_) => "synthetic",
        InputConfig::Replay(_) => "replay",
    }
}

fn describe_input(i: &InputConfig) -> String {
    match i {
        InputConfig::Osc(o) => o.url.clone(),
        InputConfig::NatNet(n) => n.url.clone(),
        InputConfig::Vrpn(v) => v.url.clone(),
        InputConfig::Glove(g) => g.url.clone(),
        InputConfig::Synthetic(s) => {
            format!("synthetic:{}", s.motion.as_deref().unwrap_or("default"))
        }
        InputConfig::Replay(r) => match (&r.session, &r.path) {
            (Some(n), _) => format!("replay:{n}"),
            (None, Some(p)) => format!("replay:{}", p.display()),
            (None, None) => "replay".into(),
        },
    }
}

/// The rig, its name, and the procedural character when there is one.
fn bind_character(
    cfg: &StageConfig,
    base_dir: &std::path::Path,
    quiet: bool,
) -> Result<(Rig, String, Option<Arc<rigless::character::Character>>)> {
    if let Some(p) = &cfg.character.procedural {
        let (ch, bind) = match p.as_str() {
            "body" => (demo_body(), body_bind_params()),
            _ => (demo_hand(), hand_bind_params()),
        };
        let rig = Rig::bind(&ch, &bind).with_context(|| format!("binding the procedural {p}"))?;
        let name = ch.name.clone();
        return Ok((rig, name, Some(Arc::new(ch))));
    }
    let path = base_dir.join(cfg.character.path.as_ref().context("no character given")?);
    let loaded = rigless::character::file::load_character(&path)?;
    let (rig, source) = crate::load_or_bind(&path, &loaded, false, quiet)?;
    if !quiet {
        println!("{}: {source}", path.display());
    }
    Ok((rig, loaded.character.name.clone(), None))
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
        "frame {:>6}  {:>5.1} Hz  solve ms p50 {:.2} p99 {:.2} (frame {:.2} / {:.2})  iters {:>4.1}  markers: {m} measured, {p} predicted, {r} rigid, {h} held  clients {clients}",
        st.frames, st.frame_rate_hz, st.solve_ms_p50, st.solve_ms_p99, st.frame_ms_p50, st.frame_ms_p99, st.iterations_mean
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
    source_samples: u64,
    source_dropped: u64,
    reason: &str,
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
            "source_samples": source_samples,
            "source_dropped": source_dropped,
            "stopped": reason,
        });
        println!("{v}");
        return Ok(());
    }
    println!(
        "done ({reason}): {} frames, frame ms p50 {:.2} p99 {:.2}, {} deadline stops, {} overruns; inputs sent {source_samples} samples, {source_dropped} dropped at a full channel",
        st.frames, st.frame_ms_p50, st.frame_ms_p99, st.deadline_stops, st.overruns
    );
    println!(
        "markers: {:.1} % measured, {:.1} % predicted, {:.1} % rigid-filled, {:.1} % held; {} samples, {} occluded, {} gated ({} label swaps), {} re-acquired",
        pct(0), pct(1), pct(2), pct(3), b.accepted + b.occluded, b.occluded, b.gate_rejected, b.label_swaps, b.reacquired
    );
    println!("stream: {stream_json}");
    Ok(())
}
