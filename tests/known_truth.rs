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
    // Measured: scale 0.3 % off, vertices 0.79 % of the height in the mean frame and
    // 0.90 % in the worst, head within 4.4°, trunk 12.3°, lowest vertex 3 mm under the
    // truth's in the median frame. The targets (2 %, 1 %, 3 %, 5°): all met but
    // the trunk's. Without the marker set's templates (every label the rest-like frame
    // does not show on its skin started on its bone) the same case measured 5.9 % and
    // 52°; with the templates held three times more loosely, 1.24 % and 5.4°.
    assert!(r.scale_error < 0.02, "{}", r.scale_error);
    assert!(r.vertex_share_mean < 0.016, "{}", r.vertex_share_mean);
    assert!(
        r.vertex_share_worst_frame < 0.018,
        "{}",
        r.vertex_share_worst_frame
    );
    assert!(r.head_deg_max < 9.0, "{}", r.head_deg_max);
    // Half the floor check's 3 cm (measured 3 mm; the check's own scale, not twice it).
    assert!(r.floor_mm_median.abs() < 15.0, "{}", r.floor_mm_median);
    // What the solve alone reaches with the markers' true layout, the floor under
    // these figures: 0.32 % mean, 0.40 % worst frame, trunk 9.8°.
    assert!(
        r.true_layout.vertex_share_mean < 0.0065,
        "{}",
        r.true_layout.vertex_share_mean
    );
    // The trunk's floor is the walk's own: it swings the right thigh 15° further back
    // than a hip extends (30°, with the rig's rest counted from a thigh hanging
    // straight), so the solve, held to that, tilts the pelvis instead. With ranges
    // counted from the rest pose (its knees bent 25°, its thighs 10° forward) the
    // trunk measured 21° with the true layout.
    let (joint, deg) = r.beyond_limits.clone().expect("the walk goes past a hip");
    assert_eq!(joint, "leg_joint_R_1");
    assert!((10.0..20.0).contains(&deg), "{deg}");
    assert!(
        r.true_layout.trunk_deg_max < 15.0,
        "{}",
        r.true_layout.trunk_deg_max
    );
    // And its skin: the four pelvis markers, moved by CesiumMan's own skinning (the
    // hips' skin weighted to the thighs), turn up to 10.9° away from the hips bone
    // (measured), so markers held rigid on it cannot tell its turn closer.
    let hips = r
        .skin_slide
        .iter()
        .find(|(j, _)| j == "Skeleton_torso_joint_1")
        .map(|s| s.1);
    assert!(
        hips.is_some_and(|d| (8.0..16.0).contains(&d)),
        "{:?}",
        r.skin_slide
    );
    // The regions split the mesh: their shares of the vertices sum to one, and their
    // errors weighted by those shares give back the mean (every frame has every vertex).
    for (what, regions, mean) in [
        ("solve", &r.by_region, r.vertex_share_mean),
        (
            "true layout",
            &r.true_layout.by_region,
            r.true_layout.vertex_share_mean,
        ),
    ] {
        let share: f64 = regions.iter().map(|x| x.1).sum();
        let weighted: f64 = regions.iter().map(|x| x.1 * x.2).sum();
        assert!((share - 1.0).abs() < 1e-9, "{what}: {share}");
        assert!(
            (weighted - mean).abs() < 1e-9 * mean,
            "{what}: {weighted} {mean}"
        );
        let names: Vec<&str> = regions.iter().map(|x| x.0).collect();
        // CesiumMan has no finger joints, and every joint of it has a role.
        assert_eq!(
            names,
            ["head", "trunk", "arms", "hands", "legs", "feet"],
            "{what}"
        );
    }
    // Over the trunk's target, so the calibration must not call itself good: it is
    // doubtful (the pelvis markers fit badly).
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
    // person's size, the idle (2.1 % of the height), the run (2.1 %) and the walk
    // (1.7 %) each with the right hand held at a joint limit in all 20 frames used,
    // which alone calls them doubtful: their misfits (1.5 to 5.3 mm) and feet would call
    // them good (the run was so called without that check).
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
    // measured scale 0.9 % off, vertices 1.7 % of the height, head within 2°; from
    // the labels' bones instead (and a scale prior of 1 mm per 5 %), 3.2 %, 5.7 % and
    // 52°.
    let walk = records
        .iter()
        .find(|r| r.clip == "Walk" && r.asset.contains('×'))
        .expect("walk at a person's size");
    assert!(walk.scale_error < 0.015, "{}", walk.scale_error);
    assert!(walk.vertex_share_mean < 0.03, "{}", walk.vertex_share_mean);
    assert!(walk.head_deg_max < 12.0, "{}", walk.head_deg_max);
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
    // The idle at a person's size: its labels placed by a take that barely moves them
    // (a pelvis label 5 cm off). Its rest-like frame alone gives a scale 25 % off (the
    // arms hang where the character's are level); the fit started there ended 1.5 % off
    // with the trunk 16° off, its objective 37 % above the truth's. Started again from
    // the segment lengths (a median over 36 pairs of labels on one bone), measured:
    // scale 0.36 % off, trunk 2.6°, vertices 2.1 % of the height. Its head looks 8°
    // aside where the actor stands most like rest; held to rest there, the headband's
    // labels were placed turned 8° and the head solved 8.2° off in every frame. Held
    // to the headband's mirror symmetry instead: measured 2.1°.
    let idle = records.iter().find(|r| r.clip == "Idle").expect("idle");
    assert!(idle.scale_error < 0.008, "{}", idle.scale_error);
    assert!(idle.trunk_deg_max < 7.0, "{}", idle.trunk_deg_max);
    assert!(idle.vertex_share_mean < 0.035, "{}", idle.vertex_share_mean);
    assert!(idle.head_deg_max < 4.5, "{}", idle.head_deg_max);
    // The run with the markers' true layout: 1.18 % mean, 1.33 % in the worst frame.
    // Its markers move up to 48 mm a frame from the first: when the marker buffer gated
    // a track's first samples as if it stood still, it rejected them for three frames
    // and re-acquired them from rest (2.6 % in the worst frame, the take's first).
    let run = records
        .iter()
        .find(|r| r.clip == "Run" && r.asset.contains('×'));
    let run = run.expect("run at a person's size");
    // Its scale from the rest-like frame's start: 2.7 % off; from the segment lengths'
    // (measured): 0.51 %.
    assert!(run.scale_error < 0.01, "{}", run.scale_error);
    // Its head: 7.2° off held to rest in the rest-like frame, 3.0° held to the
    // headband's symmetry (measured).
    assert!(run.head_deg_max < 5.5, "{}", run.head_deg_max);
    assert!(
        run.true_layout.vertex_share_worst_frame < 0.025,
        "{}",
        run.true_layout.vertex_share_worst_frame
    );
}

/// Kenney's mini character (limbs of one joint each, 0.78 m tall) on its own idle: no
/// frame fits onto its skin at a scale of its own (the bones' anchors stand far from
/// where the markers go, and every frame's fit collapses), so the calibration once
/// failed. At the segment lengths' scale (labels sharing a bone, over the take) the
/// frames fit: measured, scale 12 % off and feet 12 cm through the floor, so the
/// result must say doubtful and name the feet, never good.
#[test]
fn a_character_no_frame_fits_at_its_own_scale_is_fitted_at_the_segment_lengths() {
    if shared_path("meshes/real/kenney_mini_character_female_a.glb").is_none() {
        return;
    }
    let records = cases(
        "meshes/real/kenney_mini_character_female_a.glb",
        &["idle"],
        1.0,
    );
    let idle = records.first().expect("the idle calibrates");
    println!("{idle:?}");
    assert!(idle.scale_error < 0.25, "{}", idle.scale_error);
    assert_eq!(idle.verdict, Verdict::Doubtful, "{:?}", idle.concerns);
    assert!(
        idle.concerns
            .iter()
            .any(|c| c.contains("under the take's floor")),
        "{:?}",
        idle.concerns
    );
}
