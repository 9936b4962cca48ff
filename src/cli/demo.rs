//! `rigless demo`: a bundled session of a procedural character played live through the
//! whole pipeline (the embedded default stage, with the flags applied).

use super::{check_seconds, run_stage, LiveOptions, ViewerFlag};
use anyhow::Result;
use clap::ValueEnum;
use rigless::output::rerun_sink::RerunTarget;
use std::net::SocketAddr;

#[derive(clap::Args)]
pub struct DemoArgs {
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

#[derive(Clone, Copy, ValueEnum)]
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
    let (procedural, session) = match (a.character, a.motion) {
        (DemoCharacter::Hand, _) => ("hand", "hand_finger_play"),
        (DemoCharacter::Body, DemoMotion::Walk) => ("body", "body_walk"),
        (DemoCharacter::Body, DemoMotion::Reach) => ("body", "body_reach"),
        (DemoCharacter::Body, DemoMotion::Rom) => ("body", "body_rom"),
    };
    // The embedded default stage, with the flags applied; validated like a file.
    let text = format!(
        "[character]\nprocedural = \"{procedural}\"\n\n[[inputs]]\ntype = \"replay\"\nsession = \"{session}\"\nspeed = {:?}\nloop = {}\n\n[outputs.stream]\ntcp = \"{}\"\n",
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
