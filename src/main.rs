//! The `rigless` command line: the only place that prints to the user and exits.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use rigless::bench::{capsules, characters};
use std::path::PathBuf;

mod live;

/// Animate a character mesh live from a handful of motion-capture markers, with no
/// rigging step.
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the live daemon from a stage config.
    ///
    /// Run the live daemon from a stage config (TOML: the character, the inputs, the
    /// solver, the outputs; every key is documented in src/config.rs and stages/): bind
    /// the character (or load its bake cache), start the inputs and the solver thread,
    /// serve the vertex stream, print a status line every second, and run until the
    /// inputs end, --seconds pass, or Ctrl-C (clients are told goodbye).
    Run {
        /// The stage config file.
        #[arg(long)]
        config: PathBuf,
        /// Stop after this many seconds.
        #[arg(long)]
        seconds: Option<f64>,
        /// Check the config, print every problem, and exit without running.
        #[arg(long)]
        check: bool,
        /// Record every incoming sample to this session file (overrides `[recorder]`;
        /// `{time}` becomes the start time).
        #[arg(long)]
        record: Option<PathBuf>,
        /// Rerun: off, spawn (a viewer; without one on PATH, save rigless-CHARACTER.rrd
        /// and print how to open it), connect=HOST:PORT (a running viewer, gRPC port 9876
        /// by default) or save=PATH.rrd. Overrides the stage's [outputs.rerun].
        #[arg(long, value_name = "off|spawn|connect=ADDR|save=PATH")]
        rerun: Option<rigless::output::rerun_sink::RerunTarget>,
        /// Print the status and the summary as JSON lines instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Replay a bundled session of a procedural character live (the default demo).
    ///
    /// The embedded default: play a bundled recorded session of a procedural character
    /// (the hand's finger play by default, or the body's walk or reach; 0.5 mm noise and
    /// 5 % of samples lost in occlusion gaps, see replay/README.md) live through the whole
    /// pipeline, in real time: the marker buffer fills the gaps, the solver thread solves
    /// every frame at 120 Hz, and the vertex stream serves the deformed mesh (see
    /// protocols/vertex-stream.md). Prints a status line every second and a summary at the
    /// end; stops at the end of the session, after --seconds, or on Ctrl-C.
    Demo {
        /// Which procedural character: the hand (8 markers) or the body (36 markers).
        #[arg(long, value_enum, default_value_t = DemoCharacter::Hand)]
        character: DemoCharacter,
        /// The body's motion (the hand always plays its finger play).
        #[arg(long, value_enum, default_value_t = DemoMotion::Walk)]
        motion: DemoMotion,
        /// Stop after this many seconds (default: at the end of the session).
        #[arg(long)]
        seconds: Option<f64>,
        /// Play the session again and again (until --seconds or Ctrl-C).
        #[arg(long = "loop")]
        looping: bool,
        /// Playback speed (1 = real time).
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Where the vertex stream listens (TCP; port 0 picks a free port).
        #[arg(long, default_value = "127.0.0.1:7878")]
        stream: std::net::SocketAddr,
        /// Also serve the vertex stream over WebSocket here (e.g. 127.0.0.1:7879).
        #[arg(long)]
        websocket: Option<std::net::SocketAddr>,
        /// Rerun: off, spawn (a viewer; without one on PATH, save rigless-CHARACTER.rrd
        /// and print how to open it), connect=HOST:PORT (a running viewer, gRPC port 9876
        /// by default) or save=PATH.rrd. Overrides the stage's [outputs.rerun].
        #[arg(long, value_name = "off|spawn|connect=ADDR|save=PATH")]
        rerun: Option<rigless::output::rerun_sink::RerunTarget>,
        /// Print the status and the summary as JSON lines instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Bind a character file and cache the result.
    ///
    /// Bind a character: read its TOML file and mesh, build the control mesh, the Green
    /// coordinates and the factorization, print a summary, and cache the result next to
    /// the character file (`NAME.rigcache`, keyed by a hash of the character file, the
    /// mesh file and this version) so the next start loads it instead of binding again.
    Bake {
        /// The character file (TOML: mesh, skeleton, markers; see README).
        character: PathBuf,
        /// Bind again even if the cache is current.
        #[arg(long)]
        force: bool,
        /// Print the summary as one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Print what an input (OSC, VMC, NatNet, VRPN, data glove) decodes.
    ///
    /// Print what an input decodes, one line per packet (one JSON object with --json):
    /// receive time, source time, and each marker's name, position in metres in the world
    /// frame (Y up) and flags. The first tool to run when a stage is set up. URLs:
    /// osc://HOST:PORT (binds it; native schema, /marker/{name} and /mocap/{name}
    /// patterns, and VMC), vmc://HOST:PORT (VMC only),
    /// natnet://HOST:PORT[?version=M.m&server=IP[:PORT]] (binds the data port; a multicast
    /// address joins the group; with server=, connects to Motive's command port for its
    /// version and marker names, and keeps a unicast stream alive),
    /// vrpn://DEVICE@HOST[:PORT] (UDP connection mode: the server calls back and sends
    /// reports over UDP; port 3883 by default) or vrpn://DEVICE@tcp://HOST:PORT (connects;
    /// one marker DEVICE_SENSOR per sensor),
    /// glove:///dev/ttyUSB0[?baud=115200&format=alpha|legacy&max=4095] (a serial data
    /// glove, reopened when replugged; one line per glove line: curls, splay, joystick and
    /// buttons as fractions of full scale, and the procedural hand's finger joints posed
    /// by them with the wrist at rest).
    Listen {
        /// The input URL, e.g. osc://127.0.0.1:9000.
        url: String,
        /// One JSON object per packet.
        #[arg(long)]
        json: bool,
        /// Stop after this many seconds (default: until Ctrl-C).
        #[arg(long)]
        seconds: Option<f64>,
        /// Stop after this many packets.
        #[arg(long)]
        packets: Option<u64>,
        /// Metres per sender unit (0.001 for a millimetre sender).
        #[arg(long, default_value_t = 1.0)]
        scale: f64,
        /// The sender's up axis is Z (converted to the world's Y up).
        #[arg(long)]
        z_up: bool,
    },
    /// Send a recording as live OSC, VMC, VRPN or NatNet traffic, or solve a character
    /// from it.
    ///
    /// Send a recording (C3D, TSV, BVH or session) as live traffic with its original
    /// timing: to an OSC receiver in the native schema (osc://HOST:PORT), to a VMC
    /// receiver (vmc://HOST:PORT, markers as trackers), or as a VRPN tracker server
    /// (vrpn://DEVICE@HOST:PORT binds TCP and UDP there and serves clients in both VRPN
    /// connection modes; each marker a sensor, in label order), or as a NatNet 3.0
    /// server (natnet://HOST:PORT receives the frames, unicast or a multicast group;
    /// ?server=IP:PORT binds a command port that answers connect and model-definition
    /// requests, naming the markers replay:LABEL).
    /// Prints the send-time jitter against the file's clock at the end.
    ///
    /// With --solve instead of --to, the recording drives a character through the whole
    /// live pipeline in real time (as `rigless run` with a replay input): markers are
    /// matched to the character's by label, the solver runs at 120 Hz, the vertex stream
    /// is served (--stream) and --rerun records or shows it.
    Replay {
        /// The recording.
        file: PathBuf,
        /// Where to send, e.g. osc://127.0.0.1:9000.
        #[arg(long, required_unless_present = "solve", conflicts_with = "solve")]
        to: Option<String>,
        /// Solve this character from the recording: `hand`, `body` (the procedural ones)
        /// or a character file (TOML).
        #[arg(long, value_name = "hand|body|CHARACTER.toml")]
        solve: Option<String>,
        /// With --solve: the deformation method.
        #[arg(long, value_enum, default_value_t = Method::Arap, requires = "solve")]
        method: Method,
        /// With --solve: where the vertex stream listens (TCP; port 0 picks a free port).
        #[arg(long, default_value = "127.0.0.1:7878", requires = "solve")]
        stream: std::net::SocketAddr,
        /// With --solve: Rerun: off, spawn, connect=HOST:PORT or save=PATH.rrd (as on
        /// `rigless run`).
        #[arg(
            long,
            value_name = "off|spawn|connect=ADDR|save=PATH",
            requires = "solve"
        )]
        rerun: Option<rigless::output::rerun_sink::RerunTarget>,
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
        #[arg(long, default_value_t = rigless::replay::recording::DEFAULT_BVH_METRES_PER_UNIT)]
        bvh_scale: f64,
        /// Print the summary as one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Show what a recording holds.
    ///
    /// Show what a recording holds (C3D, Qualisys TSV, BVH or a session file): markers, rate, frames,
    /// duration, the file's units, the share of missing samples per marker, the bounding
    /// box (metres, Y up), and anything the reader had to tolerate.
    Info {
        /// The recording.
        file: PathBuf,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
        /// Metres per BVH unit (BVH files have no units; CMU's conversions use about
        /// 0.0564).
        #[arg(long, default_value_t = rigless::replay::recording::DEFAULT_BVH_METRES_PER_UNIT)]
        bvh_scale: f64,
    },
    /// Write the bundled sessions (C3D).
    ///
    /// Write the bundled sessions (the procedural hand's finger play, the body's walk and
    /// reach, as C3D with noise and occlusion gaps) into a folder; `replay/` in the source
    /// tree holds exactly what this writes.
    MakeSessions {
        /// Folder to write `NAME.c3d` into (created if missing).
        dir: PathBuf,
    },
    /// Write the procedural hand as an example character.
    ///
    /// Write the procedural hand as a mesh (OBJ) and a character file (TOML) into a
    /// folder: a complete example of the character format to start from, ready for
    /// `rigless bake DIR/hand.toml`.
    ExportHand {
        /// Folder to write `hand.obj` and `hand.toml` into (created if missing).
        dir: PathBuf,
    },
    /// Run a benchmark suite and print one line per case (a table, or JSON with --json).
    Bench {
        /// Which suite: `capsules` (plain ARAP on the benchmark tet meshes of the shared
        /// data folder), `characters` (the procedural hand and body playing their motions),
        /// `gapfill` (the marker buffer's fill error by gap length, on synthetic sessions
        /// and the shared data folder's Qualisys hand recording), or `live` (the whole
        /// pipeline in real time: latency from input to client, missed ticks, 50 clients),
        /// `codecs` (decode cost per packet of each input format, 50 markers), or `replay`
        /// (send-time jitter of `rigless replay` at 120 Hz against the file's clock).
        #[arg(long, value_enum, default_value_t = Suite::Capsules)]
        suite: Suite,
        /// Print one JSON object per line instead of a table.
        #[arg(long)]
        json: bool,
        /// The shared data folder (holds `tetmesh/`).
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Seconds per case of the `live` suite.
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum DemoCharacter {
    Hand,
    Body,
}

#[derive(Clone, Copy, ValueEnum)]
enum DemoMotion {
    Walk,
    Reach,
}

#[derive(Clone, Copy, ValueEnum)]
enum Method {
    /// Volumetric ARAP with skeleton constraints and Green coordinates.
    Arap,
    /// Harmonic rotation fields and a Poisson rebuild (de Aguiar et al.).
    Harmonic,
}

#[derive(Clone, Copy, ValueEnum)]
enum Suite {
    Capsules,
    Characters,
    Gapfill,
    Live,
    Codecs,
    Replay,
}

/// The stage `rigless replay FILE --solve CHARACTER` runs: the recording as a replay
/// input, validated like a stage file.
fn solve_stage(
    file: &std::path::Path,
    character: &str,
    method: Method,
    stream: std::net::SocketAddr,
    speed: f64,
    looping: bool,
    bvh_scale: f64,
) -> Result<rigless::config::StageConfig> {
    use toml::{Table, Value};
    let abs = |p: &std::path::Path| -> Result<Value> {
        let p = std::fs::canonicalize(p).with_context(|| format!("{}", p.display()))?;
        Ok(Value::String(p.to_string_lossy().into_owned()))
    };
    let mut ch = Table::new();
    match character {
        "hand" | "body" => ch.insert("procedural".into(), Value::String(character.into())),
        path => ch.insert("path".into(), abs(std::path::Path::new(path))?),
    };
    let mut input = Table::new();
    input.insert("type".into(), Value::String("replay".into()));
    input.insert("path".into(), abs(file)?);
    input.insert("speed".into(), Value::Float(speed));
    input.insert("loop".into(), Value::Boolean(looping));
    input.insert("bvh_scale".into(), Value::Float(bvh_scale));
    let method = match method {
        Method::Arap => "arap",
        Method::Harmonic => "harmonic",
    };
    let mut stage = toml::toml! {
        [solver]
        method = method

        [outputs.stream]
        tcp = (stream.to_string())
    };
    stage.insert("character".into(), Value::Table(ch));
    stage.insert("inputs".into(), Value::Array(vec![Value::Table(input)]));
    Ok(rigless::config::parse_stage(
        &toml::to_string(&stage)?,
        "replay --solve flags",
    )?)
}

fn main() -> std::process::ExitCode {
    match real_main() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // The whole chain of causes, without a backtrace: these are user errors.
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn real_main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let cli = Cli::parse();
    if matches!(cli.command, Command::Bench { .. }) {
        // Benchmarks print tables and JSON lines to stdout: piped into `head`, they should
        // end quietly like any Unix filter, not panic on the closed pipe. (Their sockets
        // are TCP, whose sends carry MSG_NOSIGNAL, so only stdout is concerned.)
        // SAFETY: restoring the default disposition of a signal; no handler is installed.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    match cli.command {
        Command::Run {
            config,
            seconds,
            check,
            record,
            rerun,
            json,
        } => {
            check_seconds(seconds)?;
            let cfg = rigless::config::load_stage(&config)?;
            if check {
                println!("{}: ok", config.display());
                return Ok(());
            }
            let base = config.parent().unwrap_or(std::path::Path::new("."));
            live::run(
                &cfg,
                base,
                &live::RunOptions {
                    seconds,
                    json,
                    record,
                    rerun,
                },
            )
        }
        Command::Demo {
            character,
            motion,
            seconds,
            looping,
            speed,
            stream,
            websocket,
            rerun,
            json,
        } => {
            check_seconds(seconds)?;
            let (procedural, session) = match (character, motion) {
                (DemoCharacter::Hand, _) => ("hand", "hand_finger_play"),
                (DemoCharacter::Body, DemoMotion::Walk) => ("body", "body_walk"),
                (DemoCharacter::Body, DemoMotion::Reach) => ("body", "body_reach"),
            };
            let ws_line = websocket.map_or(String::new(), |w| format!("websocket = \"{w}\"\n"));
            // The embedded default stage, with the flags applied; validated like a file.
            let text = format!(
                "[character]\nprocedural = \"{procedural}\"\n\n[[inputs]]\ntype = \"replay\"\nsession = \"{session}\"\nspeed = {speed:?}\nloop = {looping}\n\n[outputs.stream]\ntcp = \"{stream}\"\n{ws_line}"
            );
            let cfg = rigless::config::parse_stage(&text, "demo flags")?;
            live::run(
                &cfg,
                std::path::Path::new("."),
                &live::RunOptions {
                    seconds,
                    json,
                    record: None,
                    rerun,
                },
            )
        }
        Command::Listen {
            url,
            json,
            seconds,
            packets,
            scale,
            z_up,
        } => {
            check_seconds(seconds)?;
            listen(&url, json, seconds, packets, scale, z_up)
        }
        Command::Replay {
            file,
            to,
            solve,
            method,
            stream,
            rerun,
            speed,
            looping,
            start,
            end,
            markers,
            dropout_percent,
            noise_mm,
            seed,
            bvh_scale,
            json,
        } => {
            use rigless::replay::sender::{replay, ReplayOptions, Target};
            let mut problems = Vec::new();
            if !(speed.is_finite() && speed > 0.0 && speed <= 100.0) {
                problems.push(format!("--speed must be in (0, 100], got {speed}"));
            }
            if !(start.is_finite() && start >= 0.0) {
                problems.push(format!("--start must be zero or more seconds, got {start}"));
            }
            if end.is_some_and(|e| !(e.is_finite() && e > start)) {
                problems.push(format!("--end must be after --start ({start} s)"));
            }
            if !(0.0..=100.0).contains(&dropout_percent) {
                problems.push(format!(
                    "--dropout-percent must be 0 to 100, got {dropout_percent}"
                ));
            }
            if !(noise_mm.is_finite() && noise_mm >= 0.0) {
                problems.push(format!("--noise-mm must be zero or more, got {noise_mm}"));
            }
            if !(bvh_scale.is_finite() && bvh_scale > 0.0) {
                problems.push(format!("--bvh-scale must be positive, got {bvh_scale}"));
            }
            if let Some(character) = solve {
                if start != 0.0 {
                    problems.push("--start shapes what --to sends; with --solve the recording plays from its first frame (--end stops it early)".into());
                }
                if !problems.is_empty() {
                    bail!("{}", problems.join("\n"));
                }
                let cfg =
                    solve_stage(&file, &character, method, stream, speed, looping, bvh_scale)?;
                return live::run(
                    &cfg,
                    std::path::Path::new("."),
                    &live::RunOptions {
                        // The recording's seconds at this speed.
                        seconds: end.map(|e| e / speed),
                        json,
                        record: None,
                        rerun,
                    },
                );
            }
            let to = to.expect("clap requires --to without --solve");
            let target = rigless::input::parse_url(&to)
                .and_then(|u| Target::from_url(&u))
                .map_err(|e| problems.push(e))
                .ok();
            if !problems.is_empty() {
                bail!("{}", problems.join("\n"));
            }
            let target = target.expect("checked above");
            if let Target::NatNet { data, command } = &target {
                match command {
                    Some(c) => eprintln!("serving NatNet 3.0 frames to {data}; command port {c} (clients: natnet://{data}?server={c})"),
                    None => eprintln!("sending NatNet 3.0 frames to {data} (markers named replay_1, replay_2...; add ?server=IP:PORT for a command port that names them)"),
                }
            }
            if let Target::Vrpn { device, bind } = &target {
                eprintln!("serving {device} as a VRPN tracker on TCP and UDP {bind} (clients: {device}@{bind} or {device}@tcp://{bind})");
            }
            let rec = rigless::replay::recording::Recording::load_with(&file, bvh_scale)?;
            let subset: Option<Vec<String>> =
                markers.map(|m| m.split(',').map(|s| s.trim().to_owned()).collect());
            if let Some(sub) = &subset {
                let unknown: Vec<&String> =
                    sub.iter().filter(|m| !rec.labels.contains(m)).collect();
                if !unknown.is_empty() {
                    bail!(
                        "{}: no such labels: {:?} (it has {})",
                        file.display(),
                        unknown,
                        rec.labels.join(", ")
                    );
                }
            }
            let opts = ReplayOptions {
                speed,
                looping,
                start_s: start,
                end_s: end,
                markers: subset,
                dropout: dropout_percent / 100.0,
                noise_m: noise_mm * 1e-3,
                seed,
            };
            if !json {
                eprintln!(
                    "replaying {} ({} markers, {} frames at {} Hz) to {to}{}",
                    file.display(),
                    rec.labels.len(),
                    rec.frames.len(),
                    rec.rate_hz,
                    if looping {
                        ", looping; Ctrl-C stops"
                    } else {
                        ""
                    }
                );
            }
            let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            {
                let stop = std::sync::Arc::clone(&stop);
                std::thread::spawn(move || {
                    if let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                        .enable_all()
                        .build()
                    {
                        if rt.block_on(tokio::signal::ctrl_c()).is_ok() {
                            stop.store(true, std::sync::atomic::Ordering::Relaxed);
                        }
                    }
                });
            }
            let clock = rigless::daemon::clock::SystemClock::new();
            let stats = replay(&rec, target, &opts, &clock, 0.01, &stop)
                .with_context(|| format!("sending to {to}"))?;
            if json {
                println!("{}", serde_json::to_string(&stats)?);
            } else {
                println!(
                    "sent {} packets ({} bytes, {} errors, {} samples dropped on purpose); send-time jitter ms p50 {:.3} p99 {:.3} max {:.3}",
                    stats.packets, stats.bytes, stats.send_errors, stats.samples_dropped,
                    stats.jitter_ms_p50, stats.jitter_ms_p99, stats.jitter_ms_max
                );
            }
            Ok(())
        }
        Command::Info {
            file,
            json,
            bvh_scale,
        } => {
            if !(bvh_scale.is_finite() && bvh_scale > 0.0) {
                bail!("--bvh-scale must be a positive number of metres per unit, got {bvh_scale}");
            }
            let rec = rigless::replay::recording::Recording::load_with(&file, bvh_scale)?;
            let s = rec.summary();
            if json {
                println!("{}", serde_json::to_string(&s)?);
                return Ok(());
            }
            println!("{}", s.name);
            println!(
                "  {} markers, {} Hz, {} frames ({:.2} s), stored in {}, {:.1} % of samples missing",
                s.markers, s.rate_hz, s.frames, s.duration_secs, rec.file_units, s.gap_percent
            );
            if let (Some(lo), Some(hi)) = (s.bbox_min_m, s.bbox_max_m) {
                println!(
                    "  bounding box (m, Y up): x {:.3}..{:.3}, y {:.3}..{:.3}, z {:.3}..{:.3}",
                    lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
                );
            }
            for m in &s.per_marker {
                println!("  {:<32} {:>6.1} % missing", m.name, m.gap_percent);
            }
            for w in &s.warnings {
                println!("  warning: {w}");
            }
            Ok(())
        }
        Command::MakeSessions { dir } => {
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
            for spec in &rigless::replay::bundled::SPECS {
                let bytes = rigless::replay::bundled::generate(spec)?;
                let path = dir.join(format!("{}.c3d", spec.name));
                std::fs::write(&path, &bytes)
                    .with_context(|| format!("writing {}", path.display()))?;
                println!("wrote {} ({} bytes)", path.display(), bytes.len());
            }
            Ok(())
        }
        Command::Bake {
            character,
            force,
            json,
        } => bake(&character, force, json),
        Command::ExportHand { dir } => {
            let path = rigless::character::file::write_character_files(
                &characters::demo_hand(),
                Some(&characters::hand_bind_params()),
                &dir,
            )
            .with_context(|| format!("writing the hand into {}", dir.display()))?;
            println!(
                "wrote {} and its mesh; try: rigless bake {}",
                path.display(),
                path.display()
            );
            Ok(())
        }
        Command::Bench {
            suite: Suite::Capsules,
            json,
            data,
            ..
        } => bench_capsules(&data, json),
        Command::Bench {
            suite: Suite::Characters,
            json,
            ..
        } => bench_characters(json),
        Command::Bench {
            suite: Suite::Gapfill,
            json,
            data,
            ..
        } => bench_gapfill(&data, json),
        Command::Bench {
            suite: Suite::Codecs,
            json,
            ..
        } => {
            for r in rigless::bench::codecs::run() {
                if json {
                    println!("{}", serde_json::to_string(&r)?);
                } else {
                    println!(
                        "{:<12} {:>3} markers {:>5} bytes  decode µs median {:.2} (p10 {:.2}, p90 {:.2})",
                        r.codec, r.markers, r.packet_bytes, r.decode_us_median, r.decode_us_p10, r.decode_us_p90
                    );
                }
            }
            Ok(())
        }
        Command::Bench {
            suite: Suite::Replay,
            json,
            seconds,
            ..
        } => {
            use rigless::replay::sender::{replay, ReplayOptions, Target};
            check_seconds(Some(seconds))?;
            let rec = rigless::replay::recording::Recording::from_c3d(
                "hand_finger_play",
                rigless::replay::bundled::bundled("hand_finger_play").expect("bundled"),
            )?;
            // A receiving socket that reads nothing: the kernel drops what overflows.
            let sink = std::net::UdpSocket::bind("127.0.0.1:0")?;
            let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
            {
                let stop = std::sync::Arc::clone(&stop);
                std::thread::spawn(move || {
                    std::thread::sleep(std::time::Duration::from_secs_f64(seconds));
                    stop.store(true, std::sync::atomic::Ordering::Relaxed);
                });
            }
            let opts = ReplayOptions {
                looping: true,
                ..ReplayOptions::default()
            };
            let clock = rigless::daemon::clock::SystemClock::new();
            let st = replay(
                &rec,
                Target::Osc(sink.local_addr()?),
                &opts,
                &clock,
                0.01,
                &stop,
            )?;
            if json {
                println!(
                    "{}",
                    serde_json::json!({"suite": "replay", "rate_hz": rec.rate_hz, "seconds": seconds, "stats": st})
                );
            } else {
                println!(
                    "replay at {} Hz for {seconds} s: {} packets; send-time jitter ms p50 {:.3} p99 {:.3} max {:.3}",
                    rec.rate_hz, st.packets, st.jitter_ms_p50, st.jitter_ms_p99, st.jitter_ms_max
                );
            }
            Ok(())
        }
        Command::Bench {
            suite: Suite::Live,
            json,
            seconds,
            ..
        } => {
            check_seconds(Some(seconds))?;
            bench_live(seconds, json)
        }
    }
}

fn bake(path: &std::path::Path, force: bool, json: bool) -> Result<()> {
    use rigless::character::file::load_character;
    let t0 = std::time::Instant::now();
    let loaded = load_character(path)?;
    let ch = &loaded.character;
    let read_s = t0.elapsed().as_secs_f64();
    let (rig, source) = load_or_bind(path, &loaded, force, json)?;
    let s = &rig.stats;
    if json {
        println!(
            "{}",
            serde_json::json!({
                "character": ch.name,
                "mesh_vertices": ch.vertices.len(),
                "triangles": ch.triangles.len(),
                "joints": ch.skeleton.len(),
                "markers": ch.markers.len(),
                "height_m": rig.height_m,
                "stats": s,
                "cache": source,
            })
        );
        return Ok(());
    }
    println!(
        "character      {}: {} mesh vertices, {} triangles, {} joints, {} markers, {:.3} m tall (read in {read_s:.3} s)",
        ch.name,
        ch.vertices.len(),
        ch.triangles.len(),
        ch.skeleton.len(),
        ch.markers.len(),
        rig.height_m
    );
    println!(
        "control mesh   {} vertices, {} tets ({} cells, {} duplicated for separate parts), smallest dihedral {:.1}°, clamped weights {}",
        s.control_vertices, s.control_tets, s.cell_instances, s.duplicated_cells, s.min_dihedral_deg, s.clamped_weights
    );
    println!(
        "mesh in cage   {} of {} vertices inside the control mesh; Green coordinates rest error {:.1e} m, {} barycentric fallbacks",
        s.mesh_vertices_inside, s.mesh_vertices, s.green_max_rest_error_m, s.green_fallback_vertices
    );
    if s.mesh_vertices_inside < s.mesh_vertices {
        println!(
            "warning        {} mesh vertices lie outside their control tet",
            s.mesh_vertices - s.mesh_vertices_inside
        );
    }
    println!(
        "stages         lattice {:.3} s, Green coordinates {:.3} s, weights + factorization {:.3} s",
        s.seconds_lattice, s.seconds_green, s.seconds_weights_factor
    );
    println!("cache          {source}");
    Ok(())
}

fn bench_characters(json: bool) -> Result<()> {
    use characters::{
        body_bind_params, demo_body, demo_hand, hand_bind_params, run_character, CharacterRun,
        Motion,
    };
    use rigless::character::body::BodyMotion;
    use rigless::solve::frame::{Method, SolverParams};
    use rigless::solve::harmonic::HarmonicParams;
    let run = CharacterRun {
        seconds: 10.0,
        rate_hz: 120.0,
        noise_m: 0.0,
        frame_budget_s: 1.0 / 120.0,
    };
    let hand = demo_hand();
    let body = demo_body();
    // The body at about 50,000 triangles (25,000 vertices): the harmonic method's second
    // target.
    let body50k = rigless::character::body::body(0.006, 50_000);
    // Frame p99 targets (ms) of the two methods; the harmonic method's is the body's.
    let cases = [
        (&hand, hand_bind_params(), Motion::FingerPlay, 1.0, None),
        (
            &body,
            body_bind_params(),
            Motion::Body(BodyMotion::Walk),
            4.0,
            Some(3.0),
        ),
        (
            &body,
            body_bind_params(),
            Motion::Body(BodyMotion::Reach),
            4.0,
            Some(3.0),
        ),
        (
            &body50k,
            body_bind_params(),
            Motion::Body(BodyMotion::Walk),
            f64::NAN,
            Some(15.0),
        ),
    ];
    if !json {
        println!(
            "{:<9} {:<6} {:<12} {:>6} {:>5} {:>9} {:>9} {:>6} {:>8} {:>8} {:>8} {:>7} {:>7} {:>5} {:>8}",
            "method",
            "char",
            "motion",
            "verts",
            "n",
            "p50 ms",
            "p99 ms",
            "iters",
            "bone_err",
            "limit°",
            "res mm",
            "vol",
            "gt %",
            "inv",
            "target"
        );
    }
    for (ch, bind, motion, arap_target_ms, harmonic_target_ms) in cases {
        for (method, target_ms) in [
            (Method::Arap, Some(arap_target_ms).filter(|t| t.is_finite())),
            (
                Method::Harmonic(HarmonicParams::default()),
                harmonic_target_ms,
            ),
        ] {
            let params = SolverParams {
                method,
                ..SolverParams::default()
            };
            let rec = run_character(ch, &bind, params, motion, run, |_, _| {})
                .with_context(|| format!("running the procedural {}", ch.name))?;
            if json {
                println!("{}", serde_json::to_string(&rec)?);
                continue;
            }
            // The harmonic method has no control mesh: no iterations, no sampled bones
            // (the posture's are rigid), no tets.
            let arap = rec.method == "arap";
            let na = |v: String| if arap { v } else { "-".into() };
            println!(
                "{:<9} {:<6} {:<12} {:>6} {:>5} {:>9.3} {:>9.3} {:>6} {:>8} {:>8.3} {:>8.2} {:>7.3} {:>7.2} {:>5} {:>8}",
                rec.method,
                rec.character,
                rec.motion,
                rec.mesh_vertices,
                na(rec.n.to_string()),
                rec.frame_ms_p50,
                rec.frame_ms_p99,
                na(format!("{:.2}", rec.iterations_mean)),
                na(format!("{:.4}", rec.bone_length_error_mean)),
                rec.joint_limit_violation_deg_max,
                rec.marker_residual_mm_rms,
                rec.volume_error_mean,
                rec.gt_vertex_error_mean * 100.0,
                na(rec.inverted_tets_max.to_string()),
                target_ms.map_or("-".into(), |t| format!("p99≤{t}"))
            );
        }
    }
    Ok(())
}

fn bench_capsules(data: &std::path::Path, json: bool) -> Result<()> {
    let dir = data.join("tetmesh");
    if !dir.is_dir() {
        bail!(
            "{} not found: the capsules suite needs the shared benchmark meshes (pass --data DIR)",
            dir.display()
        );
    }
    if !json {
        println!(
            "{:<20} {:>6} {:>7} {:>7} {:>9} {:>12} {:>10} {:>10} {:>12} {:>9} {:>8}",
            "mesh",
            "n",
            "tets",
            "clamped",
            "factor_s",
            "iter_ms p50",
            "p10",
            "p90",
            "libigl_ms",
            "target",
            "inverted"
        );
    }
    for (file, _, _, _) in capsules::CASES {
        let path = dir.join(file);
        let rec = capsules::run_case(&path, 10, capsules::timed_iters_for(file))
            .with_context(|| format!("benchmarking {}", path.display()))?;
        if json {
            println!("{}", serde_json::to_string(&rec)?);
        } else {
            println!(
                "{:<20} {:>6} {:>7} {:>7} {:>9.3} {:>12.3} {:>10.3} {:>10.3} {:>5.2}-{:<6.2} {:>9.2} {:>8}",
                rec.mesh,
                rec.n,
                rec.tets,
                rec.clamped_weights,
                rec.factor_s,
                rec.per_iter_ms_median,
                rec.per_iter_ms_p10,
                rec.per_iter_ms_p90,
                rec.libigl_ms_low,
                rec.libigl_ms_high,
                rec.target_ms,
                rec.inverted_tets
            );
        }
    }
    Ok(())
}

fn bench_gapfill(data: &std::path::Path, json: bool) -> Result<()> {
    use rigless::bench::gapfill::{measure, Trajectories};
    use rigless::character::body::BodyMotion;
    use rigless::character::demo::{demo_body, demo_hand, Motion};
    use rigless::input::synthetic::{SyntheticParams, SyntheticSession};
    use rigless::markers::buffer::BufferConfig;
    use std::sync::Arc;
    const GAPS_S: [f64; 7] = [0.01, 0.025, 0.05, 0.1, 0.2, 0.5, 1.0];
    let mut sets = Vec::new();
    for (ch, motion) in [
        (demo_hand(), Motion::FingerPlay),
        (demo_body(), Motion::Body(BodyMotion::Walk)),
    ] {
        let segment = ch.markers.iter().map(|m| m.joint.unwrap_or(0)).collect();
        let rest = ch.markers.iter().map(|m| m.rest).collect();
        let name = format!("synthetic {} {}", ch.name, motion.name());
        let mut s = SyntheticSession::new(
            Arc::new(ch),
            motion,
            SyntheticParams {
                duration_secs: 30.0,
                gap_fraction: 0.0,
                noise_m: 0.0005,
                ..SyntheticParams::default()
            },
        );
        let mut frames = Vec::new();
        let mut batch = Vec::new();
        for i in 0..s.frames() {
            batch.clear();
            s.frame(i, 0.0, &mut batch);
            frames.push(batch.iter().map(|m| m.position_m).collect());
        }
        sets.push(Trajectories {
            name,
            rate_hz: s.params().rate_hz,
            frames,
            segment,
            rest,
        });
    }
    let tsv = data.join("hand/dfki_hand_recording.tsv");
    match std::fs::read_to_string(&tsv) {
        Ok(text) => {
            let r = rigless::replay::tsv::parse_tsv(&text)
                .with_context(|| format!("reading {}", tsv.display()))?;
            // Rigid groups by name prefix (hand_, back_, pillow_, ...).
            let mut groups: Vec<String> = Vec::new();
            let segment = r
                .marker_names
                .iter()
                .map(|n| {
                    let g = n.split('_').next().unwrap_or(n).to_owned();
                    groups.iter().position(|x| *x == g).unwrap_or_else(|| {
                        groups.push(g);
                        groups.len() - 1
                    })
                })
                .collect();
            let rest = r
                .frames
                .iter()
                .find(|f| f.iter().all(|p| p.is_finite()))
                .cloned()
                .unwrap_or_else(|| vec![glam::DVec3::ZERO; r.marker_names.len()]);
            sets.push(Trajectories {
                name: "dfki_hand_recording.tsv".into(),
                rate_hz: r.rate_hz,
                frames: r.frames,
                segment,
                rest,
            });
        }
        Err(e) => eprintln!("skipping the real hand recording: {}: {e}", tsv.display()),
    }
    // BTS: 22 gait markers with half the samples missing; no rigid clusters, so every
    // marker is its own segment (prediction only).
    let bts = data.join("c3d/BTS.c3d");
    match std::fs::read(&bts) {
        Ok(bytes) => {
            let c = rigless::replay::c3d::read_c3d(&bytes)
                .with_context(|| format!("reading {}", bts.display()))?;
            let n = c.labels.len();
            let mut rest = vec![glam::DVec3::ZERO; n];
            for (k, r) in rest.iter_mut().enumerate() {
                if let Some(p) = c.frames.iter().map(|f| f[k]).find(|p| p.is_finite()) {
                    *r = p;
                }
            }
            sets.push(Trajectories {
                name: "BTS.c3d".into(),
                rate_hz: c.rate_hz,
                frames: c.frames,
                segment: (0..n).collect(),
                rest,
            });
        }
        Err(e) => eprintln!("skipping BTS.c3d: {}: {e}", bts.display()),
    }
    if !json {
        println!(
            "{:<34} {:>7} {:>6} {:>9} {:>8} {:>10} {:>9} {:>9} {:>6} {:>6} {:>6}",
            "recording",
            "gap_ms",
            "gaps",
            "mean_mm",
            "p95_mm",
            "predict_mm",
            "rigid_mm",
            "held_mm",
            "pred%",
            "rigid%",
            "held%"
        );
    }
    for tr in &sets {
        for r in measure(tr, &BufferConfig::default(), &GAPS_S, 1.0) {
            if json {
                println!("{}", serde_json::to_string(&r)?);
            } else {
                println!(
                    "{:<34} {:>7.0} {:>6} {:>9.2} {:>8.2} {:>10.2} {:>9.2} {:>9.2} {:>6.1} {:>6.1} {:>6.1}",
                    r.recording, r.gap_ms, r.gaps, r.error_mm_mean, r.error_mm_p95, r.predicted_mm_mean,
                    r.rigid_mm_mean, r.held_mm_mean, 100.0 * r.predicted_share, 100.0 * r.rigid_share,
                    100.0 * r.held_share
                );
            }
        }
    }
    Ok(())
}

/// The bound rig of a loaded character file: from its bake cache when current (and not
/// `force`), else bound (with a progress bar unless `quiet`) and cached. Returns the rig
/// and a line saying which.
pub fn load_or_bind(
    path: &std::path::Path,
    loaded: &rigless::character::file::LoadedCharacter,
    force: bool,
    quiet: bool,
) -> Result<(rigless::rig::bind::Rig, String)> {
    use rigless::rig::bind::{BindStage, Rig};
    use rigless::rig::cache;
    use std::io::Write;
    let json = quiet;
    let ch = &loaded.character;
    let cache_file = cache::cache_path(path);
    let t1 = std::time::Instant::now();
    let (rig, source) = match (force, cache::load(path, loaded.inputs_hash)) {
        (false, Ok(rig)) => (
            rig,
            format!(
                "loaded {} in {:.3} s",
                cache_file.display(),
                t1.elapsed().as_secs_f64()
            ),
        ),
        (_, cached) => {
            let why = match cached {
                Ok(_) => "--force".to_string(),
                Err(miss) => miss.to_string(),
            };
            let mut last = (None, -1i64);
            let rig = Rig::bind_with_progress(ch, &loaded.bind, &mut |stage, f| {
                let pct = (f * 100.0) as i64;
                if json || (Some(stage), pct / 5) == (last.0, last.1 / 5) {
                    return;
                }
                last = (Some(stage), pct);
                let name = match stage {
                    BindStage::Lattice => "lattice and binding",
                    BindStage::GreenCoordinates => "Green coordinates",
                    BindStage::Factorization => "weights and factorization",
                };
                let bar: String = (0..20)
                    .map(|k| if k < pct / 5 { '#' } else { '.' })
                    .collect();
                eprint!("\r  binding [{bar}] {name:<26} {pct:>3}%");
                let _ = std::io::stderr().flush();
            })
            .with_context(|| format!("binding {}", path.display()))?;
            if !json {
                eprintln!("\r  binding [####################] done{:<30}", "");
            }
            let written = cache::store(path, &rig, loaded.inputs_hash)?;
            (rig, format!("bound ({why}); wrote {}", written.display()))
        }
    };
    Ok((rig, source))
}

fn check_seconds(seconds: Option<f64>) -> Result<()> {
    match seconds {
        Some(s) if !(s.is_finite() && s > 0.0) => {
            bail!("--seconds must be a positive number of seconds, got {s}")
        }
        _ => Ok(()),
    }
}

fn bench_live(seconds: f64, json: bool) -> Result<()> {
    use rigless::bench::live::{run_live, LiveCase};
    use rigless::character::demo::{demo_hand, hand_bind_params, Motion};
    use rigless::rig::bind::Rig;
    use std::sync::Arc;
    let ch = Arc::new(demo_hand());
    let rig = Arc::new(Rig::bind(&ch, &hand_bind_params()).context("binding the hand")?);
    if !json {
        println!(
            "{:<6} {:>6} {:>8} {:>7} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} rerun logged/skipped",
            "char",
            "rate",
            "clients",
            "frames",
            "overrun",
            "solve p50",
            "solve p99",
            "wait p99",
            "lat p50",
            "lat p99",
            "over p50",
            "over p99",
            "rss MiB"
        );
    }
    let rrd_dir = tempfile_dir()?;
    let rrd = rrd_dir.join("bench-live.rrd");
    // (rate, readers besides the measuring client, silent clients, a Rerun sink saving
    // every frame: the same case with and without it shows what logging costs the solver)
    for (rate, readers, silent, rerun) in [
        (120.0, 0, 0, false),
        (120.0, 0, 0, true),
        (240.0, 0, 0, false),
        (120.0, 48, 1, false),
    ] {
        let r = run_live(
            Arc::clone(&rig),
            Arc::clone(&ch),
            Motion::FingerPlay,
            &LiveCase {
                rate_hz: rate,
                seconds,
                readers,
                silent,
                rerun_file: rerun.then(|| rrd.clone()),
            },
        )?;
        if json {
            println!("{}", serde_json::to_string(&r)?);
        } else {
            println!(
                "{:<6} {:>6.0} {:>8} {:>7} {:>8} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>5.0}->{:<5.0} {}",
                r.character, r.rate_hz, r.clients, r.frames, r.overruns, r.solve_ms_p50, r.solve_ms_p99,
                r.wait_ms_p99, r.latency_ms_p50, r.latency_ms_p99, r.overhead_ms_p50, r.overhead_ms_p99,
                r.rss_start_mib, r.rss_end_mib,
                if r.rerun { format!("{}/{}", r.rerun_frames_logged, r.rerun_frames_skipped) } else { "-".into() }
            );
        }
    }
    let _ = std::fs::remove_dir_all(&rrd_dir);
    Ok(())
}

/// A fresh folder under the system's temporary directory, for benchmark outputs.
fn tempfile_dir() -> Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("rigless-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}

fn listen(
    url: &str,
    json: bool,
    seconds: Option<f64>,
    packets: Option<u64>,
    scale: f64,
    z_up: bool,
) -> Result<()> {
    use rigless::input::{parse_url, InputUrl};
    use rigless::protocol::osc::OscMapping;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    if !(scale.is_finite() && scale > 0.0) {
        bail!("--scale must be a positive number of metres per unit, got {scale}");
    }
    let parsed = parse_url(url).map_err(anyhow::Error::msg)?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            if let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
            {
                if rt.block_on(tokio::signal::ctrl_c()).is_ok() {
                    stop.store(true, Ordering::Relaxed);
                }
            }
        });
    }
    if let Some(s) = seconds {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(s));
            stop.store(true, Ordering::Relaxed);
        });
    }
    // One printed line per decoded packet.
    let mut seen = 0u64;
    let mut out = std::io::stdout().lock();
    let mut write_err = None;
    let mut print = |recv: f64,
                     src: Option<f64>,
                     frame: Option<i64>,
                     ms: &[(&str, glam::DVec3, bool)],
                     extra: Option<(&str, serde_json::Value)>| {
        use std::io::Write;
        let line = if json {
            let mut v = serde_json::json!({
                "receive_unix_s": recv,
                "source_time_s": src,
                "frame": frame,
                "markers": ms.iter().map(|(name, p, occluded)| serde_json::json!({
                    "name": name,
                    "position_m": if *occluded { serde_json::Value::Null } else { serde_json::json!(p.to_array()) },
                    "occluded": occluded,
                })).collect::<Vec<_>>(),
            });
            if let Some((key, value)) = extra {
                v[key] = value;
            }
            v.to_string()
        } else if let Some((key, value)) = extra {
            format!("recv {recv:.6}  {key} {value}")
        } else {
            let text: Vec<String> = ms
                .iter()
                .map(|(name, p, occluded)| {
                    if *occluded {
                        format!("{name} occluded")
                    } else {
                        format!("{name} ({:.4}, {:.4}, {:.4})", p.x, p.y, p.z)
                    }
                })
                .collect();
            format!(
                "recv {recv:.6}  source {}  frame {}  {} markers: {}",
                src.map_or("-".into(), |t| format!("{t:.6}")),
                frame.map_or("-".into(), |n| n.to_string()),
                ms.len(),
                text.join(", ")
            )
        };
        if let Err(e) = writeln!(out, "{line}").and_then(|_| out.flush()) {
            write_err = Some(e);
            stop.store(true, Ordering::Relaxed);
        }
        seen += 1;
        if packets.is_some_and(|n| seen >= n) {
            stop.store(true, Ordering::Relaxed);
        }
    };
    let summary = match parsed {
        InputUrl::Osc(addr) | InputUrl::Vmc(addr) => {
            use rigless::input::osc::{bind, run, OscStats};
            let mapping = if matches!(parsed, InputUrl::Vmc(_)) {
                OscMapping {
                    patterns: Vec::new(),
                    ..OscMapping::default()
                }
            } else {
                OscMapping {
                    scale,
                    z_up,
                    ..OscMapping::default()
                }
            };
            let sock = bind(addr).with_context(|| format!("binding {addr}"))?;
            eprintln!(
                "listening on {url} (bound {}); Ctrl-C stops",
                sock.local_addr()?
            );
            let stats = OscStats::default();
            run(&sock, &mapping, &stop, &stats, &mut |recv, f| {
                let ms: Vec<(&str, glam::DVec3, bool)> = f
                    .markers()
                    .iter()
                    .map(|m| (m.name.as_str(), m.position_m, m.occluded))
                    .collect();
                print(recv, f.source_time_s(), f.frame, &ms, None)
            });
            stats.to_string()
        }
        InputUrl::Vrpn { device, addr, mode } => {
            use rigless::input::vrpn::{run_mode, sensor_name, VrpnMode, VrpnStats};
            match mode {
                VrpnMode::Tcp => eprintln!(
                    "connecting to {addr} for {device} (reconnects by itself); Ctrl-C stops"
                ),
                VrpnMode::Udp => eprintln!(
                    "asking {addr} (UDP) to call back for {device} (asks again after a drop); Ctrl-C stops"
                ),
            }
            let stats = VrpnStats::default();
            run_mode(
                mode,
                addr,
                &device,
                &stop,
                &stats,
                &mut |recv, source, r| {
                    let name = sensor_name(&device, r.sensor);
                    print(
                        recv,
                        Some(source),
                        None,
                        &[(name.as_str(), r.position, false)],
                        None,
                    )
                },
            );
            format!(
                "{} connections, {} messages, {} bytes, {} reports, {} pings answered, {} errors, {} datagrams ({} bad)",
                stats.connections.load(Ordering::Relaxed),
                stats.messages.load(Ordering::Relaxed),
                stats.bytes.load(Ordering::Relaxed),
                stats.reports.load(Ordering::Relaxed),
                stats.pings_answered.load(Ordering::Relaxed),
                stats.errors.load(Ordering::Relaxed),
                stats.datagrams.load(Ordering::Relaxed),
                stats.bad_datagrams.load(Ordering::Relaxed)
            )
        }
        InputUrl::Glove(port) => {
            use rigless::input::glove::{
                default_finger_joints, run, FingerCalibration, GloveStats, HandMap,
            };
            use rigless::protocol::glove::buttons;
            // Joint positions on the procedural hand, wrist at rest, full-scale calibration.
            let hand = rigless::character::demo::demo_hand();
            let sk = &hand.skeleton;
            let cal = [FingerCalibration {
                open: 0,
                closed: port.max_value,
            }; 5];
            let map = HandMap::new(sk, &default_finger_joints(), cal, port.max_value)
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            let shown: Vec<usize> = map
                .joints()
                .iter()
                .flat_map(|f| [f[0], f[1], f[2], f[2] + 1])
                .filter(|&j| j < sk.len())
                .collect();
            let mut local = vec![glam::DQuat::IDENTITY; sk.len()];
            let (mut wr, mut wp) = (local.clone(), vec![glam::DVec3::ZERO; sk.len()]);
            eprintln!(
                "reading {} ({} baud, {:?}, full scale {}; reopens by itself); Ctrl-C stops",
                port.path.display(),
                port.baud,
                port.format,
                port.max_value
            );
            let stats = GloveStats::default();
            let max = f64::from(port.max_value);
            run(&port, &stop, &stats, &mut |recv, r| {
                map.local_rotations(r, &mut local);
                sk.forward(&local, glam::DVec3::ZERO, &mut wr, &mut wp);
                let ms: Vec<(&str, glam::DVec3, bool)> = shown
                    .iter()
                    .map(|&j| (sk.joints[j].name.as_str(), wp[j], false))
                    .collect();
                let frac = |v: &[Option<u32>]| -> Vec<Option<f64>> {
                    v.iter().map(|x| x.map(|x| f64::from(x) / max)).collect()
                };
                let pressed: Vec<&str> = (0..8)
                    .filter(|b| r.buttons & (1 << b) != 0)
                    .map(|b| buttons::NAMES[b])
                    .collect();
                let glove = serde_json::json!({
                    "curl": frac(&r.curl),
                    "splay": frac(&r.splay),
                    "joystick": frac(&r.joystick),
                    "trigger": r.trigger.map(|x| f64::from(x) / max),
                    "buttons": pressed,
                });
                print(recv, None, None, &ms, Some(("glove", glove)))
            });
            stats.to_string()
        }
        InputUrl::NatNet(addr, version, server) => {
            use rigless::input::natnet::{bind, markers_of, run_input, NatNetStats};
            let sock = bind(addr).with_context(|| format!("binding {addr}"))?;
            eprintln!(
                "listening on {url} (bound {}, NatNet {}.{}); Ctrl-C stops",
                sock.local_addr()?,
                version.0,
                version.1
            );
            let stats = NatNetStats::default();
            let mut named = Vec::new();
            if let Some(server) = server {
                eprintln!("talking to the NatNet server's command port {server}: version and marker names from it");
            }
            run_input(
                &sock,
                addr,
                version,
                server,
                &stop,
                &stats,
                &mut |recv, f, names| {
                    named.clear();
                    markers_of(f, names, &mut named);
                    let ms: Vec<(&str, glam::DVec3, bool)> = named
                        .iter()
                        .map(|m| (m.name.as_str(), m.position_m, m.occluded))
                        .collect();
                    print(recv, Some(f.timestamp_s), Some(f.frame as i64), &ms, None)
                },
            )
            .with_context(|| format!("opening a command socket for {url}"))?;
            format!(
                "{}; {} frames, {} other messages",
                stats.packets,
                stats.frames.load(Ordering::Relaxed),
                stats.other.load(Ordering::Relaxed)
            )
        }
    };
    if let Some(e) = write_err {
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            return Err(e.into());
        }
    }
    eprintln!("{summary}");
    Ok(())
}
