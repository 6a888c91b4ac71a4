//! The solver's state as its callers read and set it: positions, velocities, constraints,
//! loads, the material, the active set, and the forces at the current positions.

use super::*;

impl Solver {
    /// Current positions (m).
    pub fn positions(&self) -> &[Vec3] {
        &self.p
    }

    /// Current velocities (m/s).
    pub fn velocities(&self) -> &[Vec3] {
        &self.v
    }

    /// Rest positions (m).
    pub fn rest(&self) -> &[Vec3] {
        &self.rest
    }

    /// Point masses (kg).
    pub fn masses(&self) -> &[f64] {
        &self.mass
    }

    /// Point volumes (m³).
    pub fn volumes(&self) -> &[f64] {
        &self.volume
    }

    /// The MLS operator.
    pub fn operator(&self) -> &MlsOperator {
        &self.op
    }

    /// The material as the force evaluation sees it.
    pub fn params(&self) -> &ElasticParams {
        &self.params
    }

    /// Settings.
    pub fn config(&self) -> &SolverConfig {
        &self.config
    }

    /// The last tick's report.
    pub fn last_report(&self) -> &StepReport {
        &self.last
    }

    /// Ticks taken.
    pub fn tick_count(&self) -> u64 {
        self.tick
    }

    /// Sub-steps per tick currently used by the explicit mode.
    pub fn substeps(&self) -> u32 {
        self.substeps
    }

    /// Sub-steps per tick the explicit mode plans from dt_crit (and keeps through cuts):
    /// what it returns to once rollbacks and the stiffening's rise relax.
    pub fn planned_substeps(&self) -> u32 {
        self.planned_substeps
    }

    /// Overwrites positions (e.g. an initial deformation); velocities are kept.
    pub fn set_positions(&mut self, p: &[Vec3]) {
        self.p.copy_from_slice(p);
    }

    /// Puts residual tension into the body (`Prestress::surface_layer`), in every mode.
    pub fn set_prestress(&mut self, prestress: Prestress) {
        self.prestress = prestress;
    }

    /// Overwrites velocities.
    pub fn set_velocities(&mut self, v: &[Vec3]) {
        self.v.copy_from_slice(v);
    }

    /// Fixes the dofs of point i selected by `mask` at their current positions.
    pub fn fix(&mut self, i: usize, mask: [bool; 3]) {
        self.fixed[i] = mask;
        self.target[i] = self.p[i];
        self.invalidate_projective();
    }

    /// Releases every constraint.
    pub fn release_all(&mut self) {
        self.fixed.iter_mut().for_each(|m| *m = [false; 3]);
        self.invalidate_projective();
    }

    /// Where the fixed dofs of point i should be at the end of the next tick (m). The
    /// explicit mode moves them linearly over the tick's sub-steps.
    pub fn set_target(&mut self, i: usize, target: Vec3) {
        self.target[i] = target;
    }

    /// Which dofs of each point are fixed.
    pub fn fixed(&self) -> &[[bool; 3]] {
        &self.fixed
    }

    /// Sets the external force on point i (N), held until changed.
    pub fn set_external_force(&mut self, i: usize, f: Vec3) {
        self.external[i] = f;
    }

    /// Holds the body by `held` (attachments, a tray) from the next step on; the
    /// critical step is measured again with its stiffness.
    pub fn hold(&mut self, mut held: held::Held) {
        held.wake(&self.is_active);
        self.held = Some(held);
        self.dt_crit = None;
    }

    /// Presses `contact`'s tool into the body in static solves (`None` lifts it off).
    pub fn press(&mut self, contact: Option<contact::ToolContact>) {
        self.contact_force
            .iter_mut()
            .for_each(|f| *f = Vec3::zeros());
        self.contact = contact;
    }

    /// Gives the body a blade to keep out of it in the explicit tick (`None` takes it
    /// away); see [`blade::BladeBody`].
    pub fn set_blade(&mut self, body: Option<blade::BladeBody>) {
        self.blade = body;
    }

    /// The blade, if the body has one.
    pub fn blade(&self) -> Option<&blade::BladeBody> {
        self.blade.as_ref()
    }

    /// The blade, to move it and rebuild its samples.
    pub fn blade_mut(&mut self) -> Option<&mut blade::BladeBody> {
        self.blade.as_mut()
    }

    /// The blade's faces push the samples out after the points moved in a step of `h`
    /// ([`blade::BladeBody::project`]): only points of the body with no fixed dof move, and
    /// of those only the active ones when `active_only` (the explicit mode integrates the
    /// active set; the projective one, every point). Returns (kinetic energy gained, work
    /// the blade did).
    pub(super) fn project_blade(&mut self, h: f64, active_only: bool) -> (f64, f64) {
        let Some(blade) = &mut self.blade else {
            return (0.0, 0.0);
        };
        let (is_active, fixed, mass) = (&self.is_active, &self.fixed, &self.mass);
        let body = self.material_points;
        blade.project(&mut self.p, &mut self.v, mass, h, |k| {
            if k < body && (!active_only || is_active[k]) && fixed[k] == [false; 3] {
                1.0 / mass[k]
            } else {
                0.0
            }
        })
    }

    /// The lips' and the spine's push (`BladeBody::lip_forces`) over a step of `h` taken
    /// after it, as an explicit sub-step of their own: each awake body point's free dofs
    /// moved by f·h²/m with its velocity by f·h/m, so the tissue gets the impulse the
    /// blade books where the rows are on awake, free points, as in the explicit mode (put
    /// through the implicit step's CG solve it got it only to the solve's tolerance,
    /// 3e-5). Bounded as in the explicit mode (`Field::Explicit`) with the tick as the
    /// step.
    pub(super) fn push_lips(&mut self, h: f64) {
        let Some(blade) = &mut self.blade else {
            return;
        };
        blade.lip_forces(
            &self.p,
            &self.mass,
            &mut self.lip_force,
            h,
            blade::Field::Explicit,
        );
        for &i in &self.active_list {
            let i = i as usize;
            if i >= self.material_points {
                continue;
            }
            let dv = self.lip_force[i] * (h / self.mass[i]);
            for a in 0..3 {
                if !self.fixed[i][a] {
                    self.v[i][a] += dv[a];
                    self.p[i][a] += dv[a] * h;
                }
            }
        }
    }

    /// The blade with the operator and rest positions its samples' rows are built from,
    /// and the points' positions.
    #[allow(clippy::type_complexity)]
    pub fn blade_with_rows(
        &mut self,
    ) -> Option<(&mut blade::BladeBody, &MlsOperator, &[Vec3], &[Vec3])> {
        let (op, rest, p) = (&self.op, &self.rest[..], &self.p[..]);
        self.blade.as_mut().map(|b| (b, op, rest, p))
    }

    /// The tool pressed into the body, if any.
    pub fn contact(&self) -> Option<&contact::ToolContact> {
        self.contact.as_ref()
    }

    /// One augmented-Lagrangian update of the pressed tool's contacts at the current
    /// positions ([`contact::ToolContact::absorb_give`]); nothing without a tool.
    pub fn absorb_contact_give(&mut self) {
        if let Some(contact) = &mut self.contact {
            contact.absorb_give(&self.p);
        }
    }

    /// The tool pressed into the body, to move it.
    pub fn contact_mut(&mut self) -> Option<&mut contact::ToolContact> {
        self.contact.as_mut()
    }

    /// What holds the body through its surface, if anything.
    pub fn held(&self) -> Option<&held::Held> {
        self.held.as_ref()
    }

    /// Sets the gravitational acceleration (m/s²) from the next step on.
    pub fn set_gravity(&mut self, g: Vec3) {
        self.config.gravity = g;
    }

    /// Removes every external force.
    pub fn clear_external_forces(&mut self) {
        self.external.iter_mut().for_each(|f| *f = Vec3::zeros());
    }

    /// Changes the material stiffness (Young's modulus, Pa) in place, e.g. a ramped
    /// tissue-stiffness fault; the time step is recomputed before the next tick.
    pub fn set_youngs_modulus(&mut self, e: f64) {
        let nu = self.poisson_ratio();
        let ratio = e / self.params.youngs_modulus_pa;
        self.params.lame = Lame::from_young_poisson(e, nu);
        self.params.youngs_modulus_pa = e;
        // The diagonal is linear in E at a fixed ν (the wave modulus and the hourglass
        // stiffness both are): scaled in place, no allocation on the simulation thread.
        if ratio.is_finite() && ratio > 0.0 {
            self.precond.iter_mut().for_each(|d| *d *= ratio);
            // ω² of M⁻¹K is linear in E too: the critical step scales as 1/√ratio, with
            // no power iteration (milliseconds at organ scale, on the simulation thread).
            self.dt_crit = self.dt_crit.map(|dt| dt / ratio.sqrt());
            // The fits' ω² are linear in E too, and so is their cap.
            self.omega_sq_cap = self.omega_sq_cap.map(|cap| cap * ratio);
            self.fit_omega_sq.iter_mut().for_each(|w| *w *= ratio);
            self.through_slaves.iter_mut().for_each(|w| *w *= ratio);
            // The layer's tension σ = Eε/(1 − ν) at its fixed prestrain ε.
            self.prestress.scale(ratio);
        } else {
            self.precond = statics::diagonal_stiffness(&self.op, &self.params, &self.volume);
            self.dt_crit = None;
            self.omega_sq_cap = None;
        }
        self.substeps_for_dt = f64::NAN;
        self.invalidate_projective();
    }

    pub(super) fn poisson_ratio(&self) -> f64 {
        let Lame { lambda, mu } = self.params.lame;
        lambda / (2.0 * (lambda + mu))
    }

    /// Restricts the explicit mode to `points` (the cutting-affected region): every other
    /// point is frozen where it is, at rest, and costs nothing per sub-step; frozen points
    /// next to active ones still push on them through their fits. Reuses its buffers.
    pub fn set_active(&mut self, points: &[u32]) {
        for &i in &self.active_list {
            self.is_active[i as usize] = false;
        }
        // The previous list, to stop the points that leave it.
        std::mem::swap(&mut self.active_list, &mut self.retired);
        self.active_list.clear();
        for &i in points {
            // Slaved nodes are never integrated: they follow their masters.
            if !self.slaves.is_slaved(i as usize)
                && !std::mem::replace(&mut self.is_active[i as usize], true)
            {
                self.active_list.push(i);
            }
        }
        self.active_list.sort_unstable();
        for &i in &self.retired {
            if !self.is_active[i as usize] {
                self.v[i as usize] = Vec3::zeros();
                if let Some(implicit) = &mut self.implicit {
                    implicit.forget_guess(i as usize);
                }
            }
        }
        self.eval_set.get_or_insert_with(EvalSet::default);
        self.rebuild_eval_set();
        if let Some(held) = &mut self.held {
            held.wake(&self.is_active);
        }
    }

    /// Rebuilds the restricted evaluation set for the active list and the slaved nodes with
    /// an active master (whose every fit must be evaluated: they hand the force back).
    pub(super) fn rebuild_eval_set(&mut self) {
        let Some(set) = &mut self.eval_set else {
            return;
        };
        self.eval_seed.clear();
        self.eval_seed.extend_from_slice(&self.active_list);
        for &s in self.slaves.list() {
            let masters = self.slaves.masters_of(s as usize);
            if masters.iter().any(|&(k, _)| self.is_active[k as usize]) {
                self.eval_seed.push(s);
            }
        }
        self.eval_seed.sort_unstable();
        set.rebuild(&self.op, &self.eval_seed, true);
    }

    /// Makes every point active again.
    pub fn activate_all(&mut self) {
        self.active_list.clear();
        for i in 0..self.p.len() {
            let active = !self.slaves.is_slaved(i);
            self.is_active[i] = active;
            if active {
                self.active_list.push(i as u32);
            }
        }
        self.eval_set = None;
        if let Some(held) = &mut self.held {
            held.wake(&self.is_active);
        }
    }

    /// The points the explicit mode integrates.
    pub fn active_points(&self) -> &[u32] {
        &self.active_list
    }

    /// Kinetic energy of the free dofs of active points (J).
    pub(super) fn active_kinetic_energy(&self) -> f64 {
        let mut e = 0.0;
        for &i in &self.active_list {
            let i = i as usize;
            for a in 0..3 {
                if !self.fixed[i][a] {
                    e += 0.5 * self.mass[i] * self.v[i][a] * self.v[i][a];
                }
            }
        }
        e
    }

    /// Deformation gradient of point i now.
    pub fn deformation_gradient(&self, i: usize) -> Mat3 {
        self.op.deformation_gradient(i, &self.p)
    }

    /// Elastic forces at the current positions (N), and their statistics.
    pub fn elastic_forces(&mut self) -> (&[Vec3], ForceStats) {
        let stats = self.evaluate_elastic(ForceBuffer::Force);
        (&self.force, stats)
    }

    /// Kinetic energy of the free dofs (J).
    pub fn kinetic_energy(&self) -> f64 {
        kinetic_energy(&self.mass, &self.v, &self.fixed)
    }

    /// The loads on point i besides the tissue's and the supports': applied forces and
    /// gravity (N).
    pub(super) fn body_load(&self, i: usize) -> Vec3 {
        self.external[i] + self.config.gravity * self.base_mass[i]
    }

    /// The loads on point i that do work in a one-step tick: `body_load` and the supports'
    /// force (N).
    pub(super) fn applied_load(&self, i: usize) -> Vec3 {
        self.body_load(i) + self.held_force[i]
    }

    /// A one-step mode's solver could not be built (cannot happen for positive masses): the
    /// state is kept and the tick reported diverged.
    pub(super) fn unbuilt_step(&mut self, message: &str) -> StepReport {
        debug_assert!(false, "{message}");
        self.events.push(SolverEvent::Diverged {
            tick: self.tick,
            reason: DivergenceReason::NonFinite,
        });
        StepReport {
            diverged: true,
            ..StepReport::default()
        }
    }

    /// Begins a tick taken in one step (projective, implicit): slaved nodes are fixed dofs,
    /// held for the tick where their masters are now (the step has no place for the
    /// interpolation), and every blade sample is a candidate (the step has no speed bound).
    pub(super) fn begin_one_step_tick(&mut self) {
        self.slaves.interpolate(&mut self.p);
        for &i in self.slaves.list() {
            self.target[i as usize] = self.p[i as usize];
        }
        if let Some(blade) = &mut self.blade {
            blade.begin_tick();
            blade.begin_attempt();
            blade.begin_substep(0.0, 1.0, &self.p, f64::INFINITY);
        }
        self.crack_sink.begin_tick();
    }

    /// A one-step tick (implicit, projective) is done: the crack takes its share of what
    /// moves, and its sink is one tick older.
    pub(super) fn end_one_step_tick(&mut self, dt: f64) {
        self.crack_sink.absorb(&mut self.v, &self.mass, dt);
        self.crack_sink.end_tick();
    }

    /// The crack front jumped at a cost of `energy_j`: the crack takes up to that much
    /// kinetic energy from the points that carried the front over the next ticks
    /// ([`crack_sink::CrackSink`]).
    pub fn sink_crack_energy(&mut self, energy_j: f64) {
        if let Some(blade) = &self.blade {
            self.crack_sink.open(blade.front_points(), energy_j);
        }
    }
}
