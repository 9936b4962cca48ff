//! Golden tests on the real recordings in `../shared/data` (skipped, with the reason
//! printed, when the folder is absent): every C3D file's marker count, rate, frame count,
//! labels and gap share, and the Qualisys hand recording read from TSV and from its C3D
//! conversion agreeing sample for sample.

mod common;

use rigless::replay::c3d::read_c3d;
use rigless::replay::tsv::parse_tsv;
use std::path::PathBuf;

fn data(rel: &str) -> Option<PathBuf> {
    common::shared_path(rel)
}

fn missing_share(frames: &[Vec<glam::DVec3>]) -> f64 {
    let total = frames.iter().map(|f| f.len()).sum::<usize>().max(1);
    let missing = frames.iter().flatten().filter(|p| !p.is_finite()).count();
    missing as f64 / total as f64
}

#[test]
fn every_real_c3d_file_reads_with_its_known_figures() {
    // (file, points, rate, frames, first label, gap share range): figures from the data
    // folder's README and the files' own parameter sections.
    let cases = [
        ("c3d/BTS.c3d", 22, 100.0, 675, "c7", (0.50, 0.54)),
        ("c3d/FP_Type1.c3d", 22, 100.0, 634, "sacrum", (0.0, 0.001)),
        ("c3d/Qualisys.c3d", 55, 200.0, 340, "L_IAS", (0.0, 0.0)),
        (
            "c3d/Vicon.c3d",
            51,
            100.0,
            580,
            "boite:gauche_ext",
            (0.005, 0.015),
        ),
        (
            "hand/dfki_hand_recording_converted.c3d",
            21,
            100.0,
            6000,
            "hand_top",
            (0.001, 0.02),
        ),
    ];
    for (rel, points, rate, frames, first, (lo, hi)) in cases {
        let Some(path) = data(rel) else { continue };
        let c = read_c3d(&std::fs::read(&path).unwrap()).unwrap_or_else(|e| panic!("{rel}: {e}"));
        assert_eq!(c.labels.len(), points, "{rel}");
        assert_eq!(c.rate_hz, rate, "{rel}");
        assert_eq!(c.frames.len(), frames, "{rel}");
        assert_eq!(c.labels[0], first, "{rel}");
        let gaps = missing_share(&c.frames);
        assert!((lo..=hi).contains(&gaps), "{rel}: gap share {gaps}");
        // Every present sample is a plausible position in a capture volume (metres).
        for p in c.frames.iter().flatten().filter(|p| p.is_finite()) {
            assert!(p.abs().max_element() < 20.0, "{rel}: {p}");
        }
    }
}

/// The files' own word on which points are model outputs (POINT:ANGLES, FORCES, ...,
/// MODELED_MARKERS: the data folder's README counts them), and a Qualisys take whose
/// gaps are written as (0, 0, 0): read as gaps (its README: about 23 %).
#[test]
fn model_outputs_and_zero_gaps_are_read_as_what_they_are() {
    if let Some(path) = data("c3d/real/pycgm_pig_movement_trial.c3d") {
        let c = read_c3d(&std::fs::read(&path).unwrap()).unwrap();
        let count = |g: &str| {
            c.point_groups
                .iter()
                .filter(|x| x.as_deref() == Some(g))
                .count()
        };
        assert_eq!(c.point_groups.len(), 239);
        assert_eq!(
            [
                count("ANGLES"),
                count("POWERS"),
                count("FORCES"),
                count("MOMENTS"),
                count("MODELED_MARKERS")
            ],
            [26, 16, 20, 18, 2]
        );
        let k = c.labels.iter().position(|l| l == "LHipAngles").unwrap();
        assert_eq!(c.point_groups[k].as_deref(), Some("ANGLES"));
        let k = c.labels.iter().position(|l| l == "LASI").unwrap();
        assert_eq!(c.point_groups[k], None);
    }
    if let Some(path) = data("c3d/real/numediart_03_rolling.c3d") {
        let c = read_c3d(&std::fs::read(&path).unwrap()).unwrap();
        let gaps = missing_share(&c.frames);
        assert!((0.20..0.26).contains(&gaps), "gap share {gaps}");
        assert!(c.frames.iter().flatten().all(|p| *p != glam::DVec3::ZERO));
        assert!(
            c.warnings.iter().any(|w| w.contains("(0, 0, 0)")),
            "{:?}",
            c.warnings
        );
    }
}

#[test]
fn qualisys_first_sample_values() {
    let Some(path) = data("c3d/Qualisys.c3d") else {
        return;
    };
    let c = read_c3d(&std::fs::read(path).unwrap()).unwrap();
    assert_eq!(c.first_frame, 705);
    assert_eq!(c.units, "mm");
    // L_IAS in frame 705: (-220.1226, 306.4248, 846.3361) mm in the file's Z-up frame
    // (decoded independently with Python's struct module from block 29).
    let p = c.frames[0][0];
    assert!(
        (p - glam::DVec3::new(-0.2201226, 0.8463361, -0.3064248)).length() < 1e-6,
        "{p}"
    );
}

#[test]
fn tsv_and_its_c3d_conversion_agree() {
    let (Some(tsv), Some(c3d)) = (
        data("hand/dfki_hand_recording.tsv"),
        data("hand/dfki_hand_recording_converted.c3d"),
    ) else {
        return;
    };
    let t = parse_tsv(&std::fs::read_to_string(tsv).unwrap()).unwrap();
    let c = read_c3d(&std::fs::read(c3d).unwrap()).unwrap();
    assert_eq!(t.marker_names, c.labels);
    assert_eq!(t.rate_hz, c.rate_hz);
    assert_eq!(t.frames.len(), c.frames.len());
    let mut compared = 0;
    for (a, b) in t.frames.iter().flatten().zip(c.frames.iter().flatten()) {
        assert_eq!(a.is_finite(), b.is_finite());
        if a.is_finite() {
            // The C3D stores f32 millimetres: 1e-4 mm resolution at 1 m.
            assert!((*a - *b).length() < 1e-6, "{a} vs {b}");
            compared += 1;
        }
    }
    assert!(compared > 120_000, "{compared}");
}

#[test]
fn cmu_bvh_joints_by_forward_kinematics() {
    let Some(path) = data("bvh/131_01.bvh") else {
        return;
    };
    // CMU's BVH conversions: about 0.056444 m per unit.
    let r = rigless::replay::recording::Recording::load_with(&path, 0.056444).unwrap();
    // 31 joints and 7 end sites; "Frame Time: .0083333" is 120 Hz; 994 frames.
    assert_eq!(r.labels.len(), 38);
    assert_eq!(r.labels[0], "Hips");
    assert_eq!(r.rate_hz, 120.0);
    assert_eq!(r.frames.len(), 994);
    // The root's position channels of frame 0 are 5.2300 16.9002 -33.8986 (the first
    // motion line), in metres here.
    let hips = r.frames[0][0];
    let want = glam::DVec3::new(5.23, 16.9002, -33.8986) * 0.056444;
    assert!((hips - want).length() < 1e-9, "{hips} vs {want}");
    // Every bone keeps its length in every frame (rigid forward kinematics): check the
    // left thigh (LeftHip to LeftKnee).
    let (hip, knee) = (
        r.labels.iter().position(|l| l == "LeftHip").unwrap(),
        r.labels.iter().position(|l| l == "LeftKnee").unwrap(),
    );
    let len0 = (r.frames[0][knee] - r.frames[0][hip]).length();
    assert!((len0 - 0.056444 * (2.49329f64.powi(2) + 6.85026f64.powi(2)).sqrt()).abs() < 1e-9);
    for f in &r.frames {
        assert!(((f[knee] - f[hip]).length() - len0).abs() < 1e-9);
    }
}
