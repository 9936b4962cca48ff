//! The `capsules` suite: plain volumetric ARAP (one rotation per vertex, clamped cotangent
//! weights) on the four TetGen capsules of `../shared/data/tetmesh`, with their own
//! constraints, timed per local+global iteration, to compare with the libigl reference
//! figures in that folder's README.

use super::Spread;
use crate::rig::arap_system::{ArapOperator, ArapSystem, LinearRows};
use crate::rig::factor::FactorError;
use crate::rig::tetmesh::{read_capsule, TetMeshError};
use std::path::Path;
use std::time::Instant;

/// The files, with libigl 2.6.3's per-iteration range (ms) and this project's target (ms).
pub const CASES: [(&str, f64, f64, f64); 4] = [
    ("capsule_400.bin", 0.46, 0.56, 0.15),
    ("capsule_2000.bin", 2.3, 2.9, 0.8),
    ("capsule_10000.bin", 26.0, 35.0, 8.0),
    ("capsule_30000.bin", 123.0, 136.0, 40.0),
];

/// Weight of the pinned-vertex rows relative to the (unitless) shape term: high enough
/// that the soft pins hold to about 1e-4 of the capsule length, low enough to keep the
/// factorization well conditioned.
pub const PIN_WEIGHT: f64 = 1e5;

/// One measured capsule.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CapsuleRecord {
    pub suite: &'static str,
    pub mesh: String,
    pub n: usize,
    pub tets: usize,
    pub clamped_weights: usize,
    pub min_dihedral_deg: f64,
    pub factor_s: f64,
    pub per_iter_ms_median: f64,
    pub per_iter_ms_p10: f64,
    pub per_iter_ms_p90: f64,
    pub local_ms_median: f64,
    pub global_ms_median: f64,
    pub timed_iters: usize,
    pub rrms: f64,
    pub polar_iters_per_vertex: f64,
    pub inverted_tets: usize,
    pub pin_residual_max: f64,
    pub libigl_ms_low: f64,
    pub libigl_ms_high: f64,
    pub target_ms: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum CapsuleBenchError {
    #[error(transparent)]
    Mesh(#[from] TetMeshError),
    #[error("{mesh}: {source}")]
    Factor { mesh: String, source: FactorError },
}

/// Runs one capsule: `converge_iters` iterations from rest (the same state libigl would be
/// timed in after its first iterations), then `timed` individually timed iterations.
pub fn run_case(
    path: &Path,
    converge_iters: usize,
    timed: usize,
) -> Result<CapsuleRecord, CapsuleBenchError> {
    let prob = read_capsule(path)?;
    let name = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let (lib_lo, lib_hi, target) = CASES
        .iter()
        .find(|c| c.0 == name)
        .map(|c| (c.1, c.2, c.3))
        .unwrap_or((f64::NAN, f64::NAN, f64::NAN));
    let t0 = Instant::now();
    let op = ArapOperator::new(&prob.mesh);
    let mut rows = LinearRows::new();
    for &i in &prob.constrained {
        rows.push(&[(i, 1.0)], PIN_WEIGHT);
    }
    let sys = ArapSystem::new(op, rows, 1.0).map_err(|source| CapsuleBenchError::Factor {
        mesh: name.clone(),
        source,
    })?;
    let factor_s = t0.elapsed().as_secs_f64();
    let mut st = sys.new_state();
    st.targets.clone_from(&prob.targets);
    for _ in 0..converge_iters {
        sys.local_step(&mut st);
        sys.global_step(&mut st);
    }
    let mut total = Vec::with_capacity(timed);
    let mut local = Vec::with_capacity(timed);
    let mut global = Vec::with_capacity(timed);
    let mut rr = 0.0;
    for _ in 0..timed {
        let a = Instant::now();
        rr = sys.rrms(sys.local_step(&mut st));
        let b = Instant::now();
        sys.global_step(&mut st);
        let c = Instant::now();
        local.push(b - a);
        global.push(c - b);
        total.push(c - a);
    }
    let s = Spread::of(&total);
    let pin_residual_max = (0..sys.rows.len())
        .map(|r| (sys.rows.eval(r, &st.positions) - st.targets[r]).length())
        .fold(0.0, f64::max);
    Ok(CapsuleRecord {
        suite: "capsules",
        mesh: name,
        n: prob.mesh.positions.len(),
        tets: prob.mesh.tets.len(),
        clamped_weights: sys.op.clamped_weights,
        min_dihedral_deg: prob.mesh.dihedral_range_deg().0,
        factor_s,
        per_iter_ms_median: s.median_ms,
        per_iter_ms_p10: s.p10_ms,
        per_iter_ms_p90: s.p90_ms,
        local_ms_median: Spread::of(&local).median_ms,
        global_ms_median: Spread::of(&global).median_ms,
        timed_iters: timed,
        rrms: rr,
        polar_iters_per_vertex: st.polar_iters as f64 / prob.mesh.positions.len() as f64,
        inverted_tets: prob.mesh.inverted_tets(&st.positions),
        pin_residual_max,
        libigl_ms_low: lib_lo,
        libigl_ms_high: lib_hi,
        target_ms: target,
    })
}

/// Iterations to time per case: enough samples for a stable median within about a second.
pub fn timed_iters_for(n_vertices_hint: &str) -> usize {
    match n_vertices_hint {
        "capsule_400.bin" => 400,
        "capsule_2000.bin" => 200,
        "capsule_10000.bin" => 60,
        _ => 25,
    }
}
/// The suite: every case of [`CASES`] found under `data/tetmesh`, one line each.
pub fn suite(
    data: &Path,
    json: bool,
    out: &mut dyn std::io::Write,
) -> Result<(), super::BenchError> {
    let dir = data.join("tetmesh");
    if !dir.is_dir() {
        return Err(super::BenchError::NoData {
            suite: "capsules",
            dir: dir.display().to_string(),
        });
    }
    if !json {
        writeln!(
            out,
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
        )?;
    }
    for (file, _, _, _) in CASES {
        let path = dir.join(file);
        let rec = run_case(&path, 10, timed_iters_for(file))
            .map_err(|e| super::BenchError::case(path.display().to_string(), e))?;
        if json {
            super::json_line(out, &rec)?;
            continue;
        }
        writeln!(
            out,
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
        )?;
    }
    Ok(())
}
