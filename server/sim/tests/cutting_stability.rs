//! Stability in cutting (issue 4, item 10): blades that start or stop inside, leave and
//! re-enter, cross an earlier cut, cut through a thin part, cuts that leave slivers and
//! isolated points, a press that backs out before rupture, a pressed blade that slides,
//! a blade that turns back along its cut, a blade held still in its cut by a device that
//! reads a little off every tick, a second deeper pass along a cut, sawing deeper in one
//! stroke, sawing to and fro, a raked blade, and a stab (alone and followed by a slide). In every case: nothing non-finite, the tool force
//! bounded and without jumps outside rupture, no divergence, and the drawn surface still
//! closed, manifold and consistently oriented.

use scalpel_sim::cut::incision::corners_of_kind;
use scalpel_sim::cut::{FaceKind, ToolPose};
use scalpel_sim::force::CutPhase;
use scalpel_sim::geometry::topology::check_surface;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{CutScript, Keyframe, NoClock, Simulation};
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{BuiltScene, ForceSpec, SceneSpec, build_scene, builtin};

/// Largest change of the tool force in one tick outside a rupture (N). The loading curve
/// rises by millinewtons per tick at 5 mm/s and the ripple is a fraction of a newton over
/// millimetres; anything near this bound is a jump the device would feel as a kick.
const MAX_FORCE_STEP_N: f64 = 0.25;

const TICK_S: f64 = 1e-3;

fn scene(name: &str) -> BuiltScene {
    cutting_scene(builtin(name).unwrap())
}

/// `spec` built with cutting on.
fn cutting_scene(mut spec: SceneSpec) -> BuiltScene {
    spec.features.cutting = true;
    build_scene(&spec, None, &mut Silent).unwrap()
}

/// A script through `frames` (time s, tip mm), blade edge pointing up.
fn script(frames: &[(f64, [f64; 3])]) -> CutScript {
    CutScript {
        keyframes: frames
            .iter()
            .map(|&(t_s, tip)| Keyframe {
                t_s,
                pose: ToolPose::pointing(Vec3::from(tip) * 1e-3, Vec3::z()),
            })
            .collect(),
        description: "test".into(),
    }
}

/// What a run did.
#[derive(Debug, Default)]
struct Trace {
    peak_n: f64,
    max_step_n: f64,
    /// Where the largest step happened: tick, phases and magnitudes before and after.
    max_step_at: String,
    ruptures: usize,
    /// Ticks where a forward cut came out of the tissue (the last ligament parts).
    breakthroughs: usize,
    diverged_ticks: usize,
    /// Ticks the solver's guard rolled back at least once.
    rolled_back_ticks: usize,
    /// Most explicit sub-steps in a tick.
    substeps_max: u32,
    /// Deepest depth reading (m).
    max_depth_m: f64,
    /// Ticks where the blade fell out of the tissue while cutting and came back the next
    /// tick: the reading flickering on a surface it sits on.
    dropouts: usize,
    /// Work the tool did on the tissue (J): Σ −f·Δx over the ticks where that is positive.
    work_in_j: f64,
    /// Work the tissue did on the tool (J): Σ f·Δx where positive. A passive tissue never
    /// gives back more than it took.
    work_out_j: f64,
    /// Ticks in the cutting regime.
    cutting_ticks: usize,
    /// The regime on the script's last tick, with the tool still there.
    phase_at_end: Option<CutPhase>,
    /// Every tick's tool force and size of Σ.
    ticks: PerTick,
}

/// Per-tick records, shown in a trace by their count only.
#[derive(Default)]
struct PerTick {
    /// Tool force (N).
    force: Vec<Vec3>,
    /// Triangles of the swept surface Σ.
    sigma: Vec<usize>,
    /// Depth of the edge in the tissue, along it (m).
    depth: Vec<f64>,
}

impl std::fmt::Debug for PerTick {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ticks", self.force.len())
    }
}

/// Plays `script` tick by tick (then `idle_ticks` with no tool), checking every tick.
fn drive(sim: &mut Simulation, script: &CutScript, idle_ticks: usize, spec: &ForceSpec) -> Trace {
    let max_force = spec.max_force_n;
    let ticks = (script.duration_s() / TICK_S).ceil() as usize;
    let mut trace = Trace::default();
    let mut last = Vec3::zeros();
    let mut last_phase = None;
    let mut last_depth = 0.0;
    let mut out_after_cutting = false;
    let mut last_tip = None;
    for k in 0..ticks + idle_ticks {
        let pose = (k < ticks).then(|| script.pose_at(k as f64 * TICK_S));
        // The force of the last tick is what the hand felt while moving to this pose.
        let tip = pose.map(|p| p.tip_m);
        if let (Some(a), Some(b)) = (last_tip, tip) {
            let work = last.dot(&(b - a));
            trace.work_out_j += work.max(0.0);
            trace.work_in_j += (-work).max(0.0);
        }
        last_tip = tip;
        sim.handle_tool_pose(pose);
        let r = sim.tick(TICK_S, &mut NoClock);
        let f = r.tool_force_n;
        assert!(f.iter().all(|c| c.is_finite()), "tick {k}: force {f:?}");
        assert!(
            f.norm() <= max_force + 1e-12,
            "tick {k}: |f| = {}",
            f.norm()
        );
        let ruptured = r.cut.as_ref().is_some_and(|c| c.force.ruptured);
        trace.ruptures += usize::from(ruptured);
        let phase = r
            .cut
            .as_ref()
            .map(|c| (c.force.phase, c.in_tissue, c.withdrawing));
        // A blade cutting forward out of the far side of the tissue parts the last ligament:
        // like a rupture, a physical drop, bounded by the cutting force.
        // So is a depth that falls by millimetres in one tick as the edge comes out of the
        // far side.
        let depth = r.cut.as_ref().map_or(0.0, |c| c.depth_m);
        let cutting_forward = matches!(last_phase, Some((CutPhase::Cutting, true, false)));
        let breakthrough =
            cutting_forward && (matches!(phase, Some((_, false, _))) || last_depth - depth > 1e-3);
        let depth_before = std::mem::replace(&mut last_depth, depth);
        trace.max_depth_m = trace.max_depth_m.max(depth);
        let in_tissue = matches!(phase, Some((_, true, _)));
        trace.cutting_ticks += usize::from(matches!(phase, Some((CutPhase::Cutting, ..))));
        trace.dropouts += usize::from(out_after_cutting && in_tissue);
        out_after_cutting = cutting_forward && !in_tissue;
        trace.breakthroughs += usize::from(breakthrough);
        // With no tool there is no device to push: the force is simply zero.
        if pose.is_none() {
            assert_eq!(f, Vec3::zeros(), "tick {k}: force without a tool");
        } else if breakthrough {
            // The drop is at most the cutting force at the depth just before it.
            let cutting = (1.0 + spec.ripple_amplitude)
                * (spec.toughness_n_per_m * depth_before + spec.friction_n);
            assert!(
                (f - last).norm() <= cutting + 1e-9,
                "tick {k}: breakthrough step {} over the cutting force {cutting}",
                (f - last).norm()
            );
        } else if !ruptured && (f - last).norm() > trace.max_step_n {
            trace.max_step_n = (f - last).norm();
            trace.max_step_at = format!(
                "tick {k}: {:?} {:.3} N -> {phase:?} {:.3} N",
                last_phase,
                last.norm(),
                f.norm()
            );
        }
        last = f;
        trace.ticks.force.push(f);
        trace.ticks.depth.push(depth);
        trace
            .ticks
            .sigma
            .push(sim.cutting().map_or(0, |c| c.sigma.triangles.len()));
        if k + 1 == ticks {
            trace.phase_at_end = phase.map(|(p, ..)| p);
        }
        last_phase = phase;
        trace.peak_n = trace.peak_n.max(f.norm());
        trace.diverged_ticks += usize::from(r.solver.diverged);
        trace.rolled_back_ticks += usize::from(r.solver.rollbacks > 0);
        trace.substeps_max = trace.substeps_max.max(r.solver.substeps);
        if k % 64 == 0 || k + 1 == ticks + idle_ticks {
            assert!(
                sim.solver()
                    .positions()
                    .iter()
                    .all(|p| p.iter().all(|c| c.is_finite())),
                "tick {k}: non-finite point"
            );
            assert!(
                sim.surface()
                    .positions
                    .iter()
                    .all(|p| p.iter().all(|c| c.is_finite())),
                "tick {k}: non-finite surface vertex"
            );
        }
    }
    // As `scalpel cut` ends a run: a re-cut still on its worker thread lands now.
    sim.settle_incision();
    trace
}

fn assert_sound_surface(sim: &Simulation) {
    let (drawn, _) = sim.current_surface().drawn();
    let check = check_surface(&drawn.triangles, drawn.positions.len());
    assert!(
        check.closed && check.manifold && check.oriented,
        "{check:?}"
    );
}

/// Plays `script` on a fresh simulation of `scene` (then `idle_ticks` with no tool) and
/// checks the run is calm: no divergence, no drop-outs, no force step over the bound.
fn calm_run(scene: &BuiltScene, script: &CutScript, idle_ticks: usize) -> (Simulation, Trace) {
    let mut sim = Simulation::new(scene);
    let trace = drive(&mut sim, script, idle_ticks, &scene.spec.force);
    assert_calm(&trace);
    (sim, trace)
}

fn assert_calm(trace: &Trace) {
    println!("{trace:?}");
    assert_eq!(trace.diverged_ticks, 0);
    assert_eq!(trace.dropouts, 0, "{trace:?}");
    assert!(trace.max_step_n <= MAX_FORCE_STEP_N, "{trace:?}");
}

/// No body point is held by the blade's dent any more. (Virtual points, after the body's
/// points, are slaved to body points: fixed dofs by design.)
fn assert_dent_released(sim: &Simulation) {
    let body = sim.solver().material_points();
    assert!(
        sim.solver().fixed()[..body]
            .iter()
            .all(|f| *f == [false; 3])
    );
}

/// Top of the organ at (x, y) in mm.
fn top_mm(scene: &BuiltScene, x: f64, y: f64) -> f64 {
    scalpel_sim::pipeline::vertical_extent(&scene.model.surface, x * 1e-3, y * 1e-3)
        .unwrap()
        .0
        * 1e3
}

#[test]
fn blade_that_starts_and_stops_inside() {
    let scene = scene("liver");
    let z = top_mm(&scene, 0.0, 0.0) - 8.0;
    // Appears 8 mm deep, cuts 15 mm, stands still for half a second, then the tool is gone.
    let s = script(&[
        (0.0, [-10.0, 0.0, z]),
        (3.0, [5.0, 0.0, z]),
        (3.5, [5.0, 0.0, z]),
    ]);
    let (mut sim, trace) = calm_run(&scene, &s, 300);
    // Appearing inside, it presses the way it first moves: it ruptures and cuts.
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert!(trace.cutting_ticks > 2000, "{trace:?}");
    // With the blade gone the force is gone and the dent released.
    let r = sim.tick(TICK_S, &mut NoClock);
    assert_eq!(r.tool_force_n, Vec3::zeros());
    assert_dent_released(&sim);
    assert_sound_surface(&sim);
}

#[test]
fn a_press_that_backs_out_before_rupture() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    // Down at 5 mm/s to 2.5 mm past the surface (rupture takes 3.17), half a second held,
    // back up the same way.
    let press = top - 0.8 * spec.rupture_displacement_m * 1e3;
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (1.5, [-30.0, 0.0, press]),
        (2.0, [-30.0, 0.0, press]),
        (3.5, [-30.0, 0.0, top + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    // The capsule holds, and its force eases off the way it came: backing out neither
    // ruptures it nor makes it push harder (it did both when loading counted path length
    // and the averaged direction could not turn round).
    assert_eq!((trace.ruptures, trace.cutting_ticks), (0, 0), "{trace:?}");
    assert!(trace.peak_n < spec.rupture_force_n, "{trace:?}");
    // Out again at the end, and the dent let go.
    assert_eq!(trace.phase_at_end, Some(CutPhase::Free), "{trace:?}");
    assert_dent_released(&sim);
    assert!(trace.work_in_j > 5e-4, "{trace:?}");
    // Elastic: what the press put in comes back, and no more.
    assert!(
        trace.work_out_j <= 1.02 * trace.work_in_j && trace.work_out_j >= 0.8 * trace.work_in_j,
        "{trace:?}"
    );
    assert_sound_surface(&sim);
}

/// While the blade dents the capsule, the free points next to the held patch are
/// integrated. The affected region around the edge (3 support radii) does not cover a patch
/// two rupture displacements wide on a fine lattice: the cerebroma's 147 held points had
/// neighbours asleep, frozen where they were, that took the patch's whole strain at its rim
/// — on the small tumour scan they sprang out inverted at 1.7 m/s when rupture woke them, a
/// rollback in its default stroke (docs/CUTTING-DECISIONS.md "Displacement-controlled dent").
#[test]
fn a_held_dent_keeps_its_surroundings_integrated() {
    let scene = scene("cerebroma");
    let top = top_mm(&scene, 0.0, 0.0);
    let press = top - 0.9 * scene.spec.force.rupture_displacement_m * 1e3;
    let s = script(&[
        (0.0, [0.0, 0.0, top + 1.0]),
        (0.8, [0.0, 0.0, press]),
        (1.0, [0.0, 0.0, press]),
    ]);
    let mut sim = Simulation::new(&scene);
    let ticks = (s.duration_s() / TICK_S) as usize;
    let (mut held_ticks, mut most_held) = (0, 0);
    for k in 0..=ticks {
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        sim.tick(TICK_S, &mut NoClock);
        let solver = sim.solver();
        let body = solver.material_points();
        let held: Vec<usize> = (0..body)
            .filter(|&i| solver.fixed()[i] == [true; 3])
            .collect();
        if held.is_empty() {
            continue;
        }
        held_ticks += 1;
        most_held = most_held.max(held.len());
        // The press begins at the end of a tick; its points are integrated from the next.
        if held_ticks == 1 {
            continue;
        }
        let mut active = vec![false; solver.positions().len()];
        for &i in solver.active_points() {
            active[i as usize] = true;
        }
        for &i in &held {
            for &j in solver.operator().neighbours(i) {
                // Nodes after the body's points are virtual points (slaved).
                assert!(
                    active[j as usize] || j as usize >= body,
                    "tick {k}: point {j}, a neighbour of the dented point {i}, is frozen"
                );
            }
        }
    }
    // The dent was held from first contact to the end, over many points.
    assert!(
        held_ticks > 700 && most_held > 100,
        "{held_ticks} {most_held}"
    );
}

#[test]
fn a_pressed_blade_that_slides_slices() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    // 1.5 mm into the capsule (half the rupture displacement), then 10 mm sideways.
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (1.3, [-30.0, 0.0, top - 1.5]),
        (3.3, [-20.0, 0.0, top - 1.5]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    // It slices: the capsule ruptures within the rupture displacement of sliding, at a
    // force well under the rupture force, and the blade cuts on.
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert!(trace.peak_n < 0.8 * spec.rupture_force_n, "{trace:?}");
    assert!(trace.cutting_ticks > 1000, "{trace:?}");
    assert_sound_surface(&sim);
}

#[test]
fn a_blade_that_turns_back_along_its_cut() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let spec = &scene.spec.force;
    let z = top - 10.0;
    // Down 10 mm, 30 mm forward, 20 mm back the same way, out.
    let s = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (3.0, [-30.0, 0.0, z]),
        (9.0, [0.0, 0.0, z]),
        (13.0, [-20.0, 0.0, z]),
        (16.0, [-20.0, 0.0, top + 5.0]),
    ]);
    // The turn is smooth: the resistance passes through zero instead of flipping by twice
    // its size in one tick (5.5 N when the direction was a blend of unit vectors).
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    // Forward it cuts: fracture and friction (J_c·d ≥ 1.9 N at 10 mm).
    let forward = trace.ticks.force[8500];
    assert!(forward.x < -2.0, "{forward:?}");
    // Back along its own cut it opens nothing: friction only, against the motion, from
    // 3 mm after the turn on; Σ does not grow.
    let friction = (1.0 + spec.ripple_amplitude) * spec.friction_n;
    for (k, f) in trace.ticks.force[9600..13000].iter().enumerate() {
        assert!(
            f.x > 0.0 && f.norm() <= friction + 1e-9,
            "tick {}: {f:?}",
            9600 + k
        );
    }
    assert_eq!(trace.ticks.sigma[9500], trace.ticks.sigma[13000]);
    // What the tissue did on the hand around the turn is a sliver of what the cut took:
    // the averaged direction's lag (0.67 mJ), and the steady motion's — the heading holds
    // until the smoothed tip is a deadband behind where it last moved to, 2 × (0.1 mm +
    // 10 ms at 5 mm/s) of the way back at the full 2.6 N of cutting, ≈ 0.8 mJ.
    assert!(trace.work_out_j < 0.02 * trace.work_in_j, "{trace:?}");
    assert_sound_surface(&sim);
}

#[test]
fn blade_that_leaves_and_reenters() {
    let scene = scene("liver");
    let top = top_mm(&scene, 0.0, 0.0);
    let (up, down) = (top + 10.0, top - 8.0);
    let s = script(&[
        (0.0, [-30.0, 0.0, up]),
        (3.6, [-30.0, 0.0, down]),
        (6.6, [-15.0, 0.0, down]),
        (10.2, [-15.0, 0.0, up]),
        (13.2, [15.0, 0.0, up]),
        (16.8, [15.0, 0.0, down]),
        (19.8, [30.0, 0.0, down]),
        (23.4, [30.0, 0.0, up]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 0);
    assert_eq!(
        trace.ruptures, 2,
        "one rupture per entry into intact capsule"
    );
    let stats = sim.incisions().unwrap();
    println!("{stats:?}");
    assert!(stats.incisions >= 2);
    assert!(stats.min_angle_deg >= 15.0);
    assert_sound_surface(&sim);
}

#[test]
fn two_crossing_cuts() {
    let scene = scene("liver");
    let top = top_mm(&scene, 0.0, 0.0);
    let (up, down) = (top + 10.0, top - 8.0);
    let s = script(&[
        (0.0, [-25.0, 0.0, up]),
        (3.6, [-25.0, 0.0, down]),
        (13.6, [25.0, 0.0, down]),
        (17.2, [25.0, 0.0, up]),
        (19.2, [0.0, -25.0, up]),
        (22.8, [0.0, -25.0, down]),
        (32.8, [0.0, 25.0, down]),
        (36.4, [0.0, 25.0, up]),
    ]);
    let (sim, _) = calm_run(&scene, &s, 0);
    let stats = sim.incisions().unwrap();
    println!("{stats:?}");
    assert!(stats.incisions >= 2, "{stats:?}");
    assert!(stats.min_angle_deg >= 15.0);
    assert_sound_surface(&sim);
}

/// Three wounds made one after the other across the liver's top, 60 mm apart (one of the
/// endurance scripts of docs/CUTTING-DECISIONS.md, "Virtual points slaved to the points they join"): the virtual points on the
/// earlier walls, moved once a tick to where their wall vertices went, drove the tissue
/// that carries those vertices, a loop with a tick's lag that pumped energy into the walls
/// during the second stroke — from then on the guard rolled ticks back, doubling their
/// sub-steps up to 32 768 (0.5–3.8 s per tick), and 223 ticks diverged. Slaved to the
/// points around them, the nodes close no loop: every tick is calm and none is rolled back.
#[test]
fn several_wounds_in_one_session_stay_calm() {
    let scene = scene("liver");
    let mut frames: Vec<(f64, [f64; 3])> = Vec::new();
    let mut t = 0.0;
    // (x, first y, last y, depth mm): along −y, 10 mm/s down, 8 mm/s along.
    for (x, y0, y1, depth) in [
        (-58.5, 42.8, 12.8, 7.5),
        (-8.1, 25.2, -0.9, 5.1),
        (53.7, 7.1, -17.9, 7.2),
    ] {
        let above = top_mm(&scene, x, y0) + 10.0;
        if !frames.is_empty() {
            t += 1.0;
        }
        frames.push((t, [x, y0, above]));
        t += (10.0 + depth) / 10.0;
        let steps = 10;
        for k in 0..=steps {
            let y = y0 + (y1 - y0) * k as f64 / steps as f64;
            if k > 0 {
                t += (y1 - y0).abs() / steps as f64 / 8.0;
            }
            frames.push((t, [x, y, top_mm(&scene, x, y) - depth]));
        }
        t += (10.0 + depth) / 10.0;
        frames.push((t, [x, y1, top_mm(&scene, x, y1) + 10.0]));
    }
    // Upright, facing along the strokes (−y).
    let mut s = script(&frames);
    for k in &mut s.keyframes {
        k.pose = ToolPose::facing(k.pose.tip_m, Vec3::z(), -Vec3::y());
    }
    let (sim, trace) = calm_run(&scene, &s, 500);
    assert_eq!(trace.rolled_back_ticks, 0, "{trace:?}");
    let stats = sim.incisions().unwrap();
    println!("{stats:?}");
    assert!(stats.incisions >= 3, "{stats:?}");
    assert!(stats.min_angle_deg >= 15.0);
    let vp = sim.virtual_points().expect("the liver uses virtual points");
    assert!(vp.stats.placed > 20, "{:?}", vp.stats);
    assert_sound_surface(&sim);
}

#[test]
fn cut_through_a_thin_part() {
    // The 10 mm beam: the blade goes down right through it (the tip comes out underneath),
    // then cuts across to the side and out.
    let scene = scene("beam");
    let bbox = scene.model.surface.bbox();
    let (z0, z1) = (bbox.min[2] * 1e3, bbox.max[2] * 1e3);
    let y1 = bbox.max[1] * 1e3;
    let s = script(&[
        (0.0, [0.0, 0.0, z1 + 5.0]),
        (4.0, [0.0, 0.0, z0 - 5.0]),
        (6.0, [0.0, y1 + 5.0, z0 - 5.0]),
        (9.0, [0.0, y1 + 5.0, z1 + 5.0]),
    ]);
    let (sim, trace) = calm_run(&scene, &s, 200);
    // One rupture, and the blade read the whole thickness of the part while through it.
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert!(
        (trace.max_depth_m * 1e3 - (z1 - z0)).abs() < 1.0,
        "{trace:?}"
    );
    assert_sound_surface(&sim);
}

/// The stiff and extreme materials of physics.md §9 under the blade: E = 1 MPa (200× the
/// liver) and ν = 0.499 (c_p 6.6× the liver's), each cut on the liver with explicit
/// sub-steps planned for it. The cut is the same cut: one rupture, an incision, no tick
/// rolled back, the surface sound.
#[test]
fn stiff_and_near_incompressible_tissue_cuts_calmly() {
    for (youngs_modulus_pa, poisson_ratio) in [(1e6, 0.45), (5e3, 0.499)] {
        let mut spec = builtin("liver").unwrap();
        spec.material.youngs_modulus_pa = youngs_modulus_pa;
        spec.material.poisson_ratio = poisson_ratio;
        let scene = cutting_scene(spec);
        let top = top_mm(&scene, -10.0, 0.0);
        let (up, down) = (top + 5.0, top - 8.0);
        let s = script(&[
            (0.0, [-10.0, 0.0, up]),
            (2.6, [-10.0, 0.0, down]),
            (6.6, [10.0, 0.0, down]),
            (9.2, [10.0, 0.0, up]),
        ]);
        let (sim, trace) = calm_run(&scene, &s, 100);
        let what = format!("E {youngs_modulus_pa} Pa, ν {poisson_ratio}: {trace:?}");
        assert_eq!(trace.ruptures, 1, "{what}");
        assert_eq!(trace.rolled_back_ticks, 0, "{what}");
        // The liver takes 1 sub-step a tick; these take what their wave speed asks.
        assert!(trace.substeps_max >= 5, "{what}");
        let stats = sim.incisions().unwrap();
        assert_eq!(stats.incisions, 1, "{what}: {stats:?}");
        assert!(stats.min_angle_deg >= 15.0, "{what}: {stats:?}");
        assert_sound_surface(&sim);
    }
}

#[test]
fn slivers_and_isolated_points() {
    // Three full-depth cuts one lattice spacing apart and across each other on the 30 mm
    // block leave one-layer slivers and points with almost no neighbours.
    let scene = scene("block");
    let s_mm = scene.model.lattice.spacing * 1e3;
    let top = top_mm(&scene, 0.0, 0.0);
    let (up, down) = (top + 10.0, top - 12.0);
    let x = 0.5 * s_mm;
    let s = script(&[
        (0.0, [x, -20.0, up]),
        (3.0, [x, -20.0, down]),
        (11.0, [x, 20.0, down]),
        (14.0, [x, 20.0, up]),
        (15.0, [x + s_mm, 20.0, up]),
        (18.0, [x + s_mm, 20.0, down]),
        (26.0, [x + s_mm, -20.0, down]),
        (29.0, [x + s_mm, -20.0, up]),
        (30.0, [-20.0, 0.5 * s_mm, up]),
        (33.0, [-20.0, 0.5 * s_mm, down]),
        (41.0, [20.0, 0.5 * s_mm, down]),
        (44.0, [20.0, 0.5 * s_mm, up]),
    ]);
    let (sim, _) = calm_run(&scene, &s, 300);
    let ranks = sim.solver().rank_counts();
    println!("{ranks:?}");
    assert!(
        ranks.planar + ranks.orphan > 0,
        "the cuts should have left degenerate neighbourhoods: {ranks:?}"
    );
    assert_sound_surface(&sim);
}

#[test]
fn a_blade_held_still_in_its_cut_by_a_noisy_hand() {
    // The liver's coarse lattice and the cerebroma's fine one (Σ grows every s/8: 0.2 mm).
    noisy_hold("liver", [-30.0, -10.0, -5.0], 10.0);
    noisy_hold("cerebroma", [-15.0, -5.0, -2.5], 5.0);
}

/// Down `depth_mm`, forward from `x_mm[0]` to `x_mm[1]`, held for 2 s, on to `x_mm[2]` —
/// through a device that reads up to 0.1 mm off in every axis on every tick (a Touch's
/// ±1 encoder count, and more), held by a hand with a 10 Hz tremor of ±0.04 mm per axis,
/// from 2.5 s on: the capsule has ruptured by then (before, the press feels the noise as
/// what it is, displacement against the capsule's stiffness — up to 4 N/mm near rupture).
fn noisy_hold(name: &str, x_mm: [f64; 3], depth_mm: f64) {
    let scene = scene(name);
    let top = top_mm(&scene, x_mm[0], 0.0);
    let z = top - depth_mm;
    let path = script(&[
        (0.0, [x_mm[0], 0.0, top + 5.0]),
        (3.0, [x_mm[0], 0.0, z]),
        (7.0, [x_mm[1], 0.0, z]),
        (9.0, [x_mm[1], 0.0, z]),
        (10.0, [x_mm[2], 0.0, z]),
    ]);
    let noise_mm = 0.1;
    let frames: Vec<_> = (0..=10_000)
        .map(|k| {
            let x = f64::from(k);
            let t = x * TICK_S;
            let n = Vec3::new((1.7 * x).sin(), (2.3 * x).sin(), (3.1 * x).cos()) * noise_mm
                + Vec3::repeat(0.04) * (2.0 * std::f64::consts::PI * 10.0 * t).sin();
            let p = path.pose_at(t).tip_m * 1e3 + if k < 2500 { Vec3::zeros() } else { n };
            (t, [p.x, p.y, p.z])
        })
        .collect();
    let (sim, trace) = calm_run(&scene, &script(&frames), 0);
    assert_eq!(trace.ruptures, 1, "{name}: {trace:?}");
    // Held, it still resists with the cutting force it had, in the direction it had:
    // the noise is not read as motion. (Read tick by tick it was: on the liver at half
    // this noise the resistance turned round every tick in steps of up to 1.7 N and the
    // crack's fracture term faded to nothing, even while cutting on; on the cerebroma Σ
    // grew to and fro around the held blade, 108 → 2796 triangles in 2 s.)
    let held = trace.ticks.force[6999];
    assert!(held.x < -1.0, "{name}: {held:?}");
    let hold = &trace.ticks.force[7000..9000];
    let mean = hold.iter().sum::<Vec3>() / hold.len() as f64;
    assert!(
        (mean.norm() - held.norm()).abs() < 0.03 * held.norm(),
        "{name}: {mean:?} {held:?}"
    );
    // Once stopped (the first ticks still carry the sideways wobble of the moving blade),
    // it holds its heading and size.
    for (k, f) in hold.iter().enumerate().skip(50) {
        assert!(
            (f - mean).norm() < 0.04 * mean.norm(),
            "{name}: tick {}: {f:?} against {mean:?}",
            7000 + k
        );
    }
    // And it does not buzz: what is left is the depth reading, which follows the noise up
    // and down (J_c × 0.2 mm ≈ 0.04 N).
    for (k, w) in hold[50..].windows(2).enumerate() {
        assert!(
            (w[1] - w[0]).norm() < 0.08,
            "{name}: tick {}: {w:?}",
            7051 + k
        );
    }
    assert_eq!(trace.ticks.sigma[7100], trace.ticks.sigma[9000], "{name}");
    // Cutting with the noise and the tremor, the resistance keeps its heading to within
    // about 4.5°.
    for (k, f) in trace.ticks.force[4000..7000].iter().enumerate() {
        assert!(
            f.x < -0.7 * held.norm() && f.y.hypot(f.z) < 0.08 * held.norm(),
            "{name}: tick {}: {f:?}",
            4000 + k
        );
    }
    // And it cuts on.
    assert!(trace.ticks.sigma[9999] > trace.ticks.sigma[9000], "{name}");
    assert!(trace.ticks.force[9800].x < -0.7 * held.norm(), "{name}");
    assert_sound_surface(&sim);
}

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
    assert_walls_reach(&sim, &scene, top - 10.0);
    assert_sound_surface(&sim);
}

/// The drawn wound walls reach the blade's height `tip_z_mm` (±1 mm) at x = −20 and −10 mm
/// along y = 0.
fn assert_walls_reach(sim: &Simulation, scene: &BuiltScene, tip_z_mm: f64) {
    let corners = wall_corners_mm(sim);
    for x in [-20.0, -10.0] {
        let top = top_mm(scene, x, 0.0);
        let deepest = deepest_near(&corners, x).map_or(0.0, |p| top - p.z);
        let expected = top - tip_z_mm;
        assert!(
            (deepest - expected).abs() < 1.0,
            "walls at x = {x} mm reach {deepest} mm, the blade went {expected} mm deep"
        );
    }
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
    assert_walls_reach(&sim, &scene, top - 10.0);
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
    // The shoulder: the liver's 17.7 mm surface edges are too coarse to draw an 8 mm slit
    // (an incision must be half an edge long).
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
    // edge and shallower behind it (the point narrows at 45°).
    let walls = wall_corners_mm(&sim);
    let span = x_span(&walls);
    assert!(
        (span.0 - (x - width_mm)).abs() < 2.0 && (span.1 - x).abs() < 2.0,
        "walls from x = {:.1} to {:.1} mm",
        span.0,
        span.1
    );
    let deepest = walls
        .iter()
        .filter(|p| (p.x - x).abs() < 2.0)
        .map(|p| top - p.z)
        .fold(0.0, f64::max);
    assert!(
        (deepest - 10.0).abs() < 1.5,
        "walls {deepest} mm deep at the edge"
    );
    let shallow = walls
        .iter()
        .filter(|p| p.x < x - width_mm + 2.0)
        .map(|p| top_mm(&scene, p.x, p.y) - p.z)
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
    assert!(
        (span.0 - (x - width_mm)).abs() < 2.0 && (span.1 - (x + 25.0)).abs() < 2.5,
        "walls from x = {:.1} to {:.1} mm",
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
            // Behind where the blade went in, the slit its flat opened going down: its
            // floor rises at 45° from 10 mm deep at -20 mm to 2 mm at -28 mm, so the
            // blade opens the crack below it, from nothing to all of its depth.
            7000..8500 if x < -20.5 && x > -27.0 => {
                assert!(f.x > friction && f.x < 1.8, "tick {k} at {x}: {f:?}");
            }
            // Past the slit: cutting again (J_c·d + friction ≈ 2.2 N, ±15 %).
            7500..9000 if x < -28.5 => assert!(f.x > 1.8, "tick {k} at {x}: {f:?}"),
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
    assert!(
        (span.0 + 30.0).abs() < 2.5 && (span.1 + 10.0).abs() < 2.5,
        "walls from x = {:.1} to {:.1} mm",
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
    assert_walls_reach(&sim, &scene, z);
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
        let near: Vec<&Vec3> = corners.iter().filter(|p| (p.x - x).abs() < 2.0).collect();
        let deepest = deepest_near(&corners, x).expect("walls");
        assert!(
            (deepest.z - z).abs() < 1.0 && deepest.y.abs() < 1.0,
            "at x = {x} mm the walls' deepest corner is {deepest:?}, the tip ran at y = 0, \
             z = {z} mm"
        );
        // Every wall corner lies in Σ, within the opening of it.
        let normal = Vec3::new(0.0, lean.cos(), lean.sin());
        let opening = sim.incisions().expect("cutting scene").opening_m * 1e3;
        for p in &near {
            let off = (*p - Vec3::new(x, 0.0, z)).dot(&normal).abs();
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
    // k_open × 10 mm deep is 3 mm (physics.md §5.1, w_o = min(0.15 L, k_open d),
    // k_open = 0.3).
    let scene = scene("shoulder");
    let script = CutScript::default_for(&scene.model.surface).expect("default stroke");
    let (sim, trace) = calm_run(&scene, &script, 0);
    assert_eq!(trace.ruptures, 1, "{trace:?}");
    assert_one_incision(&sim);
    let incisions = sim.incisions().expect("cutting scene");
    let wanted = 0.3 * 0.010;
    assert!(
        incisions.opening_m > 0.9 * wanted,
        "half-opening {} mm, k_open × depth {} mm",
        incisions.opening_m * 1e3,
        wanted * 1e3
    );
    assert_sound_surface(&sim);
}

#[test]
fn a_pose_that_is_not_finite_takes_the_tool_away_mid_cut() {
    // A caller that passed a NaN or unnormalised pose on (a hand-edited journal did) must
    // not reach the contact and the force model: the tool is away for that tick.
    let scene = scene("liver");
    let z = top_mm(&scene, 0.0, 0.0) - 5.0;
    let s = script(&[(0.0, [-10.0, 0.0, z]), (1.0, [0.0, 0.0, z])]);
    let mut sim = Simulation::new(&scene);
    sim.prepare(TICK_S);
    for k in 0..1000 {
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        sim.tick(TICK_S, &mut NoClock);
    }
    let sound = s.pose_at(1.0);
    let nan = nalgebra::Quaternion::new(f64::NAN, 0.0, 0.0, 1.0);
    for bad in [
        ToolPose {
            tip_m: Vec3::new(f64::NAN, 0.0, 0.0),
            ..sound
        },
        ToolPose {
            orientation: nalgebra::UnitQuaternion::new_unchecked(nan),
            ..sound
        },
        ToolPose {
            orientation: nalgebra::UnitQuaternion::new_unchecked(
                sound.orientation.into_inner() * 2.0,
            ),
            ..sound
        },
    ] {
        assert!(!bad.is_sound());
        sim.handle_tool_pose(Some(bad));
        let r = sim.tick(TICK_S, &mut NoClock);
        assert_eq!(r.tool_force_n, Vec3::zeros());
        assert!(
            sim.solver()
                .positions()
                .iter()
                .all(|p| p.iter().all(|c| c.is_finite()))
        );
    }
    assert!(sound.is_sound());
    // A glitch followed by a jump (a tracker that reads NaN, then 30 mm off): the blade goes
    // on from where it was at a hand's speed; it is not put down at the jump.
    let jumped = ToolPose {
        tip_m: sound.tip_m + Vec3::new(0.0, 0.03, 0.0),
        ..sound
    };
    sim.handle_tool_pose(Some(jumped));
    sim.tick(TICK_S, &mut NoClock);
    // (From the last sound tick, 10 µm short of `sound`.)
    let moved = (sim.blade_pose().unwrap().tip_m - sound.tip_m).norm();
    assert!(moved > 1.9e-3 && moved < 2.1e-3, "{moved} m in a tick");
    // A tool taken away (`None`) and put back appears where it is put.
    sim.handle_tool_pose(None);
    sim.tick(TICK_S, &mut NoClock);
    assert_eq!(sim.blade_pose(), None);
    sim.handle_tool_pose(Some(jumped));
    sim.tick(TICK_S, &mut NoClock);
    assert_eq!(sim.blade_pose(), Some(jumped));
    assert_sound_surface(&sim);
}

#[test]
fn a_device_pose_that_jumps_is_followed_at_a_hands_speed() {
    // An instructor's pose-noise fault at its largest (σ = 20 mm per axis, white per tick),
    // or a tracker that glitches, for a second in the middle of a cut. Read as given, the
    // blade crossed the liver at tens of metres a second: the solver doubled its sub-steps
    // to hundreds, ticks took hundreds of milliseconds and the station fell behind for good.
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let z = top - 10.0;
    let path = script(&[
        (0.0, [-30.0, 0.0, top + 5.0]),
        (3.0, [-30.0, 0.0, z]),
        (6.0, [0.0, 0.0, z]),
    ]);
    let noisy = 4000..5000;
    let mut rng = 0x9e37_79b9_7f4a_7c15_u64;
    let mut gauss = || {
        let mut uniform = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            ((rng >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u, v) = (uniform(), uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    };
    let mut sim = Simulation::new(&scene);
    let mut last_blade: Option<ToolPose> = None;
    let (mut most_substeps, mut rolled_back, mut cut_mm) = (0, 0, 0.0);
    for k in 0..6000 {
        let mut pose = path.pose_at(k as f64 * TICK_S);
        if noisy.contains(&k) {
            pose.tip_m += Vec3::new(gauss(), gauss(), gauss()) * 0.020;
        }
        sim.handle_tool_pose(Some(pose));
        let r = sim.tick(TICK_S, &mut NoClock);
        let blade = sim.blade_pose().expect("a tool");
        if let Some(last) = last_blade {
            let moved = (blade.tip_m - last.tip_m).norm();
            assert!(moved <= 2e-3 * (1.0 + 1e-9), "tick {k}: {moved} m");
            if r.cut.as_ref().is_some_and(|c| c.in_tissue) {
                cut_mm += moved * 1e3;
            }
        }
        last_blade = Some(blade);
        let f = r.tool_force_n;
        assert!(
            f.iter().all(|c| c.is_finite()) && f.norm() <= scene.spec.force.max_force_n + 1e-12,
            "tick {k}: {f:?}"
        );
        assert!(!r.solver.diverged, "tick {k}");
        most_substeps = most_substeps.max(r.solver.substeps);
        rolled_back += usize::from(r.solver.rollbacks > 0);
    }
    println!(
        "most sub-steps {most_substeps}, {rolled_back} ticks rolled back, {cut_mm:.0} mm in tissue"
    );
    // The liver's one sub-step a tick holds through the noise.
    assert!(
        most_substeps <= 2,
        "{most_substeps} sub-steps, {rolled_back} rolled back"
    );
    // Back on its path once the noise stops, and the cut goes on.
    assert_eq!(
        sim.blade_pose().unwrap().tip_m,
        path.pose_at(5999.0 * TICK_S).tip_m
    );
    assert!(!sim.cutting().unwrap().sigma.triangles.is_empty());
    assert_sound_surface(&sim);
}

/// A quick stroke that ends while a re-cut is still on the worker thread: the stroke's last
/// re-cut supersedes it (the superseded one never lands) and finishes the incision.
#[test]
fn a_quick_stroke_that_ends_while_a_re_cut_is_in_flight_supersedes_it() {
    let scene = scene("liver");
    let top = top_mm(&scene, -30.0, 0.0);
    let z = top - 8.0;
    // 40 mm at 200 mm/s, out in 30 ms: it ends 20-odd ticks after a re-cut was asked for
    // (checked below: one of its runs never lands).
    let s = script(&[
        (0.0, [-40.0, 0.0, top + 5.0]),
        (1.5, [-40.0, 0.0, z]),
        (1.7, [0.0, 0.0, z]),
        (1.73, [0.0, 0.0, top + 30.0]),
        (2.2, [0.0, 0.0, top + 30.0]),
    ]);
    let mut sim = Simulation::new(&scene);
    let mut landings = 0;
    for k in 0..s.tick_count(TICK_S) {
        sim.handle_tool_pose(Some(s.pose_at(k as f64 * TICK_S)));
        let r = sim.tick(TICK_S, &mut NoClock);
        assert!(!r.solver.diverged, "tick {k}");
        landings += usize::from(r.remeshed);
    }
    assert!(!sim.settle_incision(), "landed within the script");
    let stats = sim.incisions().unwrap().clone();
    println!("{stats:?}, {landings} landings");
    assert_eq!(stats.incisions, 1, "{stats:?}");
    assert!(
        landings < stats.runs,
        "a re-cut was superseded: {landings} landings of {} runs",
        stats.runs
    );
    assert!(stats.depth_m > 0.009, "{stats:?}");
    assert_sound_surface(&sim);
    let (_, kinds) = sim.current_surface().drawn();
    assert!(
        kinds.contains(&FaceKind::Wall),
        "the incision has its walls"
    );
}
