//! `rigless bake CHARACTER.toml`: binds a character file (with a progress bar), prints
//! what the bind made, and caches it next to the file.

use super::{bind_progress, end_bind_progress};
use anyhow::Result;
use rigless::character::file::load_character;
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
    let (rig, source) = found?;
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
    Ok(())
}
