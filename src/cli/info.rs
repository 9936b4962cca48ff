//! `rigless info FILE`: what a recording holds.

use anyhow::{bail, Result};
use rigless::replay::recording::{Recording, DEFAULT_BVH_METRES_PER_UNIT};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct InfoArgs {
    /// The recording.
    file: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Metres per BVH unit (BVH files have no units; CMU's conversions use about
    /// 0.0564).
    #[arg(long, default_value_t = DEFAULT_BVH_METRES_PER_UNIT)]
    bvh_scale: f64,
}

pub fn run(a: InfoArgs) -> Result<()> {
    if !(a.bvh_scale.is_finite() && a.bvh_scale > 0.0) {
        bail!(
            "--bvh-scale must be a positive number of metres per unit, got {:?}",
            a.bvh_scale
        );
    }
    let rec = Recording::load_with(&a.file, a.bvh_scale)?;
    let s = rec.summary();
    if a.json {
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
