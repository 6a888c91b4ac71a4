//! Mass scaling to whole sub-steps, as explicit FE codes offer it (LS-DYNA's DT2MS, Abaqus'
//! fixed-increment mass scaling): a tick of dt takes n = ⌈dt / (safety·dt_crit)⌉ sub-steps,
//! so a body whose dt_crit falls a few per cent short of allowing n − 1 pays a whole
//! sub-step — on the liver of Table 1, dt_crit 1.92 ms against the 2 ms that one sub-step
//! per 1 ms tick needs: twice the cost of every tick.
//!
//! The fastest modes live on the points whose lattice cells the organ's surface clips to
//! slivers (a tenth of a cell's volume under the stiffness of their neighbours' full fits).
//! A mass floor — no point lighter than a fraction f of a full cell's mass — slows exactly
//! those. The smallest f that raises dt_crit far enough is searched by bisection (a power
//! iteration per try), and only within `SolverConfig::mass_scaling_budget` of the body's
//! mass; otherwise nothing changes. It is done once, on the uncut body, before its first
//! tick (`Solver::prepare`, else in that tick). Stiffness, and so every equilibrium, is
//! untouched; the inertia of a surface layer grows by the reported mass. The cuts then keep
//! the sub-step count it gave (`kept_substeps`).
//!
//! A floor, not the least mass per point by its own ω² estimate (c·D_i/m_i, tried): that
//! reached the liver's step with 0.24 % of its mass against the floor's 0.40 %, but on the
//! cerebroma, aimed 5 % over the bound, it kept 4 sub-steps for 22 % of the default cut's
//! ticks (a cut stiffens the rows of the surface points beside it, and the estimate had
//! given mass only to those fastest before the cut); the floor, aimed 2 % over, keeps them
//! for 71 %.

use super::{Solver, SolverEvent, timestep};

/// dt_crit must clear the bound for n − 1 sub-steps by this much, so that the local step
/// updates of a cut's first re-meshes do not take the sub-step straight back.
pub(super) const HEADROOM: f64 = 1.02;

/// Bisection steps on the floor once the highest floor the budget allows has passed: the
/// floor kept is at most an eighth of that one above the least that would do.
const BISECTIONS: usize = 3;

/// What the scaling did, for reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct WholeStepMass {
    /// The floor, as a fraction of a full lattice cell's mass.
    pub floor_of_cell: f64,
    /// Points given mass.
    pub points: usize,
    /// Mass added (kg).
    pub added_kg: f64,
    /// The added mass over the body's.
    pub fraction: f64,
    /// Sub-steps per tick without it.
    pub substeps_before: u32,
    /// Sub-steps per tick with it.
    pub substeps_after: u32,
}

impl Solver {
    /// Gives the uncut body the least mass floor that lets ticks of `dt` take a sub-step
    /// fewer, within the budget (see the module doc); `dt_crit` is the body's as built.
    /// Returns dt_crit then.
    pub(super) fn scale_mass_to_whole_substeps(&mut self, dt: f64, dt_crit: f64) -> f64 {
        let budget = self.config.mass_scaling_budget;
        let safety = self.config.safety;
        let substeps = |dt_crit: f64| (dt / (safety * dt_crit)).ceil().max(1.0) as u32;
        let before = substeps(dt_crit);
        if budget <= 0.0 || before <= 1 || self.config.dt_override_s.is_some() {
            return dt_crit;
        }
        let wanted = HEADROOM * dt / ((before - 1) as f64 * safety);
        // The body's free points with volume (virtual nodes have none; fixed points are
        // not integrated and do not limit the step).
        let body: Vec<usize> = (0..self.material_points)
            .filter(|&i| self.fixed[i] != [true; 3] && self.volume[i] > 0.0)
            .collect();
        let body_kg: f64 = (0..self.material_points).map(|i| self.base_mass[i]).sum();
        let body_m3: f64 = (0..self.material_points).map(|i| self.volume[i]).sum();
        if body.is_empty() || body_kg <= 0.0 || body_m3 <= 0.0 {
            return dt_crit;
        }
        let cell_kg = body_kg / body_m3 * self.spacing_m.powi(3);
        let built = self.base_mass.clone();
        let added_at = |floor: f64| -> f64 {
            body.iter()
                .map(|&i| (floor * cell_kg - built[i]).max(0.0))
                .sum()
        };
        // The highest floor the budget allows (the added mass grows with the floor).
        let (mut lo, mut hi) = (0.0, 1.0);
        if added_at(hi) <= budget * body_kg {
            lo = hi;
        }
        for _ in 0..50 {
            let mid = 0.5 * (lo + hi);
            if added_at(mid) <= budget * body_kg {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let try_floor = |s: &mut Self, floor: f64| {
            for &i in &body {
                s.mass[i] = built[i].max(floor * cell_kg);
            }
            timestep::critical_time_step(s)
        };
        let (mut passing, mut failing) = (lo, 0.0);
        let mut found = try_floor(self, passing);
        if found.0 < wanted {
            self.mass.copy_from_slice(&built);
            return dt_crit;
        }
        for _ in 0..BISECTIONS {
            let mid = 0.5 * (passing + failing);
            let at_mid = try_floor(self, mid);
            if at_mid.0 >= wanted {
                (passing, found) = (mid, at_mid);
            } else {
                failing = mid;
            }
        }
        for &i in &body {
            self.mass[i] = built[i].max(passing * cell_kg);
        }
        self.base_mass.copy_from_slice(&self.mass);
        // The fits' ω² and the cap a cut may leave them at, from the masses now.
        self.set_omega_sq_cap();
        let (points, added_kg) = (body.iter())
            .filter(|&&i| self.mass[i] > built[i])
            .fold((0, 0.0), |(n, kg), &i| {
                (n + 1, kg + self.mass[i] - built[i])
            });
        let (dt_crit, omega_sq) = found;
        self.whole_step_mass = Some(WholeStepMass {
            floor_of_cell: passing,
            points,
            added_kg,
            fraction: added_kg / body_kg,
            substeps_before: before,
            substeps_after: substeps(dt_crit),
        });
        self.events.push(SolverEvent::MassScaled {
            tick: self.tick,
            points: points as u32,
            added_kg,
            substeps: substeps(dt_crit),
        });
        self.set_dt_crit(dt_crit, omega_sq);
        dt_crit
    }
}
