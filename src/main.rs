//! The `rigless` command line: parses the arguments and calls the command's file in
//! `cli/` (which prints and decides the exit code); the work is the library's.

use clap::{Parser, Subcommand};

mod cli;

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
    /// solver, the outputs; every key is documented in stages/hand.toml): bind the
    /// character (or load its bake cache), start the inputs and the solver thread, serve
    /// the vertex stream, print a status line every second, and run until the inputs end,
    /// --seconds pass, or Ctrl-C (clients are told goodbye).
    Run(cli::run::RunArgs),
    /// Replay a bundled session of a procedural character live (the default demo).
    ///
    /// Play a bundled recorded session of a procedural character (the hand's finger play
    /// by default, or the body's walk or reach; 0.5 mm noise and 5 % of samples lost in
    /// occlusion gaps, see replay/README.md) live through the whole pipeline, in real
    /// time: the marker buffer fills the gaps, the solver thread solves every frame at
    /// 120 Hz, and the vertex stream serves the deformed mesh (see
    /// protocols/vertex-stream.md). Prints a status line every second and a summary at
    /// the end; stops at the end of the session, after --seconds, or on Ctrl-C.
    Demo(cli::demo::DemoArgs),
    /// Bind a character file and cache the result.
    ///
    /// Bind a character: read its TOML file and mesh, build the control mesh, the Green
    /// coordinates and the factorization, print a summary, and cache the result next to
    /// the character file (`NAME.rigcache`, keyed by a hash of the character file, the
    /// mesh file and this version) so the next start loads it instead of binding again.
    Bake(cli::bake::BakeArgs),
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
    Listen(cli::listen::ListenArgs),
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
    Replay(cli::replay::ReplayArgs),
    /// Place a take's markers on a character: bones, offsets and the actor's scale.
    ///
    /// Place a take's markers on a character: for every label of the take (C3D, TSV,
    /// BVH or session), the bone that carries it and its offset there, and the scale
    /// between actor and character, fitted over frames spread across the take (MoSh's
    /// first stage on the character's own skeleton). Labels find their bones through
    /// the character file's [[markers]], its [calibration.bones] globs, a built-in
    /// marker-set table (Plug-in Gait, CMU 41, ISB, Davis, Motive Baseline, the DFKI
    /// hand, the procedural characters'), or the motion itself. A take that starts in
    /// the character's rest pose (a range of motion) calibrates best. Prints a table with
    /// each label's misfit and a flag where it fits badly; --write stores the layout and
    /// the scale in the character file.
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Show what a recording holds.
    ///
    /// Show what a recording holds (C3D, Qualisys TSV, BVH or a session file): markers,
    /// rate, frames, duration, the file's units, the share of missing samples per marker,
    /// the bounding box (metres, Y up), and anything the reader had to tolerate.
    Info(cli::info::InfoArgs),
    /// Write the bundled sessions (C3D).
    ///
    /// Write the bundled sessions (the procedural hand's finger play, the body's walk,
    /// reach and range of motion, as C3D with noise and occlusion gaps) into a folder; `replay/` in the source
    /// tree holds exactly what this writes.
    MakeSessions(cli::make_sessions::MakeSessionsArgs),
    /// Write a procedural character (the hand or the body) as an example character.
    ///
    /// Write the procedural hand or body as a mesh (OBJ) and a character file (TOML)
    /// into a folder: a complete example of the character format to start from, ready
    /// for `rigless bake DIR/hand.toml`, and a file `rigless calibrate DIR/body.toml
    /// TAKE --write` can store a studio's marker layout in.
    ExportCharacter(cli::export_character::ExportCharacterArgs),
    /// The same as `export-character hand DIR`.
    #[command(hide = true)]
    ExportHand(cli::export_character::ExportHandArgs),
    /// Run a benchmark suite and print one line per case (a table, or JSON with --json).
    Bench(cli::bench::BenchArgs),
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let result = match Cli::parse().command {
        Command::Run(a) => cli::run::run(a),
        Command::Demo(a) => cli::demo::run(a),
        Command::Bake(a) => cli::bake::run(a),
        Command::Listen(a) => cli::listen::run(a),
        Command::Replay(a) => cli::replay::run(a),
        Command::Info(a) => cli::info::run(a),
        Command::Calibrate(a) => cli::calibrate::run(a),
        Command::MakeSessions(a) => cli::make_sessions::run(a),
        Command::ExportCharacter(a) => cli::export_character::run(a),
        Command::ExportHand(a) => cli::export_character::run_hand(a),
        Command::Bench(a) => cli::bench::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // The chain of causes, without a backtrace (these are user errors), each said
            // once: a cause that its parent's message already quotes is not repeated.
            let mut text = e.to_string();
            for cause in e.chain().skip(1).map(ToString::to_string) {
                if !text.contains(&cause) {
                    text = format!("{text}: {cause}");
                }
            }
            eprintln!("error: {text}");
            std::process::ExitCode::FAILURE
        }
    }
}
