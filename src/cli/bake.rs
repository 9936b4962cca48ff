//! `rigless bake CHARACTER.toml`: binds a character file (with a progress bar), prints
//! what the bind made, and caches it next to the file; with `--exercise`, then plays a
//! range of motion through every joint and reports what it did to the character.

use super::{bind_progress, end_bind_progress};
use anyhow::Result;
use rigless::bench::exercise::ExerciseOptions;
use rigless::character::file::{load_character, LoadedCharacter};
use rigless::rig::cache::load_or_bind;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct BakeArgs {
    /// The character file (TOML: mesh, skeleton, markers; see README).
    character: PathBuf,
    /// Bind again even if the cache is current.
    #[arg(long)]
    force: bool,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
    /// After binding, play every joint to its limits and back, then all together, through
    /// the solver at 120 Hz, and report inverted tets, unmoved vertices, limit
    /// violations, volume change and frame times (binds again, timed, without the cache;
    /// with no marker layout, one marker per bone is made for it).
    #[arg(long)]
    exercise: bool,
}

pub fn run(a: BakeArgs) -> Result<()> {
    let t0 = std::time::Instant::now();
    let loaded = load_character(&a.character)?;
    let ch = &loaded.character;
    let read_s = t0.elapsed().as_secs_f64();
    let mut drawn = false;
    let mut bar = bind_progress();
    let found = load_or_bind(&a.character, &loaded, a.force, &mut |stage, f| {
        if !a.json {
            drawn = true;
            bar(stage, f);
        }
    });
    end_bind_progress(drawn);
    // What is unusual about the mesh may be why the bind failed: said first, once each.
    let (rig, source) = found.inspect_err(|_| {
        for w in &loaded.warnings {
            tracing::warn!("{}: {w}", a.character.display());
        }
    })?;
    if a.exercise && a.json {
        return exercise(&loaded, true);
    }
    let s = &rig.stats;
    if a.json {
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
                "warnings": loaded.warnings.iter().map(ToString::to_string).collect::<Vec<_>>(),
                "cell_size_m": loaded.bind.cell_size_m,
                "cell_size_reason": loaded.cell_choice.as_ref().map(|c| c.reason.clone()),
                "roles": loaded.roles,
                "cache": source.to_string(),
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
    if let Some(c) = &loaded.cell_choice {
        println!(
            "cell size      {:.4} m: {} (about {:.0} control vertices expected)",
            c.cell_size_m, c.reason, c.estimated_control_vertices
        );
    }
    println!("roles          {}", loaded.roles);
    for w in &loaded.warnings {
        println!("warning        {w} (bound anyway)");
    }
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
    if a.exercise {
        exercise(&loaded, false)?;
    }
    Ok(())
}

/// `--exercise`: the range of motion, with a progress line, and its report.
fn exercise(loaded: &LoadedCharacter, json: bool) -> Result<()> {
    let opts = ExerciseOptions::default();
    let mut shown = -1i64;
    let r = rigless::bench::exercise::exercise(&loaded.character, &loaded.bind, opts, &mut |f| {
        let pct = (f * 100.0) as i64;
        if !json && pct / 5 != shown / 5 {
            shown = pct;
            eprint!("\r  exercise {pct:>3}%");
        }
    })?;
    if !json {
        eprintln!();
    }
    if json {
        let mut v = serde_json::to_value(&r)?;
        v["roles"] = serde_json::to_value(&loaded.roles)?;
        v["warnings"] = loaded.warnings.iter().map(ToString::to_string).collect();
        v["problems"] = r.problems().into();
        println!("{v}");
        return Ok(());
    }
    println!(
        "exercise       {} frames at {} Hz: every joint to its limits and back, then all together; {} of {} joints limited; {} markers{}",
        r.frames,
        opts.rate_hz,
        r.limited_joints,
        r.joints,
        r.markers,
        if r.markers_made_for_exercise { " (one per bone, made for the exercise)" } else { "" }
    );
    println!(
        "bind           {:.2} s cold (Green coordinates {:.2} s)",
        r.bind_s, r.green_s
    );
    println!(
        "frame          p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms (full-mesh update p50 {:.3} ms)",
        r.frame_ms_p50, r.frame_ms_p99, r.frame_ms_max, r.green_ms_p50
    );
    println!(
        "quality        inverted tets max {}, unmoved vertices {}, limit violation max {:.2}°, volume change max {:.2} %, bone length error max {:.2} %, marker residual max {:.2} mm",
        r.inverted_tets_max,
        r.unmoved_vertices,
        r.joint_limit_violation_deg_max,
        100.0 * r.volume_error_max,
        100.0 * r.bone_length_error_max,
        r.marker_residual_mm_max
    );
    let problems = r.problems();
    if problems.is_empty() {
        println!("problems       none");
    }
    for p in &problems {
        println!("PROBLEM        {p}");
    }
    Ok(())
}
