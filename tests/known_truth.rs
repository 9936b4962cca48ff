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
    // Measured: scale 0.6 % off, vertices 1.4 % of the height in the mean frame and
    // 1.5 % in the worst, head within 6.6°, lowest vertex 0.4 mm from the truth's in
    // the median frame. The targets (2 %, 1 %, 3 %, 5°): scale and worst frame
    // met, the mean vertex error and the head not. Without the marker set's templates
    // (every label the rest-like frame does not show on its skin started on its bone)
    // the same case measured 5.9 % and 52°.
    assert!(r.scale_error < 0.013, "{}", r.scale_error);
    assert!(r.vertex_share_mean < 0.03, "{}", r.vertex_share_mean);
    assert!(
        r.vertex_share_worst_frame < 0.03,
        "{}",
        r.vertex_share_worst_frame
    );
    assert!(r.head_deg_max < 13.0, "{}", r.head_deg_max);
    // Half the floor check's 3 cm (measured 0.4 mm: a bound of twice that would be
    // decided by the skinning's noise).
    assert!(r.floor_mm_median.abs() < 15.0, "{}", r.floor_mm_median);
    // What the solve alone reaches with the markers' true layout, the floor under
    // these figures: 0.40 % mean, 0.62 % worst frame.
    assert!(
        r.true_layout.vertex_share_mean < 0.008,
        "{}",
        r.true_layout.vertex_share_mean
    );
    // Over the targets (1 % mean, 3 % worst frame), so the calibration must not
    // call itself good: it is doubtful (the pelvis markers fit badly).
    assert_ne!(r.verdict, Verdict::Good, "{:?}", r.concerns);
}

#[test]
fn calibrations_far_from_the_truth_are_not_called_good() {
    if shared_path("meshes/real/threejs_soldier_mixamo.glb").is_none() {
        return;
    }
    // The soldier as exported (0.22 m) on its walk, and at a person's size on its idle,
    // run and walk.
    let mut records = cases("meshes/real/threejs_soldier_mixamo.glb", &["Walk"], 1.0);
    records.extend(cases(
        "meshes/real/threejs_soldier_mixamo.glb",
        &["Idle", "Run", "Walk"],
        8.5,
    ));
    assert_eq!(records.len(), 4);
    // The bounds on known truth: scale within 2 %, vertices 1 % mean and 3 % in
    // the worst frame. A "good" outside them is the worst outcome there is; each is
    // counted. Measured: none. All four are doubtful: the actor's size at 0.22 m; at a
    // person's size, the idle (2.3 % of the height), the run (2.2 %) and the walk
    // (2.3 %) each with hands held at a joint limit in all 20 frames used, which alone
    // calls them doubtful: their misfits (1.6 to 4.4 mm) and feet would call them good
    // (the run was so called without that check).
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
    for r in &records[1..] {
        assert!(
            r.concerns.iter().any(|c| c.contains("at a joint limit")),
            "{} {}: {:?}",
            r.asset,
            r.clip,
            r.concerns
        );
    }
    // The walk at a person's size, started from the set's templates where no frame
    // shows a label on its skin (its arms hang where the character's are level):
    // measured scale 0.3 % off, vertices 2.3 % of the height, head within 6.7°; from
    // the labels' bones instead (and a scale prior of 1 mm per 5 %), 3.2 %, 5.7 % and
    // 52°.
    let walk = records
        .iter()
        .find(|r| r.clip == "Walk" && r.asset.contains('×'))
        .expect("walk at a person's size");
    assert!(walk.scale_error < 0.01, "{}", walk.scale_error);
    assert!(walk.vertex_share_mean < 0.045, "{}", walk.vertex_share_mean);
    assert!(walk.head_deg_max < 13.0, "{}", walk.head_deg_max);
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
    // The idle at a person's size: scale 0.7 % off, feet 2 cm under the take's floor,
    // vertices 2.3 % of the height (its forearms' and hands' labels placed by a take
    // that barely moves them).
    let idle = records.iter().find(|r| r.clip == "Idle").expect("idle");
    assert!(idle.scale_error < 0.013, "{}", idle.scale_error);
    assert!(idle.vertex_share_mean < 0.045, "{}", idle.vertex_share_mean);
}
