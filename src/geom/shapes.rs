//! Simple shapes with known answers, for tests and procedural characters, the bounding
//! box of a point set, and midpoint subdivision (to make big meshes from real ones).

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
/// Midpoint subdivision: each triangle into four at its edges' midpoints (shared by the
/// triangles on both sides of an edge, by vertex index), the vertices kept first and in
/// order, the new ones after them; the surface is the same, with `V + E` vertices and
/// `4·F` triangles, orientation kept.
pub fn subdivide_midpoint(
    vertices: &[DVec3],
    triangles: &[[u32; 3]],
) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut v = vertices.to_vec();
    let mut mid: std::collections::HashMap<(u32, u32), u32> =
        std::collections::HashMap::with_capacity(triangles.len() * 3 / 2);
    let mut t = Vec::with_capacity(triangles.len() * 4);
    for &[a, b, c] in triangles {
        let mut m = |p: u32, q: u32| {
            *mid.entry((p.min(q), p.max(q))).or_insert_with(|| {
                v.push(0.5 * (vertices[p as usize] + vertices[q as usize]));
                (v.len() - 1) as u32
            })
        };
        let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
        t.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    (v, t)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Signed volume of a closed triangle mesh (divergence theorem).
    fn volume(v: &[DVec3], t: &[[u32; 3]]) -> f64 {
        t.iter()
            .map(|&[a, b, c]| v[a as usize].dot(v[b as usize].cross(v[c as usize])) / 6.0)
            .sum()
    }

    #[test]
    fn midpoint_subdivision_keeps_the_surface() {
        let (v, t) = uv_sphere(DVec3::new(0.3, -1.0, 2.0), 0.7, 8, 12);
        let edges = 3 * t.len() / 2; // closed: every edge in two triangles
        let (v1, t1) = subdivide_midpoint(&v, &t);
        assert_eq!(v1.len(), v.len() + edges);
        assert_eq!(t1.len(), 4 * t.len());
        assert_eq!(&v1[..v.len()], &v[..], "the old vertices first, unchanged");
        // Same surface, same orientation: the enclosed volume is unchanged up to
        // round-off (1e-12 relative: sums of about 10^3 terms of size 1).
        let (a, b) = (volume(&v, &t), volume(&v1, &t1));
        assert!(a > 0.0 && ((a - b) / a).abs() < 1e-12, "{a} {b}");
        // Closed still: each edge in exactly two triangles.
        let mut count = std::collections::HashMap::new();
        for tri in &t1 {
            for k in 0..3 {
                let (p, q) = (tri[k], tri[(k + 1) % 3]);
                *count.entry((p.min(q), p.max(q))).or_insert(0) += 1;
            }
        }
        assert!(count.values().all(|&c| c == 2));
    }
}
