//! Keeping the planned sub-steps through cuts. A cut changes the fits beside it, and the
//! local step update after it (`Solver::topology_changed`: the calibrated diagonal bound
//! D_i/m_i of the points it touched) may shorten dt_crit. Where that falls short of the
//! step the planned sub-steps need, the whole tick pays a sub-step more for the rest of the
//! session — on the liver, whose mass floor (`whole_substeps`) gave it one sub-step per
//! tick, the seventh stroke of a session took it back to two, doubling every later tick's
//! cost for the sake of a few points whose rows a wound left stiffer.
//!
//! So a touched point whose bound would exceed the planned step's ω² is given the mass
//! that brings it there, as the cap on degenerate fits does for stability — stiffness, and
//! so every equilibrium, untouched — as long as the mass so given stays within what is left
//! of `SolverConfig::mass_scaling_budget` after the whole-step floor. A point outside the
//! budget gets none, and the step falls as before. A point's share is recomputed whenever a
//! cut touches it again (a point whose rows recover gets its mass back).

use super::{Solver, timestep};

/// The bound is kept this far under the planned step's, so that rounding in the sub-step
/// count (a ceiling) cannot tip it over.
const UNDER_THE_BOUND: f64 = 0.999;

/// Mass given to cut points to keep the planned sub-steps, for reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SubstepKeepingMass {
    /// Points given mass.
    pub points: usize,
    /// Mass given (kg).
    pub added_kg: f64,
    /// The most mass given at any time so far (kg): a point's share goes back when a later
    /// cut leaves its rows softer.
    pub most_kg: f64,
    /// The points given mass then.
    pub most_points: usize,
}

/// The state of that scaling.
#[derive(Debug, Clone, Default)]
pub(super) struct KeptSubsteps {
    /// The ω² a touched point's bound may reach, from the planned sub-steps; `None` when no
    /// plan is kept (no budget, a forced sub-step, before the first plan).
    omega_sq_limit: Option<f64>,
    /// Mass that may be given (kg).
    budget_kg: f64,
    /// Mass given now (kg) and the points it went to.
    added_kg: f64,
    points: usize,
    /// The most given at once (kg), and to how many points.
    most_kg: f64,
    most_points: usize,
    /// Per point: the mass given to it (kg).
    added: Vec<f64>,
}

impl KeptSubsteps {
    /// What is given now.
    pub(super) fn given(&self) -> SubstepKeepingMass {
        SubstepKeepingMass {
            points: self.points,
            added_kg: self.added_kg.max(0.0),
            most_kg: self.most_kg,
            most_points: self.most_points,
        }
    }

    /// Point `a`'s mass, `mass` as the cut's fits leave it, raised if its calibrated
    /// diagonal bound (`diagonal` / mass × `calibration`) would shorten the step below the
    /// planned sub-steps' and the budget allows (see the module doc).
    pub(super) fn mass_for(
        &mut self,
        a: usize,
        mass: f64,
        diagonal: f64,
        calibration: Option<f64>,
    ) -> f64 {
        if let Some(given) = self.added.get_mut(a) {
            let old = std::mem::replace(given, 0.0);
            if old > 0.0 {
                self.added_kg -= old;
                self.points -= 1;
            }
        }
        let (Some(limit), Some(calibration)) = (self.omega_sq_limit, calibration) else {
            return mass;
        };
        let extra = diagonal * calibration / limit - mass;
        // (A non-finite bound gives nothing rather than a NaN mass.)
        if !extra.is_finite() || extra <= 0.0 || self.added_kg + extra > self.budget_kg {
            return mass;
        }
        self.added[a] = extra;
        self.added_kg += extra;
        self.points += 1;
        if self.added_kg > self.most_kg {
            (self.most_kg, self.most_points) = (self.added_kg, self.points);
        }
        mass + extra
    }
}

impl Solver {
    /// Keeps ticks of `dt` at `substeps` sub-steps from now on (called with every plan):
    /// the budget is set once, from the body's mass as built and what the whole-step floor
    /// took of it.
    pub(super) fn keep_planned_substeps(&mut self, dt: f64, substeps: u32) {
        let budget = self.config.mass_scaling_budget;
        if budget <= 0.0 || self.config.dt_override_s.is_some() {
            self.kept.omega_sq_limit = None;
            return;
        }
        if self.kept.added.is_empty() {
            let floor_kg = self.whole_step_mass.map_or(0.0, |w| w.added_kg);
            let body_kg: f64 = self.base_mass[..self.material_points].iter().sum();
            self.kept.budget_kg = (budget * (body_kg - floor_kg) - floor_kg).max(0.0);
            self.kept.added = vec![0.0; self.p.len()];
        }
        let dt_needed = dt / (substeps as f64 * self.config.safety);
        self.kept.omega_sq_limit = Some(UNDER_THE_BOUND * timestep::omega_sq_of(dt_needed));
    }

    /// Mass given to cut points to keep the planned sub-steps (part of
    /// [`Solver::added_mass`]).
    pub fn substep_keeping_mass(&self) -> SubstepKeepingMass {
        self.kept.given()
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_support;
    use super::*;
    use crate::model::Neighbourhoods;
    use crate::validate::LatticeCube;

    /// A crack across half a lattice cube (the pairs across a plane between two layers)
    /// leaves the fits at its front with fewer neighbours, and the rows of two points
    /// there stiffer than any in the uncut cube; the local step update then shortens
    /// dt_crit below what ticks planned 5 % inside two sub-steps need: without a budget
    /// they take three from then on. With one, those points get the least mass that keeps
    /// two (7.6 % more each, 0.045 % of the body), only points the cut touched, the
    /// stiffness untouched (the same forces bit for bit), and a pushed body rings down at
    /// two sub-steps with no rollback. A budget under what they need changes nothing.
    #[test]
    fn a_cut_keeps_the_planned_sub_steps_with_mass_on_the_points_it_touched() {
        let s = 0.003;
        let cube = LatticeCube::new(7, s);
        let rest = cube.rest.clone();
        let centre = cube.centre();
        // A crack: the pairs across the plane between the middle layers of x, over half
        // the cube in y (its front along z through the middle).
        let middle = (cube.rest[centre].x, cube.rest[centre].y);
        let crack = |neighbours: &mut Neighbourhoods| {
            let mut changed = Vec::new();
            for i in 0..rest.len() {
                for j in neighbours.of(i).to_vec() {
                    let (a, b) = (rest[i], rest[j as usize]);
                    let across = (a.x <= middle.0) != (b.x <= middle.0);
                    if across && a.y.max(b.y) < middle.1 {
                        neighbours.remove(i, j);
                        neighbours.remove(j as usize, i as u32);
                        changed.extend([i as u32, j]);
                    }
                }
            }
            changed.sort_unstable();
            changed.dedup();
            changed
        };
        let volume = vec![s * s * s; rest.len()];
        let mass: Vec<f64> = volume.iter().map(|v| v * 1060.0).collect();
        let body_kg: f64 = mass.iter().sum();
        let cut = |budget: f64| {
            let mut neighbours = cube.neighbours(&rest, 8);
            let mut solver = cube.soft_solver(&rest, &volume, &mass, &neighbours);
            solver.config.mass_scaling_budget = budget;
            // Ticks 5 % inside two sub-steps' worth.
            let dt = 2.0 * solver.config.safety * solver.dt_crit() / 1.05;
            solver.prepare(dt);
            assert_eq!(solver.substeps(), 2);
            let changed = crack(&mut neighbours);
            solver.topology_changed(&changed, &neighbours);
            solver.plan_substeps(dt);
            (solver, dt, changed)
        };
        let (mut plain, ..) = cut(0.0);
        assert_eq!(plain.substeps(), 3, "the cut should cost a sub-step");
        assert_eq!(plain.substep_keeping_mass(), SubstepKeepingMass::default());
        let (mut kept, dt, changed) = cut(0.01);
        let given = kept.substep_keeping_mass();
        println!(
            "kept 2 sub-steps with {:.3e} kg on {} points ({:.3} % of the body; budget 1 %)",
            given.added_kg,
            given.points,
            100.0 * given.added_kg / body_kg
        );
        assert_eq!(kept.substeps(), 2);
        assert!(given.points > 0 && given.added_kg > 0.0);
        assert!(given.added_kg < 0.01 * body_kg);
        assert_eq!(
            (given.most_kg, given.most_points),
            (given.added_kg, given.points)
        );
        // Only points the cut touched (its rows and their neighbours') differ, and only
        // by the mass given to keep the sub-steps.
        let touched = |i: usize| {
            changed.iter().any(|&c| {
                c as usize == i || kept.operator().neighbours(c as usize).contains(&(i as u32))
            })
        };
        let mut differ = 0.0;
        for i in 0..rest.len() {
            if kept.mass[i] != plain.mass[i] {
                assert!(touched(i), "point {i} not touched by the cut");
                assert!(kept.mass[i] > plain.mass[i]);
                differ += kept.mass[i] - plain.mass[i];
            }
        }
        assert!((differ - given.added_kg).abs() <= 1e-12 * body_kg);
        // Same stiffness; and the pushed body rings down at two sub-steps.
        test_support::assert_same_stiffness(&mut plain, &mut kept, &rest);
        test_support::assert_rings_down_at(&mut kept, &rest, centre, dt, 2);
        // A budget under what they need (a tenth of it): as without one.
        let (tight, ..) = cut(0.1 * given.added_kg / body_kg);
        assert_eq!(tight.substeps(), 3);
        assert_eq!(tight.mass, plain.mass);
    }
}
