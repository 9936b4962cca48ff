//! Meshes as real assets are: several parts, open, overlapping, non-manifold, with
//! duplicated and flipped faces. Each procedural case with a known answer binds, keeps a
//! solid interior where a closed part is, embeds every vertex of every part, and a rigid
//! motion of all markers moves every vertex rigidly (to 1e-9 of the height, the
//! round-off bound of the hand's own rigid-motion test).

mod common;

use glam::{DQuat, DVec3};
use rigless::bench::characters::{demo_hand, hand_bind_params};
use rigless::character::bind_params::BindParams;
use rigless::character::mesh::MeshPart;
use rigless::character::procedural::Character;
use rigless::character::skeleton::{Joint, Skeleton};
use rigless::character::MarkerDef;
use rigless::geom::shapes::uv_sphere;
use rigless::markers::MarkerFrame;
use rigless::rig::bind::Rig;
use rigless::solve::frame::Solver;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Appends a part (its own vertices) to a character's mesh.
fn add_part(ch: &mut Character, (v, t): (Vec<DVec3>, Vec<[u32; 3]>)) {
    let off = ch.vertices.len() as u32;
    ch.parts.push(MeshPart {
        name: format!("part{}", ch.parts.len()),
        first_triangle: ch.triangles.len() as u32,
        triangle_count: t.len() as u32,
        first_vertex: off,
        vertex_count: v.len() as u32,
    });
    ch.vertices.extend(v);
    ch.triangles
        .extend(t.iter().map(|tri| tri.map(|i| i + off)));
}

/// The triangles of a part whose vertices all satisfy `keep` (an open piece of it).
fn piece(
    (v, t): (Vec<DVec3>, Vec<[u32; 3]>),
    keep: impl Fn(DVec3) -> bool,
) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let t = t
        .into_iter()
        .filter(|tri| tri.iter().all(|&i| keep(v[i as usize])))
        .collect();
    (v, t)
}

/// A flat open sheet of `n × n` quads spanning `origin + u·[0,1] + v·[0,1]`.
fn sheet(origin: DVec3, u: DVec3, v: DVec3, n: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let mut verts = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            verts.push(origin + u * (i as f64 / n as f64) + v * (j as f64 / n as f64));
        }
    }
    let at = |i: u32, j: u32| j * (n + 1) + i;
    let mut tris = Vec::new();
    for j in 0..n {
        for i in 0..n {
            tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    (verts, tris)
}

/// A closed ball (radius 0.1 m) with an open hemispherical shell (radius 0.13 m, the
/// upper half) around it, a two-joint skeleton through its centre along Y and four
/// markers on the ball.
fn ball_in_a_shell() -> Character {
    let joint = |name: &str, parent, y: f64| Joint {
        name: name.into(),
        parent,
        rest: DVec3::new(0.0, y, 0.0),
        limits: None,
        bend_axis: DVec3::X,
    };
    let skeleton = Skeleton::new(vec![
        joint("root", None, -0.07),
        joint("tip", Some(0), 0.07),
    ])
    .expect("a two-joint skeleton");
    let markers = [DVec3::X, -DVec3::X, DVec3::Z, DVec3::new(0.0, 0.6, 0.8)]
        .iter()
        .enumerate()
        .map(|(k, d)| MarkerDef {
            name: format!("m{k}"),
            rest: *d * 0.1,
            joint: Some(0),
        })
        .collect();
    let mut ch = Character {
        name: "ball".into(),
        vertices: Vec::new(),
        triangles: Vec::new(),
        skeleton,
        markers,
        skin: None,
        correspondences: Vec::new(),
        parts: Vec::new(),
    };
    add_part(&mut ch, uv_sphere(DVec3::ZERO, 0.1, 16, 32));
    add_part(
        &mut ch,
        piece(uv_sphere(DVec3::ZERO, 0.13, 16, 32), |p| p.y >= -1e-12),
    );
    ch
}

fn ball_params() -> BindParams {
    BindParams {
        cell_size_m: 0.02,
        skeleton_step_m: 0.018,
        w_shape: 1.0,
        w_marker: 30.0,
        w_skeleton: 1000.0,
        max_marker_distance_m: 0.03,
    }
}

/// Binds `ch`, checks every vertex is embedded, then moves all markers rigidly from a
/// cold start and returns the largest deviation of any vertex from the rigidly moved
/// mesh, over the height.
fn rigid_motion_error(ch: &Character, params: &BindParams) -> (Arc<Rig>, f64) {
    let rig = Arc::new(Rig::bind(ch, params).unwrap_or_else(|e| panic!("{}: {e}", ch.name)));
    assert_eq!(rig.stats.mesh_vertices, ch.vertices.len());
    let q = DQuat::from_axis_angle(DVec3::new(0.3, 1.0, -0.4).normalize(), 34f64.to_radians());
    let (c, t) = (DVec3::new(0.02, 0.1, -0.03), DVec3::new(0.05, 0.0, 0.1));
    let moved = |p: DVec3| c + q * (p - c) + t;
    let frame = MarkerFrame::all_present(0.0, ch.markers.iter().map(|m| moved(m.rest)).collect());
    let mut out = vec![DVec3::ZERO; ch.vertices.len()];
    let far = Instant::now() + Duration::from_secs(60);
    Solver::new(Arc::clone(&rig), common::tight_solver_params()).solve(&frame, far, &mut out);
    let worst = out
        .iter()
        .zip(&ch.vertices)
        .map(|(a, b)| (*a - moved(*b)).length())
        .fold(0.0, f64::max);
    (Arc::clone(&rig), worst / rig.height_m)
}

#[test]
fn a_ball_in_an_open_shell_is_solid_and_moves_rigidly() {
    let ch = ball_in_a_shell();
    let (rig, err) = rigid_motion_error(&ch, &ball_params());
    assert!(err < 1e-9, "rigid motion off by {err:e} of the height");
    // The ball alone, closed: the shell adds its own cells but the ball's interior is
    // solid either way (the cells inside the ball are all there: a hollow ball's cells
    // would be about its surface's only, far fewer than the ball's volume holds).
    let mut alone = ball_in_a_shell();
    let (v, t) = uv_sphere(DVec3::ZERO, 0.1, 16, 32);
    alone.vertices = v;
    alone.triangles = t;
    let solo = Rig::bind(&alone, &ball_params()).unwrap();
    let ball_cells = (4.0 / 3.0 * std::f64::consts::PI * 0.1f64.powi(3)) / 0.02f64.powi(3);
    assert!(
        solo.stats.cell_instances as f64 >= ball_cells,
        "{:?}",
        solo.stats
    );
    assert!(
        rig.stats.cell_instances > solo.stats.cell_instances,
        "{} vs {}",
        rig.stats.cell_instances,
        solo.stats.cell_instances
    );
}

#[test]
fn the_hand_with_eyes_a_sheet_and_bad_faces_binds_and_moves_rigidly() {
    let hand = demo_hand();
    let palm = hand.skeleton.joints[0].rest;
    let index_tip = hand
        .skeleton
        .joints
        .iter()
        .find(|j| j.name == "index_3")
        .expect("the hand has index_3")
        .rest;
    let params = hand_bind_params();
    let mut cases: Vec<(&str, Character)> = Vec::new();
    // Two open "eyes" (spheres with their front cap cut away) inside the palm.
    let mut eyes = hand.clone();
    for dx in [-0.01, 0.01] {
        let c = palm + DVec3::new(dx, 0.03, 0.0);
        add_part(
            &mut eyes,
            piece(uv_sphere(c, 0.006, 8, 12), |p| p.z < c.z + 0.004),
        );
    }
    cases.push(("eyes", eyes));
    // A flat open sheet hanging off the index finger's tip, 3 cm square.
    let mut flag = hand.clone();
    add_part(
        &mut flag,
        sheet(
            index_tip,
            DVec3::new(0.03, 0.0, 0.0),
            DVec3::new(0.0, 0.0, 0.03),
            6,
        ),
    );
    cases.push(("sheet", flag));
    // A closed "hat" hanging in the air 8 cm beyond the index finger's tip: a part of
    // the control mesh of its own, pinned to the motion of the joint nearest it.
    let mut hat = hand.clone();
    let above = index_tip + (index_tip - palm).normalize() * 0.08;
    add_part(&mut hat, uv_sphere(above, 0.008, 8, 12));
    cases.push(("hat in the air", hat));
    // Every 7th triangle flipped and the first 50 duplicated.
    let mut bad = hand.clone();
    for (k, t) in bad.triangles.iter_mut().enumerate() {
        if k % 7 == 0 {
            *t = [t[0], t[2], t[1]];
        }
    }
    let dup: Vec<[u32; 3]> = bad.triangles[..50].to_vec();
    bad.triangles.extend(dup);
    cases.push(("flipped and duplicated faces", bad));
    let (_, base) = rigid_motion_error(&hand, &params);
    for (name, ch) in cases {
        let (rig, err) = rigid_motion_error(&ch, &params);
        assert!(
            err < 1e-9,
            "{name}: rigid motion off by {err:e} of the height"
        );
        let free = usize::from(name == "hat in the air");
        assert_eq!(rig.stats.free_parts, free, "{name}");
        println!(
            "{name}: {} control vertices, rigid error {err:.1e} of the height (the hand alone: {base:.1e})",
            rig.stats.control_vertices
        );
    }
}
