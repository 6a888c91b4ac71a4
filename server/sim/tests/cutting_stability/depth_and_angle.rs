//! Cuts by depth and blade angle: a second deeper pass, sawing deeper or to and fro, stabs
//! (alone and followed by a slide), raked and tilted blades, a stab on a slope.

use super::*;

#[test]
fn a_second_deeper_pass_opens_only_what_lies_below_the_first() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    // 5 mm deep from x = -30 to 0 mm, out, back over the start, and 10 mm deep along the
    // same line: a surgeon deepening an incision.
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (2.0, [-30.0, 0.0, top - 5.0]),
        (8.0, [0.0, 0.0, top - 5.0]),
        (10.0, [0.0, 0.0, top + 5.0]),
        (12.0, [-30.0, 0.0, top + 5.0]),
        (15.0, [-30.0, 0.0, top - 10.0]),
        (21.0, [0.0, 0.0, top - 10.0]),
        (24.0, [0.0, 0.0, top + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    // The second pass enters the incision: no capsule to rupture.
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    // Cutting along the first pass, the edge's upper 5 mm runs in the cut already made:
    // the fracture term is J_c × the 5 mm below it, not J_c × 10 mm (2.3–2.8 N, what the
    // first pass would feel at that depth) — less the in-plane tolerance just under the
    // old floor, where a sample counts as on it (the blade's thickness and a twentieth of
    // a spacing, 0.87 mm here): ≈ 1.08 N with friction.
    let plane_tolerance = scene.spec.tool.blade_thickness_m + 0.05 * scene.model.lattice.spacing;
    let new_depth = 0.005 - plane_tolerance;
    let expected = spec.toughness_n_per_m * new_depth + spec.friction_n;
    for k in 16_500..20_500 {
        let f = trace.ticks.force[k];
        assert!(
            f.x < 0.0 && (f.norm() - expected).abs() < 0.1 * expected,
            "tick {k}: {f:?}, expected about {expected} N"
        );
    }
    // The drawn walls go down with it: as deep as the second pass along the middle of the
    // cut (they used to keep the first pass's 5 mm).
    assert_walls_reach(&sim, &scene, &trace);
    assert_sound_surface(&sim);
}

/// The drawn wound walls reach as deep as the blade's edge went (±1 mm) at x = −20 and
/// −10 mm along y = 0, both in the tissue's own frame (rest space): under gravity the organ
/// sags on into the wound after it is cut.
fn assert_walls_reach(sim: &Simulation, scene: &BuiltScene, trace: &Trace) {
    let corners = wall_corners_mm(sim);
    for x in [-20.0, -10.0] {
        let (tip, floor) = blade_floor_near(trace, x).expect("the blade passed");
        assert_edge_mapped(scene, tip, floor);
        let deepest = deepest_near(&corners, x).map_or(f64::INFINITY, |p| p.z);
        assert!(
            (deepest - floor.z).abs() < 1.0,
            "walls at x = {x} mm reach z = {deepest:.2} mm at rest, the edge went to z = \
             {:.2} mm",
            floor.z
        );
    }
}

/// The edge's tip at rest, `floor`, is as deep below the organ's rest top as the tip was
/// below the top of the organ as it rested (`tip`, world; both mm), within 1 mm (the
/// weight's strain, a few per cent of the depth): the edge the walls are compared with is
/// where the blade went.
fn assert_edge_mapped(scene: &BuiltScene, tip: Vec3, floor: Vec3) {
    let in_world = top_mm(scene, tip.x, tip.y) - tip.z;
    let at_rest = rest_top_mm(scene, floor.x, floor.y) - floor.z;
    println!(
        "edge at x = {:.1} mm: {in_world:.2} mm deep in the world, {at_rest:.2} at rest",
        floor.x
    );
    assert!(
        (in_world - at_rest).abs() < 1.0,
        "at x = {:.1} mm the tip went {in_world:.2} mm below the resting top, its edge \
         {at_rest:.2} mm below the rest top",
        floor.x
    );
}

/// Each in-tissue tick's tip (world) and the edge's tip in rest space (mm).
fn edge_ticks(trace: &Trace) -> impl Iterator<Item = (Vec3, Vec3)> + '_ {
    let ticks = &trace.ticks;
    ticks
        .tip
        .iter()
        .zip(&ticks.edge_rest)
        .filter_map(|(t, e)| Some(((*t)? * 1e3, (*e)?[0] * 1e3)))
}

/// The rest-space x (mm) of the tissue the tip was in as it passed world x `x_mm`: read on
/// the in-tissue tick whose tip came nearest. The organ resting under gravity is not where
/// its rest shape is (the liver is carried 3–4 mm along x as it settles on its tray).
fn rest_x_mm(trace: &Trace, x_mm: f64) -> f64 {
    let (tip, edge) = edge_ticks(trace)
        .min_by(|a, b| (a.0.x - x_mm).abs().total_cmp(&(b.0.x - x_mm).abs()))
        .expect("the blade was in the tissue");
    x_mm + edge.x - tip.x
}

/// Where the blade's edge went lowest within 2 mm of rest x `x`: the tip then (world) and
/// the edge's tip (rest space), in mm.
fn blade_floor_near(trace: &Trace, x: f64) -> Option<(Vec3, Vec3)> {
    edge_ticks(trace)
        .filter(|(_, e)| (e.x - x).abs() < 2.0)
        .min_by(|a, b| a.1.z.total_cmp(&b.1.z))
}

/// Top of the organ's rest shape at (x, y) in mm.
fn rest_top_mm(scene: &BuiltScene, x: f64, y: f64) -> f64 {
    scalpel_sim::pipeline::vertical_extent(&scene.model.surface, x * 1e-3, y * 1e-3)
        .expect("inside the organ")
        .0
        * 1e3
}

#[test]
fn sawing_deeper_in_one_stroke() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    // 5 mm deep from x = -30 to 0 mm, back to -30 going down to 10 mm, forward to 0 at
    // 10 mm, and out: one stroke that deepens its own cut.
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (2.0, [-30.0, 0.0, top - 5.0]),
        (8.0, [0.0, 0.0, top - 5.0]),
        (14.0, [-30.0, 0.0, top - 10.0]),
        (20.0, [0.0, 0.0, top - 10.0]),
        (22.0, [0.0, 0.0, top + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert_one_incision(&sim);
    assert_walls_reach(&sim, &scene, &trace);
    assert_sound_surface(&sim);
}

/// The wall corners of the drawn wound, in rest space (mm).
fn wall_corners_mm(sim: &Simulation) -> Vec<Vec3> {
    let surface = sim.current_surface();
    corners_of_kind(&surface.rest_mesh(), &surface.kinds, FaceKind::Wall)
        .map(|p| p * 1e3)
        .collect()
}

/// The lowest of `corners` (mm) within 2 mm of `x`.
fn deepest_near(corners: &[Vec3], x: f64) -> Option<&Vec3> {
    corners
        .iter()
        .filter(|p| (p.x - x).abs() < 2.0)
        .min_by(|a, b| a.z.total_cmp(&b.z))
}

/// The smallest and largest x of `points`.
fn x_span(points: &[Vec3]) -> (f64, f64) {
    points.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
        (lo.min(p.x), hi.max(p.x))
    })
}

/// The run opened exactly one incision, and no piece of it was refused.
fn assert_one_incision(sim: &Simulation) {
    let incisions = sim.incisions().expect("cutting scene");
    assert_eq!(
        (incisions.incisions, incisions.refused),
        (1, 0),
        "{incisions:?}"
    );
}

#[test]
fn a_stab_slits_as_wide_as_the_blade() {
    // The shoulder, whose finer top draws an 8 mm slit with room for its lips (the liver's
    // 17.7 mm surface edges are coarse for it).
    // Its top is flat behind x = -12 mm.
    let scene = scene("shoulder");
    let (x, top) = (-12.0, top_mm(&scene, -12.0, 0.0));
    let width_mm = scene.spec.tool.blade_width_m * 1e3;
    // Straight down 10 mm at 5 mm/s, held, and straight out: the blade's flat (its back
    // toward −x) slits the tissue behind the edge. Nothing used to be cut: the edge moving
    // along itself sweeps nothing.
    let s = script(&[
        (0.0, [x, 0.0, top + 5.0]),
        (3.0, [x, 0.0, top - 10.0]),
        (3.5, [x, 0.0, top - 10.0]),
        (6.5, [x, 0.0, top + 5.0]),
        // Again into the same slit: it is open, the capsule does not rupture again, and
        // the blade opens no new crack above the first one's floor.
        (7.0, [x, 0.0, top + 5.0]),
        (10.0, [x, 0.0, top - 10.0]),
        (13.0, [x, 0.0, top + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 200);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    let friction = (1.0 + scene.spec.force.ripple_amplitude) * scene.spec.force.friction_n;
    // Friction only, until the tip is within the end-of-cut tolerance (about a
    // millimetre) of the first stab's floor.
    for k in 7000..10000 {
        let (f, depth) = (trace.ticks.force[k].norm(), trace.ticks.depth[k]);
        if depth <= 8.5e-3 {
            assert!(
                f <= friction + 1e-9,
                "tick {k}: {f} N {depth} m deep going in again"
            );
        }
    }
    assert_dent_released(&sim);
    let cutting = sim.cutting().expect("cutting scene");
    // Pairs across the slit are cut, or fading near its edges (crack fronts).
    let (cut, fading) = (cutting.pairs_removed_total, cutting.transparent_pairs());
    println!("{cut} pairs cut, {fading} fading");
    assert!(
        cutting.sigma.triangles.len() > 4 && cut + fading > 20,
        "{} triangles of Σ, {cut} pairs cut, {fading} fading",
        cutting.sigma.triangles.len(),
    );
    assert_one_incision(&sim);
    // The slit runs from the edge back one blade width, as deep as the blade went at the
    // edge and shallower behind it (the point narrows at 45°); in rest space, where the
    // muscle hanging on its bone has carried it.
    let walls = wall_corners_mm(&sim);
    let span = x_span(&walls);
    let at = rest_x_mm(&trace, x);
    assert!(
        (span.0 - (at - width_mm)).abs() < 2.0 && (span.1 - at).abs() < 2.0,
        "walls from x = {:.1} to {:.1} mm, the edge went in at x = {at:.1} mm at rest",
        span.0,
        span.1
    );
    let top_at_rest = rest_top_mm(&scene, at, 0.0);
    let floor = top_at_rest - blade_floor_near(&trace, at).expect("the blade went in").1.z;
    let deepest = walls
        .iter()
        .filter(|p| (p.x - at).abs() < 2.0)
        .map(|p| top_at_rest - p.z)
        .fold(0.0, f64::max);
    assert!(
        (deepest - floor).abs() < 1.5,
        "walls {deepest} mm deep at the edge, which went {floor} mm deep"
    );
    let shallow = walls
        .iter()
        .filter(|p| p.x < at - width_mm + 2.0)
        .map(|p| rest_top_mm(&scene, p.x, p.y) - p.z)
        .fold(0.0, f64::max);
    assert!(
        shallow < deepest - 4.0,
        "walls {shallow} mm deep at the back"
    );
    assert_sound_surface(&sim);
}

#[test]
fn a_stab_then_a_slide_is_one_incision() {
    let scene = scene("liver");
    let (x, top) = (-30.0, top_mm(&scene, -30.0, 0.0));
    let width_mm = scene.spec.tool.blade_width_m * 1e3;
    // In point first, then forward 25 mm (edge first) and out: one incision from a blade
    // width behind the stab to the end.
    let s = script(&[
        (0.0, [x, 0.0, top + 5.0]),
        (3.0, [x, 0.0, top - 10.0]),
        (8.0, [x + 25.0, 0.0, top - 10.0]),
        (11.0, [x + 25.0, 0.0, top + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 200);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert_one_incision(&sim);
    let walls = wall_corners_mm(&sim);
    let span = x_span(&walls);
    let (start, end) = (rest_x_mm(&trace, x), rest_x_mm(&trace, x + 25.0));
    assert!(
        (span.0 - (start - width_mm)).abs() < 2.0 && (span.1 - end).abs() < 2.5,
        "walls from x = {:.1} to {:.1} mm, the path from {start:.1} to {end:.1} at rest",
        span.0,
        span.1
    );
    assert_sound_surface(&sim);
}

#[test]
fn sawing_to_and_fro_in_a_cut() {
    let scene = scene("liver");
    let top = top_mm(&scene, -20.0, 0.0);
    let spec = &scene.spec.force;
    let z = top - 10.0;
    // In at x = -20 mm, forward to -10, back past the start to -30, forward to -15.
    // (Going in, the blade's flat slits 8 mm behind the edge, to -28 mm.)
    let s = script(&[
        (0.0, [-20.0, 0.0, top + 5.0]),
        (3.0, [-20.0, 0.0, z]),
        (5.0, [-10.0, 0.0, z]),
        (9.0, [-30.0, 0.0, z]),
        (12.0, [-15.0, 0.0, z]),
        (14.0, [-15.0, 0.0, top + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    let friction = (1.0 + spec.ripple_amplitude) * spec.friction_n;
    let x_at = |k: usize| s.pose_at(k as f64 * TICK_S).tip_m.x * 1e3;
    for (k, f) in trace.ticks.force.iter().enumerate() {
        let x = x_at(k);
        match k {
            // Back over the first stroke, from 3 mm after the turn to 1.5 mm before its
            // start: friction only. (The fracture term used to come back 3 mm before
            // either end of a cut.)
            5500..7000 if x < -13.0 && x > -18.5 => {
                assert!(
                    f.x > 0.0 && f.norm() <= friction + 1e-9,
                    "tick {k} at {x}: {f:?}"
                );
            }
            // Behind where the blade went in (the slit its flat opened going down, its
            // floor rising at 45° from 10 mm deep at -20 mm to 2 mm at -28 mm) and past
            // it, the blade moves spine first: it cannot cut. Its spine pushes the tissue
            // under the slit's floor and past it, tearing it where it has indented it as
            // far as a blunt press ruptures it: friction and that push, far below what
            // cutting takes (J_c·d + friction ≈ 2.2 N; the edge used to sweep Σ backward
            // at that force).
            7000..9000 if x < -20.5 => {
                assert!(f.x > 0.0 && f.norm() < 0.5, "tick {k} at {x}: {f:?}");
            }
            // Forward over all of it: friction only, and Σ does not grow.
            9500..12000 => {
                assert!(
                    f.x < 0.0 && f.norm() <= friction + 1e-9,
                    "tick {k} at {x}: {f:?}"
                );
            }
            _ => {}
        }
    }
    assert_eq!(trace.ticks.sigma[9500], trace.ticks.sigma[11999]);
    // The wound runs from where the blade went back to, past its slit, to where it went
    // forward to: nothing drawn beyond (a slit kept from the first entry used to be drawn
    // behind the path's new start).
    let span = x_span(&wall_corners_mm(&sim));
    let (back, forward) = (rest_x_mm(&trace, -30.0), rest_x_mm(&trace, -10.0));
    assert!(
        (span.0 - back).abs() < 2.5 && (span.1 - forward).abs() < 2.5,
        "walls from x = {:.1} to {:.1} mm, the path from {back:.1} to {forward:.1} at rest",
        span.0,
        span.1
    );
    // One incision along all of it: the path folded back on itself is no path (the
    // incision used to be refused: "a lip crosses the region boundary").
    assert_one_incision(&sim);
    assert_sound_surface(&sim);
}

/// Down at x = −30 mm from 5 mm above `top_mm` to the tip height `z_mm` in 3 s, 30 mm along
/// +x in 6 s and out in 3 s, the blade held as `pose` has it at each tip position (m).
fn in_along_and_out(top_mm: f64, z_mm: f64, pose: impl Fn(Vec3) -> ToolPose) -> CutScript {
    let frame = |t_s: f64, tip: [f64; 3]| Keyframe {
        t_s,
        pose: pose(Vec3::from(tip) * 1e-3),
    };
    CutScript {
        keyframes: vec![
            frame(0.0, [-30.0, 0.0, top_mm + 5.0]),
            frame(3.0, [-30.0, 0.0, z_mm]),
            frame(9.0, [0.0, 0.0, z_mm]),
            frame(12.0, [0.0, 0.0, top_mm + 5.0]),
        ],
        description: "in, along and out".into(),
    }
}

#[test]
fn a_raked_blade_cuts_by_its_vertical_depth() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    let z = top - 10.0;
    // A scalpel held the usual way, handle back at 45°, tip first.
    let back = Vec3::new(-1.0, 0.0, 1.0).normalize();
    let s = in_along_and_out(top, z, |tip| ToolPose::pointing(tip, back));
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    // The new crack per millimetre forward is the vertical depth v the edge sweeps, with
    // what the tip slits ahead of it (the blade's 8 mm width × cos 45°) in quadrature: not
    // the √2 v of edge in the tissue, which the force used to read (at x = -20 mm: 3.0 N,
    // at the device's limit, for 2.2 N of vertical cut).
    let j = spec.toughness_n_per_m;
    for k in (5000..8500).step_by(100) {
        let x = s.pose_at(k as f64 * TICK_S).tip_m.x * 1e3;
        let v = trace.ticks.depth[k] / 2f64.sqrt();
        let slit = (scene.spec.tool.blade_width_m / (2f64.sqrt() * v)).min(1.0);
        let expected = j * 2f64.sqrt() * v * (0.5 + 0.5 * slit * slit).sqrt() + spec.friction_n;
        let f = trace.ticks.force[k];
        assert!(
            f.x < 0.0
                && (f.norm() - expected).abs() < 0.05 * expected
                && f.norm() < 0.9 * (j * 2f64.sqrt() * v + spec.friction_n),
            "tick {k} at {x} mm: {f:?}, expected about {expected} N"
        );
    }
    // The drawn walls reach the blade's vertical depth, not the length of edge in the
    // tissue (they went √2 × as deep, along the surface normal).
    assert_walls_reach(&sim, &scene, &trace);
    assert_sound_surface(&sim);
}

#[test]
fn a_blade_tilted_sideways_cuts_leaning_walls() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    // The edge leans 30° toward −y, the tip 8.66 mm below the top (10 mm of edge in the
    // tissue): Σ leans, and so must the walls drawn in it — they went straight down the
    // surface normal from where the edge enters, 5 mm off the tip's track.
    let lean = 30f64.to_radians();
    let back = Vec3::new(0.0, -lean.sin(), lean.cos());
    let z = top - 10.0 * lean.cos();
    let s = in_along_and_out(top, z, |tip| ToolPose::facing(tip, back, Vec3::x()));
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert_one_incision(&sim);
    let corners = wall_corners_mm(&sim);
    for x in [-20.0, -10.0] {
        // In rest space, where the tip was in the tissue as it passed x.
        let at = rest_x_mm(&trace, x);
        let (_, tip) = blade_floor_near(&trace, at).expect("the blade passed");
        let near: Vec<&Vec3> = corners.iter().filter(|p| (p.x - at).abs() < 2.0).collect();
        let deepest = deepest_near(&corners, at).expect("walls");
        assert!(
            (deepest.z - tip.z).abs() < 1.0 && (deepest.y - tip.y).abs() < 1.0,
            "where the tip passed x = {x} mm the walls' deepest corner is {deepest:?} at \
             rest, the tip's {tip:?}"
        );
        // Every wall corner lies in Σ, within the opening of it.
        let normal = Vec3::new(0.0, lean.cos(), lean.sin());
        let opening = sim.incisions().expect("cutting scene").opening_m * 1e3;
        for p in &near {
            let off = (*p - tip).dot(&normal).abs();
            assert!(off < opening + 0.5, "wall corner {p:?} is {off} mm off Σ");
        }
    }
    assert_sound_surface(&sim);
}

#[test]
fn a_stab_on_a_sloping_start_leaves_the_wound_its_full_opening() {
    // The shoulder's default stroke goes in point first where its top slopes, so the skin
    // region around the slit is narrow there. The lips' room used to be the path's nearest
    // approach to the region's boundary anywhere, and the narrow start capped the whole
    // wound: half-opening 2.35 mm in this run (2.09 mm in `scalpel cut shoulder`) where
    // k_open × 10 mm deep was 3 mm (physics.md §5.1, w_o = min(0.15 L, k_open d)). The
    // simulation's incisions are closed in rest space now (`IncisionParams::closed`): the
    // hairline the lips keep is k_open × depth there too.
    let scene = scene("shoulder");
    let script = CutScript::default_for(&scalpel_sim::pipeline::start_surface(&scene))
        .expect("default stroke");
    let (sim, trace) = calm_run(&scene, &script, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert_one_incision(&sim);
    let incisions = sim.incisions().expect("cutting scene");
    let wanted = scalpel_sim::cut::IncisionParams::closed().gape_factor * 0.010;
    assert!(
        incisions.opening_m > 0.9 * wanted,
        "half-opening {} mm, k_open × depth {} mm",
        incisions.opening_m * 1e3,
        wanted * 1e3
    );
    assert_sound_surface(&sim);
}
