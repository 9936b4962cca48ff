//! `rigless bench --suite NAME`: runs a benchmark suite, a line per case.

use anyhow::Result;
use rigless::bench::{run_suite, BenchOptions, Suite};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct BenchArgs {
    /// Which suite: `capsules` (plain ARAP on the benchmark tet meshes of the shared data
    /// folder), `characters` (the procedural hand and body playing their motions, both
    /// methods; then the data folder's real assets, one subdivided to 157,070 vertices,
    /// through `bake --exercise`'s range of motion), `gapfill` (the marker buffer's fill error by gap length, on synthetic
    /// sessions and the shared data folder's recordings), `live` (the whole pipeline in
    /// real time: latency from input to client, missed ticks, Rerun on and off, 50
    /// clients), `codecs` (decode cost per packet of each input format, 50 markers),
    /// `replay` (send-time jitter of `rigless replay` at 120 Hz against the file's
    /// clock), `calibration` (`rigless calibrate` on known truth and on the data
    /// folder's takes and assets: time, scale and offset errors, misfit), `export`,
    /// `truth`, or `actors` (1, 2, 4 and 8 bodies at 120 Hz on every core and on one,
    /// per actor frame times and missed ticks; a label swap between two bodies 0.3 m
    /// apart with the identity gate and without; two real takes in one).
    #[arg(long, value_enum, default_value_t = Suite::Capsules)]
    suite: Suite,
    /// Print one JSON object per line instead of a table.
    #[arg(long)]
    json: bool,
    /// The shared data folder (holds `tetmesh/`, `hand/`, `c3d/`, `meshes/`).
    #[arg(long, default_value = "../shared/data")]
    data: PathBuf,
    /// Seconds per case of the `live`, `replay` and `actors` suites.
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
}

pub fn run(a: BenchArgs) -> Result<()> {
    super::check_seconds(Some(a.seconds))?;
    // Piped into `head`, a benchmark ends quietly like any Unix filter instead of
    // panicking on the closed pipe. (Its sockets are TCP, whose sends carry
    // MSG_NOSIGNAL, so only stdout is concerned.)
    // SAFETY: restoring the default disposition of a signal; no handler is installed.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let opts = BenchOptions {
        data: a.data,
        seconds: a.seconds,
        json: a.json,
    };
    run_suite(a.suite, &opts, &mut std::io::stdout().lock())?;
    Ok(())
}
