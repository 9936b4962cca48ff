//! `rigless demo`: a bundled session of a procedural character played live through the
//! whole pipeline (the embedded default stage, with the flags applied).

use super::{check_seconds, run_stage, LiveOptions, ViewerFlag};
use anyhow::Result;
use clap::ValueEnum;
use rigless::output::rerun_sink::RerunTarget;
use std::net::SocketAddr;

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Which procedural character: the hand (8 markers, the default) or the body (36
    /// markers).
    #[arg(long, value_enum)]
    character: Option<DemoCharacter>,
    /// The body's motion (default: walk; the hand always plays its finger play).
    #[arg(long, value_enum)]
    motion: Option<DemoMotion>,
    /// How many performers: 1, or 2 for the bundled two-actor session (two bodies,
    /// `Ann:` and `Bob:` labels; Bob walks in 1.5 s late and passes 0.4 m from Ann),
    /// each driving its own body on the stream, the viewer and Rerun.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    actors: u8,
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
    stream: SocketAddr,
    /// The browser viewer: serve its page and the WebSocket stream at this address, or
    /// `off` (default: 127.0.0.1:7879, or
    /// a free port when that one is taken; the address is printed).
    #[arg(long, value_name = "ADDR|off")]
    viewer: Option<ViewerFlag>,
    /// Rerun: off, spawn (a viewer; without one on PATH, save rigless-CHARACTER.rrd and
    /// print how to open it), connect=HOST:PORT (a running viewer, gRPC port 9876 by
    /// default) or save=PATH.rrd.
    #[arg(long, value_name = "off|spawn|connect=ADDR|save=PATH")]
    rerun: Option<RerunTarget>,
    /// Print the status and the summary as JSON lines instead of text.
    #[arg(long)]
    json: bool,
}

/// The cast of the two-actor session (as `stages/two-actors.toml`).
const TWO_BODIES: &str = "[[actors]]\nname = \"Ann\"\nprocedural = \"body\"\nsubject = \"Ann\"\n\n[[actors]]\nname = \"Bob\"\nprocedural = \"body\"\nsubject = \"Bob\"\n";

/// A stage of one procedural character.
fn one(procedural: &str) -> String {
    format!("[character]\nprocedural = \"{procedural}\"\n")
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
enum DemoCharacter {
    Hand,
    Body,
}

#[derive(Clone, Copy, ValueEnum)]
enum DemoMotion {
    Walk,
    Reach,
    /// The range of motion: rest pose, then each group of joints bent and back.
    Rom,
}

pub fn run(a: DemoArgs) -> Result<()> {
    check_seconds(a.seconds)?;
    let motion = a.motion.unwrap_or(DemoMotion::Walk);
    let (cast, session) = match (a.actors, a.character.unwrap_or(DemoCharacter::Hand), motion) {
        (2, DemoCharacter::Hand, _) if a.character.is_some() => {
            anyhow::bail!("--actors 2 plays two bodies: leave out --character hand")
        }
        (2, _, DemoMotion::Walk) => (TWO_BODIES.to_owned(), "body_two_actors"),
        (2, _, _) => anyhow::bail!("--actors 2 plays a walk: leave out --motion"),
        (_, DemoCharacter::Hand, _) => (one("hand"), "hand_finger_play"),
        (_, DemoCharacter::Body, DemoMotion::Walk) => (one("body"), "body_walk"),
        (_, DemoCharacter::Body, DemoMotion::Reach) => (one("body"), "body_reach"),
        (_, DemoCharacter::Body, DemoMotion::Rom) => (one("body"), "body_rom"),
    };
    // The embedded default stage, with the flags applied; validated like a file.
    let text = format!(
        "{cast}\n[[inputs]]\ntype = \"replay\"\nsession = \"{session}\"\nspeed = {:?}\nloop = {}\n\n[outputs.stream]\ntcp = \"{}\"\n",
        a.speed, a.looping, a.stream
    );
    let cfg = rigless::config::parse_stage(&text, "demo flags")?;
    run_stage(
        cfg,
        std::path::Path::new("."),
        &LiveOptions {
            seconds: a.seconds,
            json: a.json,
            rerun: a.rerun,
            viewer: a.viewer,
        },
    )
}
