//! The built-in marker-set tables on the real takes of `../shared/data` (skipped, with
//! the reason printed, when it is absent): which table `--marker-set auto` picks for
//! each, how many labels it places, and which it does not know.

mod common;

use rigless::calibrate::marker_sets::{best_set, Placed};
use rigless::replay::recording::Recording;

fn labels(rel: &str) -> Option<Vec<String>> {
    let p = common::shared_path(rel)?;
    Some(Recording::load(&p).unwrap_or_else(|e| panic!("{e}")).labels)
}

/// (take, table picked, labels placed, labels in the take, labels on a prop)
#[test]
fn real_takes_pick_their_table() {
    for (rel, set, placed, total, props) in [
        // ISB landmarks; its 8 segment wands (L_WAND1...) are in no table.
        ("c3d/Qualisys.c3d", "isb", 47, 55, 0),
        // Davis: all 22, knees, malleoli, bars and heels.
        ("c3d/FP_Type1.c3d", "davis", 22, 22, 0),
        // Davis without RATT, LATT, SCR1, SCR2, SCL1, SCL2 (not in the protocol).
        ("c3d/BTS.c3d", "davis", 16, 22, 0),
        // The hand layout: 13 hand markers, elbow, shoulder, 3 on the back, 3 on a pillow.
        ("hand/dfki_hand_recording.tsv", "dfki-hand", 21, 21, 3),
        // A research upper-body set with a subject prefix: only T10 is a common label.
        ("c3d/Vicon.c3d", "plug-in-gait", 1, 51, 0),
    ] {
        let Some(labels) = labels(rel) else {
            return;
        };
        assert_eq!(labels.len(), total, "{rel}");
        let (table, n) = best_set(&labels).unwrap_or_else(|| panic!("{rel}: no table"));
        let unknown: Vec<&String> = labels.iter().filter(|l| table.place(l).is_none()).collect();
        eprintln!(
            "{rel}: {} places {n} of {total}; unknown {unknown:?}",
            table.name
        );
        assert_eq!((table.name, n), (set, placed), "{rel}");
        let on_props = labels
            .iter()
            .filter(|l| table.place(l) == Some(Placed::Prop))
            .count();
        assert_eq!(on_props, props, "{rel}");
    }
}
