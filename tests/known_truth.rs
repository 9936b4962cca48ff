//! Known truth on real assets: skinned glTF files of the shared data folder played by
//! their own animations through their own skinning, a marker set on the skin, calibrated
//! and solved ([`rigless::bench::truth`]). Skipped, with the reason printed, without the
//! shared data.

mod common;

use common::shared_path;
use rigless::bench::truth::{asset_cases, TruthRecord};
use rigless::calibrate::Verdict;

/// The suite's cases for `file` (the clips named, at `scale`).
fn cases(file: &str, clips: &[&str], scale: f64) -> Vec<TruthRecord> {
    let data = common::shared_dir();
    let mut records = Vec::new();
    asset_cases(
        &data,
        file,
        clips,
        scale,
        false,
        &mut std::io::sink(),
        &mut records,
    )
    .unwrap_or_else(|e| panic!("{file}: {e}"));
    records
}

#[test]
fn cesium_man_known_truth_is_measured_and_judged_honestly() {
    if shared_path("meshes/gltf-samples/CesiumMan.glb").is_none() {
        return;
    }
    let records = cases("meshes/gltf-samples/CesiumMan.glb", &[], 1.0);
    assert_eq!(records.len(), 1, "one clip");
    let r = &records[0];
    assert_eq!(r.markers, 39, "every Plug-in Gait marker finds the skin");
    assert_eq!(r.placed, 39);
    // Its own file at rest is its bind pose (skinning matrices 2e-7 off identity).
    assert!(r.rest_off_bind < 1e-5, "{}", r.rest_off_bind);
    // Measured: scale 1.1 % off, vertices 1.8 % of the height in the mean frame and
    // 1.9 % in the worst, head within 1.1° (its neck chain's top read as the head),
    // lowest vertex 21 mm over the truth's in the median frame. The targets
    // (2 %, 1 %, 3 %, 5°): scale, worst frame and head met, mean vertex error not.
    assert!(r.scale_error < 0.025, "{}", r.scale_error);
    assert!(r.vertex_share_mean < 0.035, "{}", r.vertex_share_mean);
    assert!(
        r.vertex_share_worst_frame < 0.03,
        "{}",
        r.vertex_share_worst_frame
    );
    assert!(r.head_deg_max < 5.0, "{}", r.head_deg_max);
    assert!(r.floor_mm_median.abs() < 40.0, "{}", r.floor_mm_median);
    // Over the targets (1 % mean, 3 % worst frame), so the calibration must not
    // call itself good: it is doubtful (the pelvis markers fit badly).
    assert_ne!(r.verdict, Verdict::Good, "{:?}", r.concerns);
}

#[test]
fn calibrations_far_from_the_truth_are_not_called_good() {
    if shared_path("meshes/real/threejs_soldier_mixamo.glb").is_none() {
        return;
    }
    // The soldier as exported (0.22 m) on its walk, and at a person's size on its walk
    // and its idle.
    let mut records = cases("meshes/real/threejs_soldier_mixamo.glb", &["Walk"], 1.0);
    records.extend(cases(
        "meshes/real/threejs_soldier_mixamo.glb",
        &["Idle", "Walk"],
        8.5,
    ));
    assert_eq!(records.len(), 3);
    // The bounds on known truth: scale within 2 %, vertices 1 % mean and 3 % in
    // the worst frame. A "good" outside them is the worst outcome there is; each is
    // counted. Measured: none (all doubtful: the actor's size at 0.22 m; the misfit of
    // 10.4 mm and flagged labels on the walk at a person's size; the feet 14 cm under
    // the floor on the idle, whose misfit of 3.3 mm alone would call it good).
    let wrong_but_good: Vec<String> = records
        .iter()
        .filter(|r| {
            let within = r.scale_error <= 0.02
                && r.vertex_share_mean <= 0.01
                && r.vertex_share_worst_frame <= 0.03;
            !within && r.verdict == Verdict::Good
        })
        .map(|r| format!("{} {}", r.asset, r.clip))
        .collect();
    assert!(wrong_but_good.is_empty(), "{wrong_but_good:?}");
    // At its exported size the actor would be 0.2 m tall: said so, so not good.
    assert_ne!(records[0].verdict, Verdict::Good);
    assert!(
        records[0]
            .concerns
            .iter()
            .any(|c| c.contains("actor would be 0.2")),
        "{:?}",
        records[0].concerns
    );
    // The idle at a person's size: scale 5.7 % off, vertices 7 % of the height, and
    // the only concern the feet, 14.4 cm under the take's floor (its lowest markers
    // 3 cm above it). Without the floor check it was called good.
    let idle = records.iter().find(|r| r.clip == "Idle").expect("idle");
    assert!(
        idle.concerns
            .iter()
            .any(|c| c.contains("under the take's floor")),
        "{:?}",
        idle.concerns
    );
}
