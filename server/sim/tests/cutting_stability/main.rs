//! Stability in cutting (issue 4, item 10), by kind: blade paths (`blade_paths`), depth and
//! blade angle (`depth_and_angle`) and extreme inputs (`extremes`). In every case: nothing
//! non-finite, the tool force bounded and without jumps outside rupture, no divergence, and
//! the drawn surface still closed, manifold and consistently oriented. The harness that
//! drives a scripted blade and records each tick is here.

use scalpel_sim::cut::corners_of_kind;
use scalpel_sim::cut::{FaceKind, ToolPose};
use scalpel_sim::force::{CutPhase, CuttingForceModel};
use scalpel_sim::geometry::topology::check_surface;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{CutScript, Keyframe, NoClock, Simulation};
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{BuiltScene, ForceSpec, SceneSpec, build_scene, builtin};

mod blade_body;
mod blade_paths;
mod depth_and_angle;
mod extremes;

/// Largest change of the tool force in one tick outside a rupture (N). The loading curve
/// rises by millinewtons per tick at 5 mm/s and the ripple is a fraction of a newton over
/// millimetres; anything near this bound is a jump the device would feel as a kick.
const MAX_FORCE_STEP_N: f64 = 0.25;

const TICK_S: f64 = 1e-3;

/// Ticks after a crack advance in which the tissue it let go may spring back onto the edge:
/// it comes back over gaps of up to 2.7 mm at 0.06–0.5 mm a tick (4 to 22 ticks traced)
/// and meets the rigid edge with what compression it kept. Part of the fracture's event,
/// bounded by the load before it.
const REBOUND_TICKS: usize = 50;

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
    /// Ticks where the crack advanced by energy (its force's drop is the sawtooth's).
    fractures: usize,
    /// Largest step within [`REBOUND_TICKS`] after a crack advance (N): the tissue it let
    /// go springing back onto the edge, never over the load before the advance.
    max_rebound_n: f64,
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
    /// The edge in the tissue's own frame (rest space, m: tip, entry), while in the tissue.
    /// Under gravity the organ sags on into a wound after it is cut, so a wall is compared
    /// with where the blade went in this frame, not in the world.
    edge_rest: Vec<Option<[Vec3; 2]>>,
    /// The tip's world position (m), while there is a tool.
    tip: Vec<Option<Vec3>>,
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
    // Ticks since the last crack advance, and the force before it, while within
    // REBOUND_TICKS of it.
    let mut rebound: Option<(usize, f64)> = None;
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
        assert_nodes_joined(sim, k);
        let f = r.tool_force_n;
        assert!(f.iter().all(|c| c.is_finite()), "tick {k}: force {f:?}");
        assert!(
            f.norm() <= max_force + 1e-12,
            "tick {k}: |f| = {}",
            f.norm()
        );
        let ruptured = r.cut.as_ref().is_some_and(|c| c.force.ruptured);
        let fractured = r.cut.as_ref().is_some_and(|c| c.fractured);
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
        } else if fractured {
            // The crack advancing by energy lets go of what the edge had loaded: the
            // sawtooth's drop; a rise there is bounded like any other tick's.
            trace.fractures += 1;
            assert!(
                f.norm() <= last.norm() + MAX_FORCE_STEP_N,
                "tick {k}: a fracture raised the force {} -> {}",
                last.norm(),
                f.norm()
            );
            let before = rebound.map_or(0.0, |(_, b)| b).max(last.norm());
            rebound = Some((0, before));
        } else if let Some((_, before)) = rebound {
            // The tissue the crack let go springs back onto the edge: passive, it never
            // pushes harder than it did before the advance.
            assert!(
                f.norm() <= before + MAX_FORCE_STEP_N,
                "tick {k}: a rebound pushed {} N, over the {before} N before the advance",
                f.norm()
            );
            trace.max_rebound_n = trace.max_rebound_n.max((f - last).norm());
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
        rebound = rebound
            .map(|(t, before)| (t + 1, before))
            .filter(|&(t, _)| t < REBOUND_TICKS);
        trace.ticks.force.push(f);
        trace.ticks.depth.push(depth);
        trace
            .ticks
            .edge_rest
            .push(r.cut.as_ref().and_then(|c| c.edge_rest));
        trace.ticks.tip.push(tip);
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

/// Every virtual point still joins all the points it is slaved to: a node a pair of which
/// the growing Σ cut (its masters split across the cut) was released in that tick.
fn assert_nodes_joined(sim: &Simulation, tick: usize) {
    let Some(vp) = sim.virtual_points() else {
        return;
    };
    for node in vp.nodes() {
        let joined = sim.neighbours().of(node as usize);
        assert!(
            (sim.solver().masters_of(node as usize)).all(|m| joined.contains(&m)),
            "tick {tick}: node {node} is slaved to a point across the cut"
        );
    }
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

/// No body point is held by the blade's dent any more: the fixed points are the scene's
/// supports' (a fresh start of the same scene), no more and no fewer. (Virtual points,
/// after the body's points, are slaved to body points: fixed dofs by design.)
fn assert_dent_released(sim: &Simulation) {
    let body = sim.solver().material_points();
    let fresh = Simulation::new(
        &build_scene(sim.spec(), None, &mut Silent).expect("the scene builds again"),
    );
    assert_eq!(
        sim.solver().fixed()[..body],
        fresh.solver().fixed()[..body],
        "only the supports' points are fixed"
    );
}

/// Top of the organ at (x, y) in mm, where it rests on its supports when the tool arrives.
fn top_mm(scene: &BuiltScene, x: f64, y: f64) -> f64 {
    let surface = scalpel_sim::pipeline::start_surface(scene);
    scalpel_sim::pipeline::vertical_extent(&surface, x * 1e-3, y * 1e-3)
        .unwrap()
        .0
        * 1e3
}
