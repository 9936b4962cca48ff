//! The `rigless` command line: the only place that prints to the user and exits.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use rigless::bench::{capsules, characters};
use std::path::PathBuf;

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
    /// Play the procedural hand's finger-play motion through the solver and print per-frame
    /// figures (iterations, how the frame stopped, rrms, bone length error, marker
    /// residual, solve time), then the session's summary against the known truth.
    Demo {
        /// Seconds of motion to play (at 120 Hz).
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// Print every Nth frame.
        #[arg(long, default_value_t = 12)]
        every: usize,
        /// Uniform marker noise amplitude in millimetres.
        #[arg(long, default_value_t = 0.0)]
        noise_mm: f64,
    },
    /// Run a benchmark suite and print one line per case (a table, or JSON with --json).
    Bench {
        /// Which suite: `capsules` (plain ARAP on the benchmark tet meshes of the shared
        /// data folder) or `characters` (the procedural hand and body playing their motions).
        #[arg(long, value_enum, default_value_t = Suite::Capsules)]
        suite: Suite,
        /// Print one JSON object per line instead of a table.
        #[arg(long)]
        json: bool,
        /// The shared data folder (holds `tetmesh/`).
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum Suite {
    Capsules,
    Characters,
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Command::Demo {
            seconds,
            every,
            noise_mm,
        } => demo(seconds, every.max(1), noise_mm),
        Command::Bench {
            suite: Suite::Capsules,
            json,
            data,
        } => bench_capsules(&data, json),
        Command::Bench {
            suite: Suite::Characters,
            json,
            ..
        } => bench_characters(json),
    }
}

fn demo(seconds: f64, every: usize, noise_mm: f64) -> Result<()> {
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds, got {seconds}");
    }
    println!("procedural hand, finger play, 120 Hz, {seconds} s (binding...)");
    println!(
        "{:>6} {:>5} {:>13} {:>8} {:>9} {:>11} {:>9}",
        "frame", "iters", "stop", "rrms", "bone_err", "marker_mm", "solve_ms"
    );
    let rec = characters::run_hand(seconds, 120.0, noise_mm * 1e-3, |f, r| {
        if f % every == 0 {
            println!(
                "{:>6} {:>5} {:>13} {:>8.4} {:>9.5} {:>11.2} {:>9.3}",
                f,
                r.iterations,
                format!("{:?}", r.stop),
                r.rrms,
                r.bone_length_error,
                r.marker_residual_rms_mm,
                r.solve_ms
            );
        }
    })
    .context("binding the procedural hand")?;
    println!("{}", serde_json::to_string_pretty(&rec)?);
    Ok(())
}

fn bench_characters(json: bool) -> Result<()> {
    let rec =
        characters::run_hand(10.0, 120.0, 0.0, |_, _| {}).context("binding the procedural hand")?;
    if json {
        println!("{}", serde_json::to_string(&rec)?);
    } else {
        println!("{}", serde_json::to_string_pretty(&rec)?);
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
