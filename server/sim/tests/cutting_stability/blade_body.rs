//! The blade as a body the tissue pushes back on (issue 40, items 2 and 3): the force on
//! the tool before rupture is the tissue's reaction, so it scales with the tissue's
//! stiffness and turns with the blade's motion.

use super::*;
use scalpel_sim::math::Mat3;
use scalpel_sim::pipeline::tissue_force::MAX_LOCAL_STIFFNESS_N_PER_M;

/// Presses the blade `depth_mm` into the liver's top at x = −30 mm at 5 mm/s, edge up,
/// then moves it by `then` (mm) over 0.2 s; returns the force on the tool at the end of
/// the press and at the end of the move (it stays before rupture).
fn press_then_move(scene: &BuiltScene, depth_mm: f64, then: [f64; 3]) -> [Vec3; 2] {
    let [(press, _), (moved, _)] = press_then_move_model(scene, 1.0, depth_mm, then);
    [press, moved]
}

/// [`press_then_move`], with the stiffness of the haptic loop's local model (∂f/∂x, N/m)
/// beside each force.
fn press_then_move_model(
    scene: &BuiltScene,
    fault: f64,
    depth_mm: f64,
    then: [f64; 3],
) -> [(Vec3, Mat3); 2] {
    let mut sim = Simulation::new(scene);
    let mut top = top_mm(scene, -30.0, 0.0);
    // An instructor's tissue-stiffness fault, before the blade arrives: the organ rests
    // elsewhere, and the blade starts from its top there.
    if fault != 1.0 {
        sim.handle_stiffness_factor(fault);
        sim.handle_tool_pose(None);
        for _ in 0..FAULT_SETTLE_TICKS {
            sim.tick(TICK_S, &mut NoClock);
        }
        let (drawn, _) = sim.current_surface().drawn();
        top = scalpel_sim::pipeline::vertical_extent(&drawn, -0.030, 0.0)
            .unwrap()
            .0
            * 1e3;
    }
    let (start, down) = ([-30.0, 0.0, top + 1.0], [-30.0, 0.0, top - depth_mm]);
    let t_down = (1.0 + depth_mm) / 5.0;
    let moved = [down[0] + then[0], down[1] + then[1], down[2] + then[2]];
    let s = script(&[(0.0, start), (t_down, down), (t_down + 0.2, moved)]);
    let ticks = (s.duration_s() / TICK_S).round() as usize;
    let mut at_press = (Vec3::zeros(), Mat3::zeros());
    for k in 0..=ticks {
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        let r = sim.tick(TICK_S, &mut NoClock);
        let cut = r.cut.as_ref().unwrap();
        assert_ne!(
            cut.force.phase,
            CutPhase::Cutting,
            "tick {k}: {:?}",
            cut.force
        );
        assert!(!r.solver.diverged && r.solver.rollbacks == 0, "tick {k}");
        let model = sim.local_force_model().stiffness_n_per_m;
        if k == (t_down / TICK_S).round() as usize {
            at_press = (r.tool_force_n, model);
        }
        if k == ticks {
            return [at_press, (r.tool_force_n, model)];
        }
    }
    unreachable!()
}

/// Ticks the organ is given to come to rest after a stiffness fault (its settling under
/// gravity takes 1.9 s from its rest shape).
const FAULT_SETTLE_TICKS: usize = 2000;

/// How far the blade is pushed sideways after a press (mm): within what the tissue under
/// its edge holds before it slips.
const SIDEWAYS_MM: f64 = 0.4;

/// The liver with `factor` × its Young's modulus, resting on its supports under gravity
/// (each stiffness settled on its own: a body whose stiffness changes sags by another
/// amount).
fn liver_at(factor: f64) -> BuiltScene {
    let mut spec = builtin("liver").unwrap();
    spec.material.youngs_modulus_pa *= factor;
    cutting_scene(spec)
}

/// The same, linear (β = 0).
fn linear_liver_at(factor: f64) -> BuiltScene {
    let mut spec = builtin("liver").unwrap();
    spec.material.youngs_modulus_pa *= factor;
    spec.material.stiffening = 0.0;
    cutting_scene(spec)
}

/// The linear liver at 2.5, 5, 10 and 20 kPa, resting on its tray, pressed 2 mm: the
/// tissue's push back grows in proportion to its stiffness (0.092, 0.179, 0.341, 0.655 N).
/// (The formula's was the same at any stiffness.) Linear, because the built-in liver's
/// strain-stiffening (β = 10) is reached by its sag under its own weight, which goes as
/// 1/E: 0.098, 0.185, 0.349, 0.667 N, each doubling 5–6 % short of twice. The points the cutting stage keeps asleep hold
/// the awake region around the blade; resting on its tray the whole liver presses alike
/// (`a_stiff_mode_press_is_felt`; docs/CUTTING-DECISIONS.md, "The sleeping region clamps
/// the press").
#[test]
fn the_press_force_scales_with_the_tissue_stiffness() {
    let forces: Vec<f64> = [1.0, 2.0, 4.0, 8.0]
        .iter()
        .map(|&k| press_then_move(&linear_liver_at(k), 2.0, [0.0; 3])[0].z)
        .collect();
    println!("2 mm press at 1, 2, 4, 8 × E: {forces:?} N");
    assert!(forces[0] > 0.01, "{forces:?}");
    // Each doubling of E doubles the push within 5 %; over the eightfold range within
    // 15 % (0.89 of proportional at 8 × E): the organ's own weight pre-strains it in
    // proportion to 1/E, which no stiffness scales away (the probe's table in
    // docs/BENCHMARKS.md shows the same at 2.5 kPa).
    for pair in forces.windows(2) {
        assert!((pair[1] / (2.0 * pair[0]) - 1.0).abs() < 0.05, "{forces:?}");
    }
    for (i, f) in forces.iter().enumerate() {
        let per_factor = f / (forces[0] * f64::from(1 << i));
        assert!((per_factor - 1.0).abs() < 0.15, "{forces:?}");
    }
}

/// A tissue-stiffness fault on the liver resting under its weight presses like a liver
/// that stiff, once the organ has come to rest at its new stiffness (every point is woken
/// for it). Before, the points asleep held the old sag and the region the blade woke sprang
/// into it: 0.001 N at 4 × E where that liver gives 0.34 N. (With a residual tension the
/// two part further, 6.5 % at 0.5 × E against 3.8 % here: the faulted organ settles again
/// dynamically on its tray with friction, the built one by a frictionless static solve.)
#[test]
fn a_stiffness_fault_presses_like_that_stiffness() {
    for factor in [0.5, 4.0] {
        let [(faulted, _), _] = press_then_move_model(&scene("liver"), factor, 2.0, [0.0; 3]);
        let stiffer = liver_at(factor);
        let built = press_then_move(&stiffer, 2.0, [0.0; 3])[0];
        println!("{factor} × E: fault {faulted:?} N, built {built:?} N");
        assert!(
            (faulted.z / built.z - 1.0).abs() < 0.05,
            "{factor} × E: {faulted:?} against {built:?}"
        );
    }
}

/// Pressed 2 mm in and then pushed 0.4 mm sideways across its flats, the blade feels the
/// tissue push back sideways: against the move, a good part of the press force. (Pushed
/// further, the liver resting under its weight lets the tissue under the edge slip: 0.018 N
/// back at 0.5 mm, 0.012 N at 1 mm.)
#[test]
fn a_blade_pushed_sideways_is_pushed_back_sideways() {
    let scene = scene("liver");
    // The scripts' blade has its back toward −x: its flats face ±y.
    let [press, moved] = press_then_move(&scene, 2.0, [0.0, SIDEWAYS_MM, 0.0]);
    println!("pressed {press:?} N, then {SIDEWAYS_MM} mm along +y: {moved:?} N");
    assert!(press.z > 0.01 && press.y.abs() < 0.1 * press.z, "{press:?}");
    assert!(moved.y < -0.15 * press.z, "{moved:?}");
}

/// In stiff mode (projective dynamics, the whole body, the blade's faces in its global
/// solve) the press is felt too, and as the explicit tick feels it: 0.106 N at 2 mm on the
/// liver resting on its tray, against 0.092 N in the explicit integrator with the far
/// points asleep (docs/CUTTING-DECISIONS.md, "The sleeping region clamps the press").
#[test]
fn a_stiff_mode_press_is_felt() {
    let mut spec = builtin("liver").unwrap();
    spec.features.stiff_mode = true;
    let scene = cutting_scene(spec);
    let explicit = press_then_move(&super::scene("liver"), 2.0, [0.0; 3])[0].z;
    let stiff = press_then_move(&scene, 2.0, [0.0; 3])[0];
    println!("2 mm press, stiff mode: {stiff:?} N (explicit {explicit:.4} N)");
    assert!(stiff.iter().all(|c| c.is_finite()));
    // The organ resting on its tray, the explicit tick's clamped region and stiff mode's
    // whole body press alike: 9 % apart at the built-in spacing, projective dynamics a
    // little stiffer on a coarse lattice (0.3 % at 12k points, docs/CUTTING-DECISIONS.md);
    // floating, the clamp made it 2.1 × as stiff.
    assert!(
        (explicit / stiff.z - 1.0).abs() < 0.25,
        "{stiff:?} {explicit}"
    );
}

/// In stiff mode the faces hold the tissue with friction too: pressed 2 mm and then drawn
/// 0.4 mm back along its length (its spine first, −x), the blade drags the tissue under
/// its tip with it, and the tissue holds it back — by friction at most μ = 0.2 × the press
/// (0.098 × it measured; the spine's push on what lies behind it would add to that).
#[test]
fn stiff_mode_faces_hold_with_friction() {
    let mut spec = builtin("liver").unwrap();
    spec.features.stiff_mode = true;
    let scene = cutting_scene(spec);
    let [press, drawn] = press_then_move(&scene, 2.0, [-0.4, 0.0, 0.0]);
    println!("stiff mode: pressed {press:?} N, drawn back 0.4 mm: {drawn:?} N");
    assert!(
        drawn.x > 0.05 * drawn.z && drawn.x < 0.2 * drawn.z,
        "{drawn:?}"
    );
}

/// The haptic loop's local model is the tissue's stiffness seen at the blade: a press
/// teaches it the stiffness along the press (in proportion to E), a sideways push the
/// stiffness across; it stays symmetric, pushes back (negative semi-definite ∂f/∂x) and
/// within what the device renders stably.
#[test]
fn the_local_model_is_the_tissue_stiffness() {
    let scene = scene("liver");
    let bounded = |k: &Mat3| {
        let eig = k.symmetric_eigen().eigenvalues;
        (k - k.transpose()).norm() < 1e-9 * k.norm().max(1.0)
            && eig
                .iter()
                .all(|&l| (-MAX_LOCAL_STIFFNESS_N_PER_M - 1e-6..=1e-6).contains(&l))
    };
    let [(f1, k1), (_, k1_held)] = press_then_move_model(&scene, 1.0, 2.0, [0.0; 3]);
    let [(_, k4), _] = press_then_move_model(&liver_at(4.0), 1.0, 2.0, [0.0; 3]);
    let [_, (moved, k_side)] = press_then_move_model(&scene, 1.0, 2.0, [0.0, SIDEWAYS_MM, 0.0]);
    println!("2 mm press: f {f1:?} N, K {k1:?}; held 0.2 s: {k1_held:?}");
    println!("4 × E: K {k4:?}");
    println!("then {SIDEWAYS_MM} mm along +y: f {moved:?} N, K {k_side:?}");
    for k in [&k1, &k1_held, &k4, &k_side] {
        assert!(bounded(k), "{k:?}");
    }
    // Along the press (z), the secant of a press whose force grows with depth.
    assert!(-k1[(2, 2)] > 0.5 * f1.z / 0.002, "{k1:?} {f1:?}");
    let ratio = k4[(2, 2)] / k1[(2, 2)];
    assert!((2.5..6.0).contains(&ratio), "4 × E gives {ratio:.2} × K");
    // Only a sideways move teaches the sideways stiffness.
    assert!(-k_side[(1, 1)] > 5.0 * (-k1[(1, 1)]).max(1.0), "{k_side:?}");
}

/// Cuts the liver at `factor` × E, 8 mm deep along +x (edge first), steps `step_mm`
/// across the flats (+y) over 5 mm of travel, then goes straight on; returns the mean
/// force across the flats (N, along +y) over 1–4 mm of travel after the step.
fn lateral_after_step(factor: f64, step_mm: f64) -> f64 {
    let scene = linear_liver_at(factor);
    let mut sim = Simulation::new(&scene);
    let top = top_mm(&scene, -30.0, 0.0);
    let z = top - 8.0;
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 1.0]),
        (1.8, [-30.0, 0.0, z]),
        (3.8, [-10.0, 0.0, z]),
        (4.3, [-5.0, step_mm, z]),
        (4.8, [0.0, step_mm, z]),
    ]);
    let (from, to) = ((4.4 / TICK_S) as usize, (4.7 / TICK_S) as usize);
    let mut sum = 0.0;
    for k in 0..=to {
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        let r = sim.tick(TICK_S, &mut NoClock);
        assert!(!r.solver.diverged && r.solver.rollbacks == 0, "tick {k}");
        if k >= from {
            assert_eq!(r.cut.as_ref().unwrap().force.phase, CutPhase::Cutting);
            sum += r.tool_force_n.y;
        }
    }
    sum / (to + 1 - from) as f64
}

/// While cutting, a blade stepped 1 mm across its flats presses the lip on that side,
/// which pushes it back: a force across the flats, against the step, from the tissue (the
/// fracture term acts along the motion only), in proportion to its stiffness.
#[test]
fn a_cutting_blade_stepped_sideways_is_pushed_back_by_the_lip() {
    let lateral: Vec<f64> = [1.0, 4.0]
        .iter()
        .map(|&k| lateral_after_step(k, 1.0) - lateral_after_step(k, 0.0))
        .collect();
    println!("across the flats after a 1 mm step, 1 and 4 × E: {lateral:?} N");
    assert!(lateral[0] < -1e-3, "{lateral:?}");
    let ratio = lateral[1] / lateral[0];
    assert!((3.0..=5.0).contains(&ratio), "{lateral:?}: × {ratio}");
}

/// The blade cut 20 mm forward along +x (its back toward −x) in `scene`, then backed 35 mm
/// the way it came — 15 mm past where its wound starts, spine first — and lifted out.
fn cut_then_back(scene: &BuiltScene) -> CutScript {
    let top = top_mm(scene, -30.0, 0.0);
    let z = top - 10.0;
    script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (3.0, [-30.0, 0.0, z]),
        (7.0, [-10.0, 0.0, z]),
        (14.0, [-45.0, 0.0, z]),
        (17.0, [-45.0, 0.0, top + 5.0]),
    ])
}

/// While the blade backs past its wound's start (7 to 14 s): per tick, what the tissue put
/// on the spine along the motion's opposite (+x, N), Σ's size, and whether it tore.
fn backing_past_the_start(scene: &BuiltScene) -> Vec<(f64, usize, bool)> {
    let s = cut_then_back(scene);
    let mut sim = Simulation::new(scene);
    let mut rows = Vec::new();
    for k in 0..14_000 {
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        let r = sim.tick(TICK_S, &mut NoClock);
        assert!(!r.solver.diverged && r.solver.rollbacks == 0, "tick {k}");
        if k >= 7_000 {
            let cut = r.cut.as_ref().unwrap();
            // A tear is the spine's, the blade withdrawing: no sweep along the chord.
            assert!(
                !cut.fractured || cut.withdrawing,
                "tick {k}: a tear while cutting"
            );
            let spine = sim
                .solver()
                .blade()
                .map_or(Vec3::zeros(), |b| b.force_on_spine());
            let sigma = sim.cutting().unwrap().sigma.triangles.len();
            rows.push((spine.x, sigma, cut.fractured));
        }
    }
    rows
}

/// A blade backed out of its wound past where it starts meets the tissue there with its
/// blunt spine: the tissue pushes the spine back (in proportion to its stiffness) and is
/// not cut — Σ does not grow — until the spine has indented it as far as a blunt press
/// ruptures it; then it tears (a fracture tick: Σ grows over the footprint) and the spine
/// meets the tissue beyond. Before, the edge swept Σ backward as if the spine cut, at the
/// formula's cutting force.
#[test]
fn a_blade_backed_past_its_wound_meets_the_tissue_with_its_spine() {
    let soft = backing_past_the_start(&linear_liver_at(1.0));
    let stiff = backing_past_the_start(&linear_liver_at(4.0));
    let first_tear = |rows: &[(f64, usize, bool)]| {
        rows.iter()
            .position(|r| r.2)
            .expect("the spine tears the tissue")
    };
    let (tear_soft, tear_stiff) = (first_tear(&soft), first_tear(&stiff));
    // The tissue tears at the same travel whatever its stiffness (its contact and its
    // field both scale with E), within a millimetre (200 ticks at 5 mm/s).
    assert!(
        tear_soft.abs_diff(tear_stiff) < 200,
        "{tear_soft} / {tear_stiff}"
    );
    // Until then Σ is what the forward stroke cut, and the spine pushes: the most it
    // pushed, four times as much at four times E.
    for rows in [&soft, &stiff] {
        let tear = first_tear(rows);
        assert!(rows[..tear].iter().all(|r| r.1 == rows[0].1));
        assert!(rows[tear].1 > rows[0].1, "a tear grows Σ");
    }
    let most = |rows: &[(f64, usize, bool)], until: usize| {
        rows[..until]
            .iter()
            .map(|r| r.0)
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let until = tear_soft.min(tear_stiff);
    let (push_soft, push_stiff) = (most(&soft, until), most(&stiff, until));
    println!(
        "spine's push before the first tear (ticks {} / {}): {push_soft:.4} / {push_stiff:.4} N (1, 4 x E)",
        7_000 + tear_soft,
        7_000 + tear_stiff
    );
    assert!(push_soft > 0.005, "{push_soft}");
    // (Not exactly 4: the organ's sag under its own weight goes as 1/E, as for the lip's
    // push, `a_cutting_blade_stepped_sideways_is_pushed_back_by_the_lip`.)
    let ratio = push_stiff / push_soft;
    assert!((3.0..=5.0).contains(&ratio), "x {ratio}");
    // Σ grows only where the tissue tears, and the spine meets the tissue beyond.
    for rows in [&soft, &stiff] {
        for pair in rows.windows(2) {
            assert!(pair[1].1 == pair[0].1 || pair[1].2, "Σ grew without a tear");
        }
        let tears = rows.iter().filter(|r| r.2).count();
        assert!(tears >= 2, "{tears} tears");
    }
    // The whole stroke, its lift included, is calm.
    calm_run(
        &linear_liver_at(1.0),
        &cut_then_back(&linear_liver_at(1.0)),
        0,
    );
}
