//! The generalized winding number of a triangle soup (Jacobson, Kavan, Sorkine-Hornung,
//! "Robust Inside-Outside Segmentation using Generalized Winding Numbers", SIGGRAPH
//! 2013): `w(q) = Σ_t Ω_t(q) / 4π`, the signed solid angles of the triangles seen from
//! `q`, summed. It is 1 inside a closed, outward-oriented surface and 0 outside, and it
//! degrades gracefully where the surface is open, non-manifold, self-intersecting or
//! made of several overlapping parts: thresholded at 1/2 it still tells the inside of a
//! body with open eyes and an open shirt over it.
//!
//! Evaluation is hierarchical (Barill, Dickson, Schmidt, Levin, Jacobson, "Fast Winding
//! Numbers for Soups and Clouds", SIGGRAPH 2018, Section 3 and Eq. 9 to first order): a
//! bounding volume hierarchy over the triangles; a node far enough from `q` (its
//! area-weighted centre farther than `BETA` times its radius) counts as one dipole,
//! `(p̃ − q) · Ñ / (4π ‖p̃ − q‖³)` with `Ñ = Σ_t a_t n̂_t` (area-weighted normals) and `p̃`
//! the area-weighted centroid; nearer nodes are opened, and the triangles of near leaves
//! are summed exactly (Van Oosterom and Strackee 1983:
//! `tan(Ω/2) = a·(b×c) / (|a||b||c| + (a·b)|c| + (b·c)|a| + (c·a)|b|)`).
//!
//! Sign convention: counter-clockwise triangles seen from outside (outward normals by
//! the right-hand rule) give +1 inside.

use glam::DVec3;
use std::f64::consts::PI;

/// A node is taken as one dipole when its centre is farther from the query than this
/// many times its radius. Barill et al. use 2 with second-order terms; with the first
/// order only, 4 keeps the error below 1 % of w on the tests' spheres (2 gave 2.5 %),
/// far from the 1/2 threshold this is used with.
const BETA: f64 = 4.0;
/// Most triangles in a leaf.
const LEAF: usize = 8;
/// Depth of the traversal stack: the tree splits at the median, so its depth is about
/// log2(triangles / LEAF) + 1, which 64 covers for any mesh that fits in memory.
const STACK: usize = 64;

#[derive(Clone, Copy, Debug)]
struct Node {
    /// Area-weighted centroid `p̃` of the node's triangles.
    centre: DVec3,
    /// Largest distance from `centre` to a corner of the node's triangles.
    radius: f64,
    /// `Ñ = Σ_t a_t n̂_t = Σ_t (b − a) × (c − a) / 2`.
    normal: DVec3,
    /// The two children, or a leaf's range of `tris`: `first..first + count`.
    kind: NodeKind,
}

#[derive(Clone, Copy, Debug)]
enum NodeKind {
    Inner { left: u32, right: u32 },
    Leaf { first: u32, count: u32 },
}

/// A triangle soup prepared for winding-number queries (precomputation apart from the
/// queries, which allocate nothing).
#[derive(Clone, Debug)]
pub struct WindingNumber {
    /// Triangle corners, in tree order.
    tris: Vec<[DVec3; 3]>,
    nodes: Vec<Node>,
}

impl WindingNumber {
    /// Builds the hierarchy over `triangles` (indices into `vertices`; out-of-range
    /// triangles are the caller's bug and panic). Degenerate triangles are kept; they
    /// add nothing.
    pub fn new(vertices: &[DVec3], triangles: &[[u32; 3]]) -> Self {
        let mut tris: Vec<[DVec3; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| vertices[i as usize]))
            .collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF + 1);
        if !tris.is_empty() {
            let n = tris.len();
            build(&mut tris, 0, n, &mut nodes);
        }
        Self { tris, nodes }
    }

    /// `w(q)`: about 1 inside, 0 outside, 1/2 on an open part's rim.
    pub fn at(&self, q: DVec3) -> f64 {
        if self.nodes.is_empty() {
            return 0.0;
        }
        let mut stack = [0u32; STACK];
        let mut top = 1;
        let mut solid = 0.0;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            let d = node.centre - q;
            let dist = d.length();
            if dist > BETA * node.radius {
                solid += d.dot(node.normal) / (dist * dist * dist);
                continue;
            }
            match node.kind {
                NodeKind::Leaf { first, count } => {
                    for t in &self.tris[first as usize..(first + count) as usize] {
                        solid += triangle_solid_angle(t, q);
                    }
                }
                NodeKind::Inner { left, right } if top + 2 <= STACK => {
                    stack[top] = left;
                    stack[top + 1] = right;
                    top += 2;
                }
                // Deeper than the stack (not reached by a median-split tree): the node
                // counts as its dipole.
                NodeKind::Inner { .. } => {
                    solid += d.dot(node.normal) / (dist * dist * dist).max(f64::MIN_POSITIVE)
                }
            }
        }
        solid / (4.0 * PI)
    }
}

impl WindingNumber {
    /// The point of the surface nearest to `q` and its distance (`None` for no
    /// triangles): the same hierarchy, searched depth-first, nearer child first, a node
    /// skipped when its bounding sphere lies farther than the best point found so far.
    pub fn closest(&self, q: DVec3) -> Option<(DVec3, f64)> {
        let mut best = (DVec3::ZERO, f64::INFINITY);
        let mut stack = [0u32; STACK];
        let mut top = usize::from(!self.nodes.is_empty());
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if (node.centre - q).length() - node.radius >= best.1 {
                continue;
            }
            match node.kind {
                NodeKind::Leaf { first, count } => {
                    for t in &self.tris[first as usize..(first + count) as usize] {
                        let c = closest_on_triangle(q, t);
                        let d = (c - q).length();
                        if d < best.1 {
                            best = (c, d);
                        }
                    }
                }
                NodeKind::Inner { left, right } if top + 2 <= STACK => {
                    let dl = (self.nodes[left as usize].centre - q).length_squared();
                    let dr = (self.nodes[right as usize].centre - q).length_squared();
                    // The nearer child on top of the stack: searched first.
                    let (near, far) = if dl <= dr {
                        (left, right)
                    } else {
                        (right, left)
                    };
                    stack[top] = far;
                    stack[top + 1] = near;
                    top += 2;
                }
                // Deeper than the stack (not reached by a median-split tree): its
                // triangles are searched one by one.
                NodeKind::Inner { .. } => {
                    for t in &self.tris {
                        let c = closest_on_triangle(q, t);
                        let d = (c - q).length();
                        if d < best.1 {
                            best = (c, d);
                        }
                    }
                }
            }
        }
        best.1.is_finite().then_some(best)
    }
}

impl WindingNumber {
    /// The surface point nearest to `q`, the signed distance to it (negative inside,
    /// where the winding number exceeds 1/2) and the outward unit direction from it
    /// towards `q`'s side (zero when `q` is on the surface); `None` for no triangles.
    pub fn signed_closest(&self, q: DVec3) -> Option<(DVec3, f64, DVec3)> {
        let (c, d) = self.closest(q)?;
        let sign = if self.at(q) > 0.5 { -1.0 } else { 1.0 };
        Some((c, sign * d, (q - c).normalize_or_zero() * sign))
    }
}

/// The point of triangle `t` nearest to `p` (Ericson, "Real-Time Collision Detection",
/// Section 5.1.5: the Voronoi region of `p` among the corners, edges and face).
pub fn closest_on_triangle(p: DVec3, t: &[DVec3; 3]) -> DVec3 {
    let [a, b, c] = *t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * ratio(d1, d1 - d3);
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * ratio(d2, d2 - d6);
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ratio(d4 - d3, (d4 - d3) + (d5 - d6));
    }
    let denom = va + vb + vc;
    if denom.abs() < f64::MIN_POSITIVE {
        // A degenerate (zero-area) triangle: its nearest corner.
        return [a, b, c]
            .into_iter()
            .min_by(|x, y| {
                (*x - p)
                    .length_squared()
                    .total_cmp(&(*y - p).length_squared())
            })
            .unwrap_or(a);
    }
    let (v, w) = (vb / denom, vc / denom);
    a + ab * v + ac * w
}

/// `x / y`, or 0 for a zero `y` (an edge of zero length: its start is as near as any).
fn ratio(x: f64, y: f64) -> f64 {
    if y != 0.0 {
        (x / y).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The signed solid angle of triangle `t` seen from `q` times 1 (the dipole terms above
/// are in the same units: steradians), Van Oosterom and Strackee's formula.
fn triangle_solid_angle(t: &[DVec3; 3], q: DVec3) -> f64 {
    let (a, b, c) = (t[0] - q, t[1] - q, t[2] - q);
    let (la, lb, lc) = (a.length(), b.length(), c.length());
    let num = a.dot(b.cross(c));
    let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
    2.0 * num.atan2(den)
}

/// Builds the node over `tris[first..first + count]` (reordering that range) and its
/// subtree; returns its index.
fn build(tris: &mut [[DVec3; 3]], first: usize, count: usize, nodes: &mut Vec<Node>) -> u32 {
    let range = &tris[first..first + count];
    let (mut area_sum, mut weighted, mut normal) = (0.0, DVec3::ZERO, DVec3::ZERO);
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for t in range {
        let n = 0.5 * (t[1] - t[0]).cross(t[2] - t[0]);
        let area = n.length();
        let centroid = (t[0] + t[1] + t[2]) / 3.0;
        area_sum += area;
        weighted += centroid * area;
        normal += n;
        lo = lo.min(centroid);
        hi = hi.max(centroid);
    }
    let centre = if area_sum > 0.0 {
        weighted / area_sum
    } else {
        0.5 * (lo + hi)
    };
    let radius = range
        .iter()
        .flatten()
        .map(|p| (*p - centre).length())
        .fold(0.0, f64::max);
    let index = nodes.len();
    nodes.push(Node {
        centre,
        radius,
        normal,
        kind: NodeKind::Leaf {
            first: first as u32,
            count: count as u32,
        },
    });
    if count > LEAF {
        // Median split of the centroids along the longest axis of their box.
        let axis = (hi - lo).max_position();
        let key = |t: &[DVec3; 3]| (t[0][axis] + t[1][axis] + t[2][axis]) / 3.0;
        let half = count / 2;
        tris[first..first + count].select_nth_unstable_by(half, |a, b| key(a).total_cmp(&key(b)));
        let left = build(tris, first, half, nodes);
        let right = build(tris, first + half, count - half, nodes);
        nodes[index].kind = NodeKind::Inner { left, right };
    }
    index as u32
}

/// Triangles oriented consistently per connected part, for [`WindingNumber`]: `tris`
/// index welded vertices (`positions`); across every edge two triangles share (a
/// manifold edge) they are made to agree, part by part by a breadth-first walk from the
/// part's first triangle, and a closed part whose signed volume `Σ a·(b×c)/6` is
/// negative is turned over (outward normals); an open part keeps the file's side. Edges of three or more triangles do not propagate.
/// Returns the reoriented triangles and how many were flipped.
pub fn orient_parts(positions: &[DVec3], tris: &[[u32; 3]]) -> (Vec<[u32; 3]>, usize) {
    use std::collections::HashMap;
    // Directed edge (a, b) of triangle t; an undirected key with the triangles on it.
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::with_capacity(3 * tris.len() / 2);
    for (t, tri) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(t as u32);
        }
    }
    let mut out = tris.to_vec();
    let mut seen = vec![false; tris.len()];
    let mut part: Vec<u32> = Vec::new();
    let mut queue = std::collections::VecDeque::new();
    for start in 0..tris.len() {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        part.clear();
        queue.push_back(start as u32);
        while let Some(t) = queue.pop_front() {
            part.push(t);
            let tri = out[t as usize];
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let on_edge = &edges[&(a.min(b), a.max(b))];
                if on_edge.len() != 2 {
                    continue;
                }
                let u = if on_edge[0] == t {
                    on_edge[1]
                } else {
                    on_edge[0]
                };
                if seen[u as usize] {
                    continue;
                }
                seen[u as usize] = true;
                // Consistent neighbours run the shared edge the other way (b, a).
                let n = out[u as usize];
                let same_way = (0..3).any(|m| n[m] == a && n[(m + 1) % 3] == b);
                if same_way {
                    out[u as usize] = [n[0], n[2], n[1]];
                }
                queue.push_back(u);
            }
        }
        // Only a closed part has an inside to face away from; an open one (a sheet, a
        // double-sided card whose two sides do not share manifold edges) keeps the
        // orientation the file gave it, whose sign does not depend on where the origin is.
        let closed = part.iter().all(|&t| {
            let tri = out[t as usize];
            (0..3).all(|k| {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                edges[&(a.min(b), a.max(b))].len() == 2
            })
        });
        let volume: f64 = part
            .iter()
            .map(|&t| {
                let [a, b, c] = out[t as usize].map(|i| positions[i as usize]);
                a.dot(b.cross(c))
            })
            .sum();
        if closed && volume < 0.0 {
            for &t in &part {
                let n = out[t as usize];
                out[t as usize] = [n[0], n[2], n[1]];
            }
        }
    }
    let flipped = out.iter().zip(tris).filter(|(a, b)| a != b).count();
    (out, flipped)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_agrees_with_a_search_of_every_triangle() {
        use crate::geom::shapes::uv_sphere;
        let (v, t) = uv_sphere(DVec3::new(0.1, 0.2, -0.3), 0.5, 12, 24);
        let wn = WindingNumber::new(&v, &t);
        let mut seed = 7u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..200 {
            let q = DVec3::new(rnd(), rnd(), rnd()) * 1.5;
            let (c, d) = wn.closest(q).expect("a surface");
            let brute = t
                .iter()
                .map(|tri| {
                    let tri = tri.map(|i| v[i as usize]);
                    (closest_on_triangle(q, &tri) - q).length()
                })
                .fold(f64::INFINITY, f64::min);
            // The same triangles, the same arithmetic: equal to rounding.
            assert!((d - brute).abs() < 1e-12, "{q}: {d} vs {brute}");
            assert!(((c - q).length() - d).abs() < 1e-12);
        }
        assert!(WindingNumber::new(&v, &[]).closest(DVec3::ZERO).is_none());
        // Signed: inside the sphere negative, the direction outward either way (radial
        // within the facets' angle: 12 rings and 24 segments leave the nearest facet
        // point up to about 11° off the radius; measured 10.6° from inside).
        let centre = DVec3::new(0.1, 0.2, -0.3);
        for q in [centre + DVec3::X * 0.3, centre + DVec3::X * 0.8] {
            let (_, d, out) = wn.signed_closest(q).expect("a surface");
            assert_eq!(d < 0.0, q == centre + DVec3::X * 0.3, "{q}: {d}");
            assert!(out.dot(DVec3::X) > 0.97, "{q}: {out}");
        }
    }

    #[test]
    fn closest_on_a_triangle_by_region() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        // Face, corner, edge and hypotenuse regions; equal to rounding.
        let near = |p: DVec3, want: DVec3| {
            let got = closest_on_triangle(p, &t);
            assert!(
                (got - want).length() < 1e-15,
                "{p}: {got} instead of {want}"
            );
        };
        near(DVec3::new(0.2, 0.3, 1.0), DVec3::new(0.2, 0.3, 0.0));
        near(DVec3::new(-1.0, -1.0, 0.0), DVec3::ZERO);
        near(DVec3::new(0.5, -1.0, 0.0), DVec3::new(0.5, 0.0, 0.0));
        near(DVec3::new(1.0, 1.0, 0.0), DVec3::new(0.5, 0.5, 0.0));
        // A degenerate triangle gives a finite point.
        let flat = [DVec3::ZERO, DVec3::ZERO, DVec3::X];
        assert!(closest_on_triangle(DVec3::new(0.5, 1.0, 0.0), &flat).is_finite());
    }
    use crate::geom::shapes::uv_sphere as sphere;

    fn brute(v: &[DVec3], t: &[[u32; 3]], q: DVec3) -> f64 {
        t.iter()
            .map(|t| triangle_solid_angle(&t.map(|i| v[i as usize]), q))
            .sum::<f64>()
            / (4.0 * PI)
    }

    #[test]
    fn a_closed_sphere_is_one_inside_and_zero_outside() {
        let (v, t) = sphere(DVec3::new(0.1, 0.2, -0.3), 1.0, 24, 48);
        let w = WindingNumber::new(&v, &t);
        for q in [
            DVec3::new(0.1, 0.2, -0.3),
            DVec3::new(0.6, 0.1, 0.0),
            DVec3::new(-0.5, 0.5, -0.4),
        ] {
            // Exact for a closed surface up to rounding; the tree's dipoles far away
            // are within 1 % (BETA = 4, first order).
            assert!((w.at(q) - 1.0).abs() < 1e-2, "{q}: {}", w.at(q));
            assert!((brute(&v, &t, q) - 1.0).abs() < 1e-9);
        }
        for q in [
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.1, 5.0, -0.3),
            DVec3::splat(-30.0),
        ] {
            assert!(w.at(q).abs() < 1e-2, "{q}: {}", w.at(q));
        }
    }

    #[test]
    fn invariants_flip_scale_and_the_tree_agree_with_the_exact_sum() {
        let (v, t) = sphere(DVec3::ZERO, 1.0, 16, 32);
        let flipped: Vec<[u32; 3]> = t.iter().map(|&[a, b, c]| [a, c, b]).collect();
        // A power of two: every rounding scales exactly, so the tree decides the same.
        let scaled: Vec<DVec3> = v.iter().map(|&p| p * 1024.0).collect();
        let (w, wf, ws) = (
            WindingNumber::new(&v, &t),
            WindingNumber::new(&v, &flipped),
            WindingNumber::new(&scaled, &t),
        );
        for k in 0..200 {
            let q = DVec3::new(
                (k as f64 * 0.37).sin() * 1.6,
                (k as f64 * 0.91).cos() * 1.6,
                (k as f64 * 0.13).sin() * 1.6,
            );
            let exact = brute(&v, &t, q);
            assert!(
                (w.at(q) - exact).abs() < 1e-2,
                "{q}: {} vs {exact}",
                w.at(q)
            );
            // Reversing every triangle negates w (up to the tree's error: the reversed
            // corners round their centroids differently); scaling space changes nothing.
            assert!((wf.at(q) + w.at(q)).abs() < 2e-2);
            assert!((ws.at(q * 1024.0) - w.at(q)).abs() < 1e-12);
        }
    }

    #[test]
    fn parts_are_oriented_outward_whatever_their_triangles_said() {
        let (v, t) = sphere(DVec3::ZERO, 1.0, 12, 24);
        let (v2, t2) = sphere(DVec3::new(3.0, 0.0, 0.0), 0.5, 8, 16);
        let off = v.len() as u32;
        let mut verts = v.clone();
        verts.extend(v2);
        let mut want = t.clone();
        want.extend(t2.iter().map(|tri| tri.map(|i| i + off)));
        // Every third triangle of the first sphere flipped, all of the second one.
        let mut given = want.clone();
        for (k, tri) in given.iter_mut().enumerate() {
            if (k < t.len() && k % 3 == 0) || k >= t.len() {
                *tri = [tri[0], tri[2], tri[1]];
            }
        }
        let (fixed, flipped) = orient_parts(&verts, &given);
        assert_eq!(fixed, want);
        assert_eq!(flipped, t.len().div_ceil(3) + t2.len());
        let w = WindingNumber::new(&verts, &fixed);
        assert!((w.at(DVec3::ZERO) - 1.0).abs() < 1e-2);
        assert!((w.at(DVec3::new(3.0, 0.1, 0.0)) - 1.0).abs() < 1e-2);
    }

    #[test]
    fn a_double_sided_sheet_still_cancels_wherever_the_origin_is() {
        // A square card and its back (the same corners, reversed): open parts keep the
        // file's sides, so the two cancel and no point near the card is inside.
        for shift in [
            DVec3::ZERO,
            DVec3::new(5.0, -3.0, 2.0),
            DVec3::new(-4.0, 1.0, -6.0),
        ] {
            let v: Vec<DVec3> = [
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ]
            .iter()
            .map(|p| DVec3::from_array(*p) + shift)
            .collect();
            let t = vec![[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]];
            let (o, _) = orient_parts(&v, &t);
            let w = WindingNumber::new(&v, &o);
            for q in [DVec3::new(0.5, 0.5, 0.05), DVec3::new(0.3, 0.6, -0.05)] {
                assert!(w.at(q + shift).abs() < 1e-9, "{shift}: {}", w.at(q + shift));
            }
        }
    }

    #[test]
    fn an_open_hemisphere_is_one_half_across_its_rim() {
        let (v, t) = sphere(DVec3::ZERO, 1.0, 24, 48);
        // Keep the upper half only (triangles whose vertices all have y >= 0).
        let upper: Vec<[u32; 3]> = t
            .iter()
            .copied()
            .filter(|tri| tri.iter().all(|&i| v[i as usize].y >= -1e-12))
            .collect();
        let w = WindingNumber::new(&v, &upper);
        // At the centre of the rim's disc the hemisphere subtends exactly half the sphere.
        assert!(
            (w.at(DVec3::ZERO) - 0.5).abs() < 1e-2,
            "{}",
            w.at(DVec3::ZERO)
        );
        assert!(w.at(DVec3::new(0.0, 0.5, 0.0)) > 0.5);
        assert!(w.at(DVec3::new(0.0, -0.5, 0.0)) < 0.5);
    }
}
