//! `rigless run --config stage.toml`: the live daemon from a stage config.

use super::{check_seconds, run_stage, LiveOptions, ViewerFlag};
use anyhow::Result;
use rigless::output::rerun_sink::RerunTarget;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct RunArgs {
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
    /// Rerun: off, spawn (a viewer; without one on PATH, save rigless-CHARACTER.rrd and
    /// print how to open it), connect=HOST:PORT (a running viewer, gRPC port 9876 by
    /// default) or save=PATH.rrd. Overrides the stage's [outputs.rerun].
    #[arg(long, value_name = "off|spawn|connect=ADDR|save=PATH")]
    rerun: Option<RerunTarget>,
    /// The browser viewer: serve its page and the WebSocket stream at this address, or
    /// `off` (default: the stage's `[outputs.stream] websocket`, else 127.0.0.1:7879, or
    /// a free port when that one is taken; the address is printed).
    #[arg(long, value_name = "ADDR|off")]
    viewer: Option<ViewerFlag>,
    /// Print the status and the summary as JSON lines instead of text.
    #[arg(long)]
    json: bool,
}

pub fn run(a: RunArgs) -> Result<()> {
    check_seconds(a.seconds)?;
    let mut cfg = rigless::config::load_stage(&a.config)?;
    if a.check {
        println!("{}: ok", a.config.display());
        return Ok(());
    }
    let base = a.config.parent().unwrap_or(std::path::Path::new("."));
    if let Some(p) = a.record {
        // Relative to where the command runs, not to the stage's folder.
        cfg.recorder.path = Some(std::path::absolute(&p).unwrap_or(p));
    }
    run_stage(
        cfg,
        base,
        &LiveOptions {
            seconds: a.seconds,
            json: a.json,
            rerun: a.rerun,
            viewer: a.viewer,
        },
    )
}
