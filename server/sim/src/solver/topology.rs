//! What a cut or a stiffness change does to the solver between steps: the rows it changed
//! refitted, the preconditioner and the masses kept to the planned sub-steps (a floor on the
//! points whose fits a cut left stiffer), and the stable step.

use super::*;

impl Solver {
    /// The neighbourhoods of `points` changed (a cut): recompute their operator rows, the
    /// preconditioner and the stable-step bound around them. Local: the work follows the
    /// changed points, not the body. Removing neighbours can only stiffen the rows, so the
    /// step is shortened when the local bound rises above the current ω² (physics.md §2.2).
    ///
    /// A cut can leave a point with a nearly degenerate fit (four neighbours almost in a
    /// plane: cond(A) 8 000, under the rank test's 10⁴) whose d_ij, all along the weak
    /// direction, make the points of that fit hundreds of times stiffer than the body's:
    /// over a session of sixteen strokes on the shoulder that took the step from 6 to 448
    /// sub-steps per tick (seconds per tick). The points of such a fit get mass instead
    /// (selective mass scaling, as explicit FE codes do for distorted elements): each point
    /// at least `fit ω² / cap` times its built mass for every fit it is in, so no fit's ω²
    /// exceeds [`OMEGA_SQ_CAP_OVER_UNCUT`] × the largest of the uncut body. Inertia grows
    /// there; stiffness, and so the equilibrium, do not. A point whose fits recover gets its
    /// mass back.
    ///
    /// A slaved node's part of a fit is its masters' (its forces are handed back to them
    /// with weights φ): a virtual point in a fit 24 times over the cap made a shoulder
    /// session's master of 12.5 mg swing (a rollback, then doubled sub-steps for a
    /// second). Its masters — a dozen or more, most with small weights — take mass by
    /// their own columns: the least mass that brings a fit's ω² = V·M·Σ|c_k|²/m_k to the
    /// cap gives each term k the mass V·M·|c_k|·S/cap, S = Σ|c_k| (Cauchy–Schwarz), which
    /// leaves it |c_k|/S of the cap. The masters' terms take that; the fit's own points take
    /// the rest of the cap, S_own/S, as one factor (their fit ω² raised by S / S_own). A
    /// master also in the fit itself has its two terms counted apart. (Mass for every
    /// master by the fit's ω² added 19.3 g to the liver's session; this way, 8.1 g.)
    pub fn topology_changed(&mut self, points: &[u32], neighbours: &Neighbourhoods) {
        // Whole sub-steps are planned for the uncut body only.
        self.whole_steps_tried = true;
        self.op
            .update_points(points, &self.rest, neighbours, &self.kernel);
        if let Some(cap) = self.omega_sq_cap {
            for &i in points {
                let i = i as usize;
                let (omega_sq, own_columns, master_columns) = self.fit_omega_sq_of(i);
                self.fit_omega_sq[i] = if master_columns > 0.0 && omega_sq > cap {
                    omega_sq * (own_columns + master_columns) / own_columns.max(1e-300)
                } else {
                    omega_sq
                };
            }
        }
        // The diagonal stiffness of a point sums its own row and its neighbours' rows.
        self.touched_buf.clear();
        for &i in points {
            for j in std::iter::once(i).chain(self.op.neighbours(i as usize).iter().copied()) {
                if !std::mem::replace(&mut self.touched_flag[j as usize], true) {
                    self.touched_buf.push(j);
                }
            }
        }
        if let Some(cap) = self.omega_sq_cap {
            self.refresh_through_slaves(cap);
        }
        let mut local = 0.0f64;
        for &a in &self.touched_buf {
            let a = a as usize;
            self.touched_flag[a] = false;
            self.precond[a] =
                statics::diagonal_stiffness_of(&self.op, &self.params, &self.volume, a);
            // Fixed points are not integrated: they do not limit the step.
            if self.fixed[a] != [true; 3] {
                if let Some(cap) = self.omega_sq_cap {
                    let own = self.fit_omega_sq[a].max(self.through_slaves[a]);
                    let worst = (self.op.neighbours(a).iter())
                        .map(|&i| self.fit_omega_sq[i as usize])
                        .fold(own, f64::max);
                    let mass = self.base_mass[a] * (worst / cap).max(1.0);
                    self.mass[a] =
                        (self.kept).mass_for(a, mass, self.precond[a], self.omega_calibration);
                }
                local = local.max(self.precond[a] / self.mass[a]);
            }
        }
        if let Some(calibration) = self.omega_calibration {
            let omega_sq = calibration * local;
            if let Some(dt) = self.dt_crit {
                let current = timestep::omega_sq_of(dt);
                if omega_sq > current {
                    self.dt_crit = Some(timestep::dt_of(omega_sq));
                    // Re-plan the sub-steps at the next tick.
                    self.substeps_for_dt = f64::NAN;
                }
            }
        } else {
            self.dt_crit = None;
        }
        self.rebuild_eval_set();
        self.invalidate_projective();
    }

    /// Recomputes `through_slaves` from the slaved nodes now (a few hundred at most, each
    /// in a few dozen fits, few of them over the cap), and adds every point whose value
    /// was or is non-zero to the touched points, whose masses are set next: a master's
    /// column φ·d in a fit over the cap asks V·M·φ|d|·S of its mass, as an ω² (see
    /// [`Solver::topology_changed`]).
    pub(super) fn refresh_through_slaves(&mut self, cap: f64) {
        for &m in &self.through_slaves_list {
            self.through_slaves[m as usize] = 0.0;
            if !std::mem::replace(&mut self.touched_flag[m as usize], true) {
                self.touched_buf.push(m);
            }
        }
        self.through_slaves_list.clear();
        let modulus = self.params.wave_modulus();
        for &s in self.slaves.list() {
            // The fits it is in are its neighbours' (the lists are symmetric).
            for &i in self.op.neighbours(s as usize) {
                let i = i as usize;
                if self.fit_omega_sq[i] <= cap {
                    continue;
                }
                let Some(slot) = self.op.neighbours(i).iter().position(|&k| k == s) else {
                    continue;
                };
                let d = (self.op.point(i).a_pinv * self.op.pair(i, slot).wx).norm();
                // (Its Σ|c| again: only fits over the cap get here, a handful.)
                let (_, own_columns, master_columns) = self.fit_omega_sq_of(i);
                let scale = self.volume[i] * modulus * d * (own_columns + master_columns);
                for &(m, phi) in self.slaves.masters_of(s as usize) {
                    let m = m as usize;
                    if self.fixed[m] == [true; 3] {
                        continue;
                    }
                    let asked = scale * phi.abs() / self.base_mass[m];
                    if asked <= cap || asked <= self.through_slaves[m] {
                        continue;
                    }
                    if self.through_slaves[m] == 0.0 {
                        self.through_slaves_list.push(m as u32);
                    }
                    self.through_slaves[m] = asked;
                    if !std::mem::replace(&mut self.touched_flag[m], true) {
                        self.touched_buf.push(m as u32);
                    }
                }
            }
        }
    }

    pub(super) fn invalidate_projective(&mut self) {
        self.projective = None;
    }

    /// The critical explicit step (s) as last computed or planned, without computing it.
    pub fn known_dt_crit(&self) -> Option<f64> {
        self.dt_crit
    }

    /// Critical explicit step 2/ω_max (s), computing it if needed.
    pub fn dt_crit(&mut self) -> f64 {
        if let Some(dt) = self.dt_crit {
            return dt;
        }
        let (dt, omega_sq) = timestep::critical_time_step(self);
        self.set_dt_crit(dt, omega_sq);
        if self.omega_sq_cap.is_none() {
            self.set_omega_sq_cap();
        }
        dt
    }

    /// Keeps a power iteration's dt_crit, and the ratio that turns the diagonal bound into
    /// a ω² estimate.
    pub(super) fn set_dt_crit(&mut self, dt: f64, omega_sq: f64) {
        self.dt_crit = Some(dt);
        self.stiffening_at_estimate = self.max_stiffening;
        // Fixed points are not integrated: they do not limit the step.
        let diagonal = (0..self.p.len())
            .filter(|&i| self.fixed[i] != [true; 3])
            .map(|i| self.precond[i] / self.mass[i])
            .fold(0.0, f64::max);
        if omega_sq > 0.0 && diagonal > 0.0 {
            self.omega_calibration = Some(omega_sq / diagonal);
        }
    }

    /// Every fit's ω² with the built masses, and the cap a cut may leave them at.
    pub(super) fn set_omega_sq_cap(&mut self) {
        self.fit_omega_sq.resize(self.p.len(), 0.0);
        for i in 0..self.p.len() {
            self.fit_omega_sq[i] = self.fit_omega_sq_of(i).0;
        }
        let uncut = self.fit_omega_sq.iter().copied().fold(0.0, f64::max);
        self.omega_sq_cap = (uncut > 0.0).then_some(OMEGA_SQ_CAP_OVER_UNCUT * uncut);
    }

    /// The mass given to the uncut body for whole sub-steps (see `whole_substeps`), if any.
    pub fn whole_step_mass(&self) -> Option<WholeStepMass> {
        self.whole_step_mass
    }

    /// The ω² point i's fit gives the points in it: `V_i M Σ_k |d_ik|² / m_k` over the fit's
    /// points k (i itself with `d_ii = −Σ_j d_ij`; fixed points left out; a slaved node's
    /// share handed to its masters as its forces are, `φ_m² |d_ik|² / m_m` each), M the wave
    /// modulus, m the built masses; and Σ|column| of its points, and of slaved nodes'
    /// masters (φ_m·d_ik). The fit's stiffness is `V_i Bᵀ C B` with B made of the
    /// d_ik, so this is the trace of its mass-weighted Gram matrix: it adds up the shares
    /// that a diagonal estimate gives each point separately, and so sees a fit whose d_ik
    /// all point along one weak direction (a mode over all its points at once).
    pub(super) fn fit_omega_sq_of(&self, i: usize) -> (f64, f64, f64) {
        self.fit_omega_sq_with(i, &self.base_mass)
    }

    /// [`Solver::fit_omega_sq_of`] with the masses `mass`.
    pub(super) fn fit_omega_sq_with(&self, i: usize, mass: &[f64]) -> (f64, f64, f64) {
        let term = self.op.point(i);
        if matches!(term.rank, PointRank::Orphan) || self.volume[i] == 0.0 {
            return (0.0, 0.0, 0.0);
        }
        let free = |k: usize| self.fixed[k] != [true; 3];
        // (Σ|c|²/m, Σ|c| of points, Σ|c| of masters) of one point of the fit.
        let share = |k: usize, d: Vec3| -> (f64, f64, f64) {
            let masters = self.slaves.masters_of(k);
            let d = d.norm();
            if masters.is_empty() {
                return if free(k) {
                    (d * d / mass[k], d, 0.0)
                } else {
                    (0.0, 0.0, 0.0)
                };
            }
            (masters.iter().filter(|&&(m, _)| free(m as usize))).fold(
                (0.0, 0.0, 0.0),
                |(sum, own, by_masters), &(m, phi)| {
                    let c = phi.abs() * d;
                    (sum + c * c / mass[m as usize], own, by_masters + c)
                },
            )
        };
        let own = share(i, -(term.a_pinv * term.sum_wx));
        let (sum, own_columns, master_columns) = (self.op.neighbours(i).iter().enumerate())
            .map(|(slot, &j)| share(j as usize, term.a_pinv * self.op.pair(i, slot).wx))
            .fold(own, |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
        (
            self.volume[i] * self.params.wave_modulus() * sum,
            own_columns,
            master_columns,
        )
    }

    /// Points given mass after cuts (see [`Solver::topology_changed`]), and the mass added
    /// (kg). O(points): for reports.
    pub fn added_mass(&self) -> (usize, f64) {
        self.mass
            .iter()
            .zip(&self.base_mass)
            .filter(|(m, b)| m > b)
            .fold((0, 0.0), |(n, kg), (m, b)| (n + 1, kg + m - b))
    }
}
