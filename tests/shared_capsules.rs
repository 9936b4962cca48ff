//! Golden test on the real TetGen capsules of `../shared/data/tetmesh` (skipped, with the
//! reason printed, when the shared data folder is absent).

mod common;

use rigless::rig::arap_system::{ArapOperator, ArapSystem, LinearRows};
use rigless::rig::tetmesh::read_capsule;

#[test]
fn capsules_read_with_their_documented_sizes_and_solve() {
    let Some(dir) = common::shared_path("tetmesh") else {
        return;
    };
    // Sizes from ../shared/data/README.md.
    for (file, n, m) in [
        ("capsule_400.bin", 418, 1_696),
        ("capsule_2000.bin", 1_854, 8_767),
    ] {
        let p = read_capsule(&dir.join(file)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (
                p.mesh.positions.len(),
                p.mesh.tets.len(),
                p.constrained.len()
            ),
            (n, m, 10),
            "{file}"
        );
        let (lo, _) = p.mesh.dihedral_range_deg();
        // The README states a minimum dihedral angle of 3.6 degrees over the set.
        assert!(lo > 3.0, "{file}: min dihedral {lo}");
        let op = ArapOperator::new(&p.mesh);
        // About a quarter of the edge weights are negative on these meshes (README).
        let frac = op.clamped_weights as f64 / op.n_edges as f64;
        assert!(
            (0.15..0.4).contains(&frac),
            "{file}: clamped fraction {frac}"
        );
        let mut rows = LinearRows::new();
        for &i in &p.constrained {
            rows.push(&[(i, 1.0)], 1e5);
        }
        let sys = ArapSystem::new(op, rows, 1.0).expect("factor");
        let mut st = sys.new_state();
        st.targets.clone_from(&p.targets);
        let (_, rrms, _) = sys.iterate(&mut st, 200, 1e-6);
        // The bend is a 60° rotation of one end: rrms settles near 0.03 (bench figures).
        assert!(rrms < 0.05, "{file}: rrms {rrms}");
        let worst = (0..sys.rows.len())
            .map(|r| (sys.rows.eval(r, &st.positions) - st.targets[r]).length())
            .fold(0.0, f64::max);
        // Soft pins at weight 1e5 hold to about 1e-5 of the capsule length 4.
        assert!(worst < 1e-4, "{file}: pin residual {worst}");
    }
}
