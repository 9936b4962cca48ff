//! Simple shapes with known answers, for tests and procedural characters, and the
//! bounding box of a point set.

use glam::DVec3;
use std::f64::consts::PI;

/// A UV sphere of radius `r` at `c`: two poles and `rings − 1` rings of `segs` vertices;
/// closed, outward oriented (counter-clockwise seen from outside), `2·segs·(rings − 1)`
/// triangles. `rings ≥ 2`, `segs ≥ 3`.
pub fn uv_sphere(c: DVec3, r: f64, rings: u32, segs: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut v = vec![c + DVec3::Y * r, c - DVec3::Y * r];
    for i in 1..rings {
        let th = PI * i as f64 / rings as f64;
        for j in 0..segs {
            let ph = 2.0 * PI * j as f64 / segs as f64;
            v.push(c + r * DVec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()));
        }
    }
    let at = |i: u32, j: u32| 2 + (i - 1) * segs + j % segs;
    let mut t = Vec::new();
    for j in 0..segs {
        t.push([0, at(1, j + 1), at(1, j)]);
        t.push([1, at(rings - 1, j), at(rings - 1, j + 1)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segs {
            let (a, b, c2, d) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
            t.push([a, b, d]);
            t.push([a, d, c2]);
        }
    }
    (v, t)
}

/// Axis-aligned bounds `(min, max)` of a point set (infinite for an empty set).
pub fn bounds(points: &[DVec3]) -> (DVec3, DVec3) {
    points
        .iter()
        .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        })
}
