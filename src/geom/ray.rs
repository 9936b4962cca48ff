//! Rays against a triangle mesh: where a ray from inside a body leaves its skin.

use glam::DVec3;

/// A ray's crossing of one triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, metres.
    pub distance: f64,
    /// The triangle's vertex indices.
    pub triangle: [u32; 3],
    /// Barycentric weights of the crossing on `triangle`.
    pub bary: [f64; 3],
    /// `1` when the triangle's winding faces along the ray (the ray leaves through it),
    /// `−1` when against it: times the triangle's normal, the outward normal of a ray
    /// leaving the body.
    pub side: f64,
}

/// Every crossing of the ray from `o` along `d` (unit) with the triangles `tris` of
/// `v`, nearest first (Möller and Trumbore, "Fast, Minimum Storage Ray/Triangle
/// Intersection", 1997).
pub fn hits(o: DVec3, d: DVec3, v: &[DVec3], tris: &[[u32; 3]]) -> Vec<Hit> {
    let mut out: Vec<Hit> = Vec::new();
    for t in tris {
        let [a, b, c] = t.map(|i| v[i as usize]);
        let (e1, e2) = (b - a, c - a);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-14 {
            continue;
        }
        let s = o - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let w = d.dot(q) / det;
        let distance = e2.dot(q) / det;
        if u < 0.0 || w < 0.0 || u + w > 1.0 || distance <= 0.0 {
            continue;
        }
        out.push(Hit {
            distance,
            triangle: *t,
            bary: [1.0 - u - w, u, w],
            side: if e1.cross(e2).dot(d) >= 0.0 {
                1.0
            } else {
                -1.0
            },
        });
    }
    out.sort_by(|a, b| a.distance.total_cmp(&b.distance));
    out
}

/// Where the ray from `o` along `d` (unit) leaves the skin: of its crossings, the
/// outermost of the first run closer than `layer_m` to one another. A clothed character
/// has layers (a body under its armour) and a marker sits on the outermost; a gap wider
/// than a layer is air before another part (an arm beside the trunk).
pub fn leaves_skin(
    o: DVec3,
    d: DVec3,
    v: &[DVec3],
    tris: &[[u32; 3]],
    layer_m: f64,
) -> Option<Hit> {
    let all = hits(o, d, v, tris);
    let mut outer = *all.first()?;
    for h in &all[1..] {
        if h.distance - outer.distance > layer_m {
            break;
        }
        outer = *h;
    }
    Some(outer)
}

/// How far out a marker sits and what may lie over the skin, for [`leaves_volume`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// The thickest layer of the surface (clothing over a body), metres: see
    /// [`leaves_skin`].
    pub layer_m: f64,
    /// A marker's centre out from the surface along its normal, metres.
    pub out_m: f64,
    /// How far past the skin's crossing the marker may go to get outside, metres.
    pub reach_m: f64,
}

/// Where the ray from `o` along `d` (unit) leaves the body's volume: the crossing of
/// [`leaves_skin`] when the point `reach.out_m` out from it lies outside (`inside`
/// says, the winding number for one), else the first later crossing, within
/// `reach.reach_m` of that one, out from which it does. A character's surface is not
/// always one closed shell: a belt, a collar or a glove's cuff entered within a layer's
/// reach leaves the point inside them, where no marker sits. When no crossing in reach
/// will do, the skin's crossing itself: an open mesh's winding number is not a clean 0
/// or 1 by its holes (0.8 just outside a low-poly character's hips), and a marker is
/// better put where the skin ends than not at all. `None` when the ray meets no skin.
pub fn leaves_volume(
    o: DVec3,
    d: DVec3,
    v: &[DVec3],
    tris: &[[u32; 3]],
    reach: Reach,
    inside: impl Fn(DVec3) -> bool,
) -> Option<Hit> {
    let first = leaves_skin(o, d, v, tris, reach.layer_m)?;
    let outside = hits(o, d, v, tris)
        .into_iter()
        .filter(|h| h.distance >= first.distance && h.distance <= first.distance + reach.reach_m)
        .find(|h| !inside(h.point(v, reach.out_m)));
    Some(outside.unwrap_or(first))
}

impl Hit {
    /// The crossing point on `v`'s mesh (the triangle's vertices as `v` places them)
    /// and, `out_m` metres out along its outward normal, the point returned.
    pub fn point(&self, v: &[DVec3], out_m: f64) -> DVec3 {
        let [a, b, c] = self.triangle.map(|i| v[i as usize]);
        let n = (b - a).cross(c - a).normalize_or_zero() * self.side;
        a * self.bary[0] + b * self.bary[1] + c * self.bary[2] + n * out_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube's 12 triangles, wound outward.
    fn cube() -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let v: Vec<DVec3> = (0..8)
            .map(|i| DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64))
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let tris = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        (v, tris)
    }

    /// The unit cube with two more about its centre, `k1` and `k2` times its size.
    fn nested_cubes(k1: f64, k2: f64) -> (Vec<DVec3>, Vec<[u32; 3]>) {
        let (v, tris) = cube();
        let c = DVec3::splat(0.5);
        let mut all = v.clone();
        let mut t = tris.clone();
        for (n, k) in [k1, k2].into_iter().enumerate() {
            all.extend(v.iter().map(|p| c + (*p - c) * k));
            let base = 8 * (n as u32 + 1);
            t.extend(tris.iter().map(|x| x.map(|i| i + base)));
        }
        (all, t)
    }

    #[test]
    fn a_ray_from_the_centre_leaves_through_the_face_it_points_at() {
        let (v, tris) = cube();
        let c = DVec3::splat(0.5);
        for d in [DVec3::X, -DVec3::Y, DVec3::Z] {
            let h = leaves_skin(c, d, &v, &tris, 0.01).unwrap();
            assert!((h.distance - 0.5).abs() < 1e-12);
            // 8 mm out along the outward normal: 0.508 from the centre.
            let p = h.point(&v, 0.008);
            assert!((p - (c + d * 0.508)).length() < 1e-12, "{p}");
        }
    }

    #[test]
    fn the_outermost_layer_within_reach_is_taken_and_air_beyond_is_not() {
        // A second cube 2 cm larger around the first, and a third far out.
        let (all, t) = nested_cubes(1.04, 3.0);
        // Off the faces' diagonals (y ≠ z), so that each face is crossed once.
        let o = DVec3::new(0.5, 0.3, 0.6);
        let h = leaves_skin(o, DVec3::X, &all, &t, 0.03).unwrap();
        assert!((h.distance - 0.52).abs() < 1e-12, "{}", h.distance);
        let all_hits: Vec<f64> = hits(o, DVec3::X, &all, &t)
            .iter()
            .map(|h| h.distance)
            .collect();
        assert_eq!(all_hits.len(), 3, "{all_hits:?}");
        assert!((all_hits[2] - 1.5).abs() < 1e-12, "{all_hits:?}");
        // Past the layer's reach the far cube is air beyond: the inner one is taken.
        let h = leaves_skin(o, DVec3::X, &all, &t, 0.01).unwrap();
        assert!((h.distance - 0.5).abs() < 1e-12, "{}", h.distance);
    }

    /// A ray that leaves a body into a thick shell around it (a belt) within a layer's
    /// reach: the point out from the crossing into the shell lies inside it, so the
    /// shell's far side is taken; past the reach, the skin's own crossing.
    #[test]
    fn a_marker_is_not_left_inside_what_covers_the_skin() {
        let (v, tris) = cube();
        let centre = DVec3::splat(0.5);
        // A shell 1.04 to 1.2 times the body: 2 cm from the body, 8 cm thick.
        let (all, t) = nested_cubes(1.04, 1.2);
        // Inside the shell: between its two surfaces.
        let inside = |p: DVec3| {
            let r = (p - centre).abs().max_element();
            (0.52..0.6).contains(&r) || r < 0.5
        };
        let o = DVec3::new(0.5, 0.3, 0.6);
        assert!((leaves_skin(o, DVec3::X, &all, &t, 0.03).unwrap().distance - 0.52).abs() < 1e-12);
        let reach = |reach_m| Reach {
            layer_m: 0.03,
            out_m: 0.008,
            reach_m,
        };
        let h = leaves_volume(o, DVec3::X, &all, &t, reach(0.1), inside).unwrap();
        assert!((h.distance - 0.6).abs() < 1e-12, "{}", h.distance);
        assert!(!inside(h.point(&all, 0.008)));
        // The shell's far side 8 cm past the crossing into it: out of a 5 cm reach.
        let h = leaves_volume(o, DVec3::X, &all, &t, reach(0.05), inside).unwrap();
        assert!((h.distance - 0.52).abs() < 1e-12, "{}", h.distance);
        // Nothing around the body: the crossing of the skin itself.
        let h = leaves_volume(o, DVec3::X, &v, &tris, reach(0.1), |p| {
            (p - centre).abs().max_element() < 0.5
        });
        assert!((h.unwrap().distance - 0.5).abs() < 1e-12);
    }
}
