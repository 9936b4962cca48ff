//! `rigless replay FILE --to URL` (a recording sent as live traffic) and `rigless replay
//! FILE --solve CHARACTER` (a recording driving a character through a stage).

use super::{ctrl_c_flag, run_stage, LiveOptions, ViewerFlag};
use anyhow::{bail, Context, Result};
use rigless::daemon::offline::export_take;
use rigless::output::rerun_sink::RerunTarget;
use rigless::replay::recording::{Recording, DEFAULT_BVH_METRES_PER_UNIT};
use rigless::replay::sender::{replay, ReplayOptions, Target};
use rigless::runtime::clock::SystemClock;
use rigless::solve::frame::Method;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct ReplayArgs {
    /// The recording.
    file: PathBuf,
    /// Where to send, e.g. osc://127.0.0.1:9000.
    #[arg(long, required_unless_present = "solve", conflicts_with = "solve")]
    to: Option<String>,
    /// Solve this character from the recording: `hand`, `body` (the procedural ones) or
    /// a character file (TOML).
    #[arg(long, value_name = "hand|body|CHARACTER.toml")]
    solve: Option<String>,
    /// With --solve: the deformation method, `arap` (volumetric ARAP and Green
    /// coordinates) or `harmonic` (harmonic rotation fields and a Poisson rebuild).
    #[arg(
        long,
        value_name = "arap|harmonic",
        default_value = "arap",
        requires = "solve"
    )]
    method: Method,
    /// With --solve: where the vertex stream listens (TCP; port 0 picks a free port).
    #[arg(long, default_value = "127.0.0.1:7878", requires = "solve")]
    stream: SocketAddr,
    /// With --solve: Rerun: off, spawn, connect=HOST:PORT or save=PATH.rrd (as on
    /// `rigless run`).
    #[arg(
        long,
        value_name = "off|spawn|connect=ADDR|save=PATH",
        requires = "solve"
    )]
    rerun: Option<RerunTarget>,
    /// With --solve: the browser viewer: serve its page and the WebSocket stream at this
    /// address, or `off` (default: 127.0.0.1:7879, or a free port when that one is
    /// taken; the address is printed).
    #[arg(long, value_name = "ADDR|off", requires = "solve")]
    viewer: Option<ViewerFlag>,
    /// Playback speed (1 = the file's timing).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Start again at the end (until Ctrl-C).
    #[arg(long = "loop")]
    looping: bool,
    /// Start this many seconds into the file (with --to).
    #[arg(long, default_value_t = 0.0)]
    start: f64,
    /// Stop this many seconds into the file (with --to or --solve).
    #[arg(long)]
    end: Option<f64>,
    /// Only these markers (comma-separated labels; with --to).
    #[arg(long, conflicts_with = "solve")]
    markers: Option<String>,
    /// Drop this share of samples at random (sent as occluded), percent (with --to).
    #[arg(long, default_value_t = 0.0, conflicts_with = "solve")]
    dropout_percent: f64,
    /// Add uniform noise of this amplitude per axis, millimetres (with --to).
    #[arg(long, default_value_t = 0.0, conflicts_with = "solve")]
    noise_mm: f64,
    /// Seed of the dropouts and the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Metres per BVH unit.
    #[arg(long, default_value_t = DEFAULT_BVH_METRES_PER_UNIT)]
    bvh_scale: f64,
    /// With --solve: character metres per recorded metre, applied to every marker
    /// (default: the character file's calibration.marker_scale, which `rigless calibrate
    /// --write` sets; else 1).
    #[arg(long, requires = "solve")]
    marker_scale: Option<f64>,
    /// With --solve: the performer whose labels drive the character when the take
    /// holds several (`Ann` for `Ann:LFHD`; "" for labels without a prefix; `--actor`
    /// says the same, e.g. with `--export` for one actor's file). Default:
    /// the subject with most labels matching a marker; the others are ignored and
    /// named.
    #[arg(long, value_name = "NAME", requires = "solve", alias = "actor")]
    subject: Option<String>,
    /// With --solve (live, not --export): drive one actor per performer of the take,
    /// each the same character: every subject with at least 3 labels matching its
    /// markers (a prop's few markers are not a performer). The status lines and the
    /// summary report each; the vertex stream, viewer and Rerun carry them all.
    #[arg(long, requires = "solve", conflicts_with_all = ["subject", "export"])]
    actors: bool,
    /// With --solve: solve every frame off line, as fast as the machine goes (no
    /// deadline, no stream), and write each to this file at the take's rate, in the
    /// format of its extension: `.pc2` (the full mesh's vertices, a point cache for
    /// Blender's Mesh Cache modifier, 3ds Max, Houdini, on the character's own mesh),
    /// `.bvh` (the fitted skeleton's motion, centimetres) or `.glb` (the mesh at rest
    /// skinned to the skeleton, each vertex to its nearest bone, and the motion as an
    /// animation: any engine).
    #[arg(
        long,
        value_name = "OUT.pc2|OUT.bvh|OUT.glb",
        requires = "solve",
        conflicts_with_all = ["end", "looping", "rerun"]
    )]
    export: Option<PathBuf>,
    /// With `--export`: parts of the take solved at once, a thread each (0: one per
    /// core). Each later part starts a quarter second early to warm its solver up; 1
    /// solves frame after frame, exactly as the live loop would.
    #[arg(long, value_name = "N", default_value_t = 0, requires = "export")]
    threads: usize,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
}

/// Every problem with the flags at once.
fn flag_problems(a: &ReplayArgs) -> Vec<String> {
    let mut problems = Vec::new();
    if a.threads > 256 {
        problems.push(format!("--threads must be 256 at most, got {}", a.threads));
    }
    if !(a.speed.is_finite() && a.speed > 0.0 && a.speed <= 100.0) {
        problems.push(format!("--speed must be in (0, 100], got {:?}", a.speed));
    }
    if !(a.start.is_finite() && a.start >= 0.0) {
        problems.push(format!(
            "--start must be zero or more seconds, got {:?}",
            a.start
        ));
    }
    if a.end.is_some_and(|e| !(e.is_finite() && e > a.start)) {
        problems.push(format!("--end must be after --start ({} s)", a.start));
    }
    if !(0.0..=100.0).contains(&a.dropout_percent) {
        problems.push(format!(
            "--dropout-percent must be 0 to 100, got {:?}",
            a.dropout_percent
        ));
    }
    if !(a.noise_mm.is_finite() && a.noise_mm >= 0.0) {
        problems.push(format!(
            "--noise-mm must be zero or more, got {:?}",
            a.noise_mm
        ));
    }
    if !(a.bvh_scale.is_finite() && a.bvh_scale > 0.0) {
        problems.push(format!(
            "--bvh-scale must be positive, got {:?}",
            a.bvh_scale
        ));
    }
    if a.solve.is_some() && a.start != 0.0 {
        problems.push("--start shapes what --to sends; with --solve the recording plays from its first frame (--end stops it early)".into());
    }
    problems
}

pub fn run(a: ReplayArgs) -> Result<()> {
    let mut problems = flag_problems(&a);
    if let Some(character) = &a.solve {
        if !problems.is_empty() {
            bail!("{}", problems.join("\n"));
        }
        if let Some(out) = &a.export {
            return export(&a, character, out);
        }
        let cfg = solve_stage(&a, character)?;
        return run_stage(
            cfg,
            Path::new("."),
            &LiveOptions {
                // The recording's seconds at this speed.
                seconds: a.end.map(|e| e / a.speed),
                json: a.json,
                rerun: a.rerun,
                viewer: a.viewer,
            },
        );
    }
    let to = a.to.clone().context("--to or --solve is required")?;
    let target = Target::parse(&to)
        .map_err(|e| problems.push(e.to_string()))
        .ok();
    let (Some(target), true) = (target, problems.is_empty()) else {
        bail!("{}", problems.join("\n"));
    };
    send(&a, &to, target)
}

/// Sends the recording to `target` as live traffic and prints the send-time jitter.
fn send(a: &ReplayArgs, to: &str, target: Target) -> Result<()> {
    match &target {
        Target::NatNet { data, command: Some(c) } => eprintln!("serving NatNet 3.0 frames to {data}; command port {c} (clients: natnet://{data}?server={c})"),
        Target::NatNet { data, command: None } => eprintln!("sending NatNet 3.0 frames to {data} (markers named replay_1, replay_2...; add ?server=IP:PORT for a command port that names them)"),
        Target::Vrpn { device, bind } => eprintln!("serving {device} as a VRPN tracker on TCP and UDP {bind} (clients: {device}@{bind} or {device}@tcp://{bind})"),
        Target::Osc(_) | Target::Vmc(_) => {}
    }
    let rec = Recording::load_with(&a.file, a.bvh_scale)?;
    let subset: Option<Vec<String>> = a
        .markers
        .as_ref()
        .map(|m| m.split(',').map(|s| s.trim().to_owned()).collect());
    if let Some(sub) = &subset {
        let unknown: Vec<&String> = sub.iter().filter(|m| !rec.labels.contains(m)).collect();
        if !unknown.is_empty() {
            bail!(
                "{}: no such labels: {:?} (it has {})",
                a.file.display(),
                unknown,
                rec.labels.join(", ")
            );
        }
    }
    let opts = ReplayOptions {
        speed: a.speed,
        looping: a.looping,
        start_s: a.start,
        end_s: a.end,
        markers: subset,
        dropout: a.dropout_percent / 100.0,
        noise_m: a.noise_mm * 1e-3,
        seed: a.seed,
    };
    if !a.json {
        eprintln!(
            "replaying {} ({} markers, {} frames at {} Hz) to {to}{}",
            a.file.display(),
            rec.labels.len(),
            rec.frames.len(),
            rec.rate_hz,
            if a.looping {
                ", looping; Ctrl-C stops"
            } else {
                ""
            }
        );
    }
    let stop = ctrl_c_flag()?;
    let stats = replay(&rec, target, &opts, &SystemClock::new(), 0.01, &stop)
        .with_context(|| format!("sending to {to}"))?;
    if a.json {
        println!("{}", serde_json::to_string(&stats)?);
    } else {
        println!(
            "sent {} packets ({} bytes, {} errors, {} samples dropped on purpose); send-time jitter ms p50 {:.3} p99 {:.3} max {:.3}",
            stats.packets, stats.bytes, stats.send_errors, stats.samples_dropped,
            stats.jitter_ms_p50, stats.jitter_ms_p99, stats.jitter_ms_max
        );
        if stats.reply_errors > 0 {
            println!(
                "{} NatNet command replies could not be sent (the client asks again)",
                stats.reply_errors
            );
        }
    }
    Ok(())
}

/// `--export OUT`: the take solved off line at its own rate, every frame's mesh
/// written to `out`, with a progress bar and a summary.
fn export(a: &ReplayArgs, character: &str, out: &Path) -> Result<()> {
    use std::io::IsTerminal;
    if rigless::output::export::ExportFormat::of(out).is_none() {
        bail!(
            "--export {}: the format follows the extension: .pc2 (a point cache of the full mesh), .bvh (the fitted skeleton) or .glb (the mesh skinned to the skeleton, animated)",
            out.display()
        );
    }
    let mut rec = Recording::load_with(&a.file, a.bvh_scale)?;
    if let Some(subject) = &a.subject {
        let dropped = rec.keep_subject(subject);
        if dropped > 0 {
            eprintln!("{dropped} labels of other subjects than {subject:?} left out");
        }
    }
    let (rig, file_scale) = super::bound_character(character)?;
    let params = rigless::solve::frame::SolverParams {
        method: a.method,
        ..Default::default()
    };
    let t0 = std::time::Instant::now();
    let bar = !a.json && std::io::stderr().is_terminal();
    let mut shown = -1i64;
    let mut progress = |done: usize, of: usize| {
        let pct = (done * 100 / of.max(1)) as i64;
        if bar && pct != shown {
            shown = pct;
            let fps = done as f64 / t0.elapsed().as_secs_f64().max(1e-9);
            eprint!(
                "\r  solving [{}] {pct:>3}%  {done} of {of} frames, {fps:.0} frames/s",
                super::bar(pct)
            );
        }
    };
    let summary = export_take(
        rig,
        params,
        &rec,
        rigless::daemon::offline::ExportOptions {
            marker_scale: a.marker_scale.unwrap_or(file_scale),
            threads: a.threads,
        },
        out,
        &mut progress,
    );
    if bar && shown >= 0 {
        eprintln!();
    }
    let summary = summary?;
    let secs = t0.elapsed().as_secs_f64();
    let fps = summary.frames as f64 / secs.max(1e-9);
    if a.json {
        let mut v = serde_json::to_value(&summary)?;
        v["path"] = out.display().to_string().into();
        v["seconds"] = secs.into();
        v["frames_per_second"] = fps.into();
        println!("{v}");
        return Ok(());
    }
    let r = &summary.replay;
    if let Some(others) = &r.other_subjects {
        println!("{others}");
    }
    println!(
        "wrote {}: {} frames of {} points at {} Hz in {secs:.2} s ({fps:.0} frames/s, {:.1} times real time, {} part(s) at once)",
        out.display(),
        summary.frames,
        summary.points,
        summary.rate_hz,
        fps / summary.rate_hz,
        summary.parts
    );
    if summary.posture_only {
        // A BVH: the posture alone was fitted.
        println!(
            "labels fed {}, samples held {:.1} %, skeleton misfit {:.1} mm RMS ({:.1} max)",
            r.labels_fed,
            r.held_share * 100.0,
            r.residual_mm_rms,
            r.residual_mm_max
        );
        return Ok(());
    }
    println!(
        "iterations {:.2} a frame on average, {} at most; {} frame(s) stopped at the iteration cap",
        r.iterations_mean, r.iterations_max, r.iteration_cap_stops
    );
    println!(
        "labels fed {}, samples held {:.1} %, misfit {:.1} mm RMS ({:.1} max), inverted tets {} at worst",
        r.labels_fed,
        r.held_share * 100.0,
        r.residual_mm_rms,
        r.residual_mm_max,
        r.inverted_tets_max
    );
    if let (Some(median), Some(min)) = (r.lowest_vertex_m_median, r.lowest_vertex_m_min) {
        println!(
            "lowest vertex {:+.1} cm from the take's floor in the median frame, {:+.1} cm at the lowest",
            median * 100.0,
            min * 100.0
        );
    }
    match r.all_limbs_driven_share {
        Some(share) => println!(
            "every one of the {} limbs driven by a marker in {:.1} % of the frames",
            r.limbs,
            share * 100.0
        ),
        None => println!("no arm or leg recognised by name: limbs not counted"),
    }
    Ok(())
}

/// Labels of a subject that make it a performer for `--actors`.
const PERFORMER_LABELS: usize = 3;

/// `--actors`: an `[[actors]]` table per performer of the take (each `character`, its
/// table `ch`), named and claimed by subject.
fn take_actors(a: &ReplayArgs, character: &str, ch: &toml::Table) -> Result<Vec<toml::Value>> {
    use rigless::markers::index::performers;
    let rec = Recording::load_with(&a.file, a.bvh_scale)?;
    let markers: Vec<String> = match character {
        "hand" => rigless::character::demo::demo_hand().markers,
        "body" => rigless::character::demo::demo_body().markers,
        path => {
            rigless::character::file::load_character(Path::new(path))?
                .character
                .markers
        }
    }
    .into_iter()
    .map(|m| m.name)
    .collect();
    let found = performers(&rec.labels, &markers, PERFORMER_LABELS);
    if found.len() < 2 {
        let whose: Vec<String> = found
            .iter()
            .map(|(s, n)| format!("{s:?} ({n} labels)"))
            .collect();
        bail!(
            "--actors: {} has {} performer{} with at least {PERFORMER_LABELS} labels matching the character's markers ({}); --actors needs two or more (without it one is driven)",
            a.file.display(),
            found.len(),
            if found.len() == 1 { "" } else { "s" },
            if whose.is_empty() { "none".to_owned() } else { whose.join(", ") }
        );
    }
    Ok(found
        .into_iter()
        .map(|(subject, _)| {
            let mut t = ch.clone();
            let name = if subject.is_empty() {
                "unprefixed".to_owned()
            } else {
                subject.clone()
            };
            t.insert("name".into(), toml::Value::String(name));
            if !subject.is_empty() {
                t.insert("subject".into(), toml::Value::String(subject));
            }
            toml::Value::Table(t)
        })
        .collect())
}

/// The stage `--solve CHARACTER` runs: the recording as a replay input, validated like a
/// stage file.
fn solve_stage(a: &ReplayArgs, character: &str) -> Result<rigless::config::StageConfig> {
    use toml::{Table, Value};
    let abs = |p: &Path| -> Result<Value> {
        let p = std::fs::canonicalize(p).with_context(|| format!("{}", p.display()))?;
        Ok(Value::String(p.to_string_lossy().into_owned()))
    };
    let mut ch = Table::new();
    match character {
        "hand" | "body" => ch.insert("procedural".into(), Value::String(character.into())),
        path => ch.insert("path".into(), abs(Path::new(path))?),
    };
    if let Some(s) = a.marker_scale {
        ch.insert("marker_scale".into(), Value::Float(s));
    }
    if let Some(s) = &a.subject {
        ch.insert("subject".into(), Value::String(s.clone()));
    }
    let actors = if a.actors {
        take_actors(a, character, &ch)?
    } else {
        Vec::new()
    };
    let mut input = Table::new();
    input.insert("type".into(), Value::String("replay".into()));
    input.insert("path".into(), abs(&a.file)?);
    input.insert("speed".into(), Value::Float(a.speed));
    input.insert("loop".into(), Value::Boolean(a.looping));
    input.insert("bvh_scale".into(), Value::Float(a.bvh_scale));
    let method = a.method.name();
    let mut stage = toml::toml! {
        [solver]
        method = method

        [outputs.stream]
        tcp = (a.stream.to_string())
    };
    if actors.is_empty() {
        stage.insert("character".into(), Value::Table(ch));
    } else {
        stage.insert("actors".into(), Value::Array(actors));
    }
    stage.insert("inputs".into(), Value::Array(vec![Value::Table(input)]));
    Ok(rigless::config::parse_stage(
        &toml::to_string(&stage)?,
        "replay --solve flags",
    )?)
}
