//! The default sampling of a mesh, chosen for real time ([`SpacingRule::RealTime`]).
//!
//! A tick of the whole body costs about points × sub-steps, and the explicit sub-steps grow
//! as 1/spacing (dt_crit ∝ spacing): 2000 points in a 12 mm tumour are 0.71 mm apart and ask
//! 13 sub-steps per 1 ms tick — 3.1 ms of work for each millisecond. A lab that loads a mesh
//! without a sampling of its own expects it to run in real time, so the default samples at
//! most `most_points` and fewer where the planned tick would not fit. Each try is planned by
//! the solver the simulation will run (its power iteration and whole-step mass floor), so the
//! count kept is the one the station pays for. Nothing is timed here: the same scene always
//! gives the same model, so a journal replays it.

use std::fmt;

use serde::Serialize;

use crate::geometry::TriMesh;
use crate::model::{CoupledModel, ModelBuildError, SpacingRule};
use crate::pipeline::SIMULATION_TICK_S;
use crate::progress::{BuildObserver, BuildStage};
use crate::solver::{Solver, SolverConfig, SolverMode, WholeStepMass};

use super::SceneSpec;

/// Points × sub-steps a 1 ms tick of the whole body may take: 0.75 ms at the 114–131 ns per
/// point and sub-step measured for whole-body ticks on the development machine (`scalpel
/// bench idle FILE`: liver, tumour at four samplings, pig liver, sphere, deltoid), leaving a
/// quarter of the tick for the surface, frames and noise. A faster machine affords more: a
/// scene asks for its own count with `[sampling] target_points`.
pub const POINT_SUBSTEPS_PER_TICK: usize = 6250;

/// Fewest points the rule samples, whatever the tick costs: fewer would leave a thin part
/// one point thick.
pub const LEAST_POINTS: usize = 250;

/// Samplings tried before the last is kept as it is.
const MOST_TRIES: usize = 8;

/// One sampling and the time step its solver plans for 1 ms ticks (what `scene inspect`
/// reports for the kept one, without planning it again).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlannedSampling {
    /// Interior points.
    pub points: usize,
    /// Sub-steps per 1 ms tick, after any whole-step mass floor.
    pub substeps: u32,
    /// Critical explicit step (s), after the floor.
    pub dt_crit_s: f64,
    /// The whole-step mass floor, if one saved a sub-step.
    pub mass_floor: Option<WholeStepMass>,
}

impl PlannedSampling {
    /// Points × sub-steps: what a tick of the whole body costs, in point updates.
    pub fn point_substeps(&self) -> usize {
        self.points * self.substeps as usize
    }
}

/// How the real-time rule chose the sampling.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SamplingPlan {
    /// The rule's most points.
    pub most_points: usize,
    /// The sampling at `most_points`.
    pub first: PlannedSampling,
    /// The sampling kept.
    pub kept: PlannedSampling,
    /// Points × sub-steps a tick may take ([`POINT_SUBSTEPS_PER_TICK`]).
    pub budget: usize,
}

impl SamplingPlan {
    /// Whether the kept sampling's tick fits the budget.
    pub fn fits(&self) -> bool {
        self.kept.point_substeps() <= self.budget
    }

    /// Whether fewer points than `most_points` asked for were kept.
    pub fn resampled(&self) -> bool {
        self.kept.points != self.first.points
    }
}

impl fmt::Display for SamplingPlan {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (first, kept) = (self.first, self.kept);
        let cost = |s: PlannedSampling| {
            format!(
                "{} sub-step(s) per 1 ms tick, {} point-sub-steps",
                s.substeps,
                s.point_substeps()
            )
        };
        if self.resampled() {
            write!(
                f,
                "{} points for real time: {} would take {} (over the {} a tick affords); {} take {}",
                kept.points,
                first.points,
                cost(first),
                self.budget,
                kept.points,
                cost(kept)
            )?;
        } else {
            write!(f, "{} points, {}", kept.points, cost(kept))?;
        }
        if self.fits() {
            if !self.resampled() {
                write!(f, " (within the {} a tick affords)", self.budget)?;
            }
            Ok(())
        } else {
            write!(
                f,
                " — over the {} a tick affords: not real time on one core",
                self.budget
            )
        }
    }
}

/// Builds the model of `spec` (whose sampling rule is `RealTime { most_points }`) from
/// `surface`. Only the explicit solver's tick grows with the sampling; other modes get
/// `most_points` and no plan.
pub(super) fn build_for_real_time(
    surface: &TriMesh,
    spec: &SceneSpec,
    most_points: usize,
    observer: &mut dyn BuildObserver,
) -> Result<(CoupledModel, Option<SamplingPlan>), ModelBuildError> {
    let config = SolverConfig::for_scene(&spec.features, &spec.material, &spec.solver);
    let mut params = spec.sampling;
    let mut build = |target: usize, observer: &mut dyn BuildObserver| {
        params.spacing = SpacingRule::TargetPoints(target);
        CoupledModel::build(
            surface.clone(),
            &params,
            spec.material.density_kg_m3,
            observer,
        )
    };
    let mut model = build(most_points, observer)?;
    if config.mode != SolverMode::Explicit {
        return Ok((model, None));
    }
    let plan = |model: &CoupledModel, observer: &mut dyn BuildObserver| {
        observer.stage(BuildStage::PlanSampling);
        let mut solver = Solver::for_model(model, &spec.material, config);
        solver.prepare(SIMULATION_TICK_S);
        PlannedSampling {
            points: model.points.len(),
            substeps: solver.substeps(),
            dt_crit_s: solver.known_dt_crit().unwrap_or(f64::NAN),
            mass_floor: solver.whole_step_mass(),
        }
    };
    let first = plan(&model, observer);
    let mut kept = first;
    let mut target = most_points;
    for _ in 1..MOST_TRIES {
        if kept.point_substeps() <= POINT_SUBSTEPS_PER_TICK {
            break;
        }
        // Sub-steps grow as 1/spacing ∝ points^(1/3), so the cost as points^(4/3); aim 3 %
        // under the budget so that a rounding up of the sub-steps does not need another try.
        // The count a lattice gives comes in steps (a cube's 13³ then 12³), so each try asks
        // at least a tenth fewer than the last, whatever came of it.
        let share = POINT_SUBSTEPS_PER_TICK as f64 / kept.point_substeps() as f64;
        let aim = (kept.points.min(target) as f64 * share.powf(0.75) * 0.97) as usize;
        let next = aim.min(target * 9 / 10).max(LEAST_POINTS);
        if next >= target {
            break;
        }
        target = next;
        model = build(target, observer)?;
        kept = plan(&model, observer);
    }
    let plan = SamplingPlan {
        most_points,
        first,
        kept,
        budget: POINT_SUBSTEPS_PER_TICK,
    };
    Ok((model, Some(plan)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::Simulation;
    use crate::progress::Silent;
    use crate::scene::{self, BuiltScene, build_scene};

    fn block(most_points: usize, tweak: impl FnOnce(&mut SceneSpec)) -> BuiltScene {
        let mut spec = scene::builtin("block").expect("built-in scene");
        spec.sampling.spacing = SpacingRule::RealTime { most_points };
        tweak(&mut spec);
        build_scene(&spec, None, &mut Silent).expect("the block builds")
    }

    /// The 30 mm block at about 2000 points (13³ = 2197, 2.3 mm apart) takes 4 sub-steps per
    /// tick, 8788 point updates, over the budget. The rule samples it coarser (12³ still
    /// over, then 11³), and the simulation built from the scene plans the sub-steps the rule
    /// counted — what the station will pay.
    #[test]
    fn a_small_organ_is_sampled_for_a_real_time_tick() {
        // As a cutting station: its simulation's solver has virtual points' spare nodes.
        let scene = block(2000, |s| {
            s.features.cutting = true;
            s.features.virtual_points = true;
        });
        let plan = scene
            .sampling_plan
            .clone()
            .expect("an explicit scene is planned");
        assert!(plan.first.points.abs_diff(2000) < 300, "{plan:?}");
        assert!(
            plan.first.point_substeps() > POINT_SUBSTEPS_PER_TICK,
            "{plan:?}"
        );
        assert!(plan.resampled() && plan.fits(), "{plan:?}");
        assert!(plan.kept.points < plan.first.points, "{plan:?}");
        assert_eq!(scene.model.points.len(), plan.kept.points);
        let mut sim = Simulation::new(&scene);
        sim.prepare(SIMULATION_TICK_S);
        assert_eq!(sim.solver().substeps(), plan.kept.substeps);
        assert_eq!(sim.solver().known_dt_crit(), Some(plan.kept.dt_crit_s));
        assert_eq!(sim.solver().whole_step_mass(), plan.kept.mass_floor);
        let said = plan.to_string();
        assert!(said.contains("for real time"), "{said}");
    }

    /// A sampling whose tick fits is kept as asked: the liver's 1527 points at one sub-step.
    #[test]
    fn a_sampling_within_the_budget_is_kept() {
        let mut spec = scene::builtin("liver").expect("built-in scene");
        let asked = spec.sampling;
        spec.sampling.spacing = SpacingRule::RealTime { most_points: 1526 };
        let scene = build_scene(&spec, None, &mut Silent).unwrap();
        let plan = scene.sampling_plan.expect("an explicit scene is planned");
        assert!(!plan.resampled() && plan.fits(), "{plan:?}");
        assert_eq!(plan.kept.substeps, 1, "{plan:?}");
        spec.sampling = asked;
        let fixed = build_scene(&spec, None, &mut Silent).unwrap();
        assert!(fixed.sampling_plan.is_none());
        assert_eq!(fixed.model.points.len(), scene.model.points.len());
        assert_eq!(fixed.model.lattice.spacing, scene.model.lattice.spacing);
    }

    /// The stiff mode's projective step is one per tick whatever the spacing: no plan, the
    /// points asked for.
    #[test]
    fn the_stiff_mode_samples_the_points_asked_for() {
        let scene = block(2000, |s| s.features.stiff_mode = true);
        assert!(scene.sampling_plan.is_none());
        assert!(scene.model.points.len().abs_diff(2000) < 300);
    }

    /// A body too stiff for any sampling (E = 1 MPa, ν = 0.49: the wave speed 20 times the
    /// liver's) stops at the fewest points and says it is not real time, instead of thinning
    /// the body to nothing.
    #[test]
    fn a_body_too_stiff_for_real_time_keeps_the_fewest_points_and_says_so() {
        let scene = block(2000, |s| {
            s.material.youngs_modulus_pa = 1e6;
            s.material.poisson_ratio = 0.49;
        });
        let plan = scene.sampling_plan.expect("an explicit scene is planned");
        assert!(!plan.fits(), "{plan:?}");
        assert!(plan.kept.points.abs_diff(LEAST_POINTS) < 50, "{plan:?}");
        let said = plan.to_string();
        assert!(said.contains("not real time"), "{said}");
    }
}
