//! Implicit mode: linearly implicit Euler (Baraff & Witkin 1998; physics.md §2.4, option 1)
//! — one Newton step of backward Euler per tick, solved by preconditioned conjugate
//! gradients on the exact StVK tangent (applied as the forces' directional difference),
//! warm-started from the last tick's velocity change.
//!
//! Why: the explicit mode's sub-steps per tick grow as 1/spacing (ω_max ∝ 1/h). Here a tick
//! is one step whatever the spacing, and what grows instead is the conjugate gradients'
//! iteration count, ∝ √κ of `M + h²K`. With the Jacobi preconditioner (the default) that
//! is ∝ 1/h again, though measured far below the sub-steps (the warm start); with the
//! factored projective-dynamics matrix as the preconditioner (`M + h² w GᵀG ⊗ I₃`,
//! rotation-invariant, so it stays good under large rotations; factored once) κ no longer
//! depends on the spacing, only on how far the tissue's tangent is from that Laplacian
//! (ν, above all). A factor left stale by a cut is still symmetric positive definite, so the
//! iteration still converges to the right step; it is only slower where the cut changed
//! the stencils. The comparison with the explicit and projective modes is in
//! docs/CUTTING-DECISIONS.md, "A step that does not shrink with the spacing".
//!
//! The step, with mass damping γ: `((1 + hγ)M + h²K) Δv = h(f − γMv) − h²K v`, then
//! `v += Δv`, `x += h v`, shortened by a line search until the tick's incremental potential
//! is no higher than at its start. At rest under balanced loads the right-hand side is
//! zero, so a truncated solve keeps the true equilibrium.

use super::Solver;
use super::events::{DivergenceReason, SolverEvent, StepReport};
use super::held::Vertices;
use super::implicit_coarse::Coarse;
use super::projective::{ComponentSystem, assemble_columns, factor_systems};
use crate::math::Vec3;
use crate::mls::operator::PointRank;

/// How the implicit mode's conjugate gradients are preconditioned.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ImplicitPreconditioner {
    /// The diagonal: no set-up, any region; iterations grow with 1/spacing (as √κ).
    #[default]
    Jacobi,
    /// The projective-dynamics matrix with the P-wave modulus as its weight, factored once:
    /// iterations that do not grow with 1/spacing, at a solve that does (its fill).
    Factored,
    /// The diagonal plus a coarse correction on 2×2×2 blocks of lattice cells, factored
    /// once (`implicit_coarse`).
    TwoLevel,
}

pub(super) struct Implicit {
    dt: f64,
    /// The last tick's Δv: the next one's first guess.
    warm: Vec<Vec3>,
    /// Conjugate-gradient vectors: residual, preconditioned residual, direction, product.
    r: Vec<Vec3>,
    z: Vec<Vec3>,
    d: Vec<Vec3>,
    q: Vec<Vec3>,
    /// The positions at the tick's start, which it is linearised about.
    start: Vec<Vec3>,
    /// The inertial target y of the tick's incremental potential.
    target_y: Vec<Vec3>,
    /// The Newton step from the first guess, in velocity.
    step_dv: Vec<Vec3>,
    factor: Option<Vec<ComponentSystem>>,
    coarse: Option<Coarse>,
}

impl Solver {
    pub(super) fn tick_implicit(&mut self, dt: f64) -> StepReport {
        let mut im = match self.implicit.take() {
            Some(im) if im.dt == dt => im,
            _ => match Implicit::build(self, dt) {
                Ok(im) => im,
                Err(message) => return self.unbuilt_step(&message),
            },
        };
        self.begin_one_step_tick();
        let report = im.step(self, dt);
        self.implicit = Some(im);
        if !report.diverged {
            // The blade's faces push the tissue out after the step (as in stiff mode when
            // its faces are not in the solve): the contact is not in the linear system.
            // So do the lips and the spine, as forces over the tick (`push_lips`).
            self.push_lips(dt);
            self.project_blade(dt, false);
        }
        self.end_one_step_tick(dt);
        if let Some(blade) = &mut self.blade {
            blade.end_tick();
        }
        report
    }
}

impl Solver {
    /// Builds the implicit step for ticks of `dt` before the first tick (a factored
    /// preconditioner is the start-up's work, not the first tick's).
    pub(super) fn prepare_implicit(&mut self, dt: f64) {
        if self.implicit.as_ref().is_none_or(|im| im.dt != dt) {
            // On failure the first tick reports it (`unbuilt_step`).
            self.implicit = Implicit::build(self, dt).ok();
        }
    }
}

impl Implicit {
    fn build(s: &Solver, dt: f64) -> Result<Self, String> {
        let n = s.p.len();
        let damping = 1.0 + dt * s.config.damping_per_s;
        // The P-wave modulus λ + 2μ matches the tangent's diagonal (as the Jacobi estimate
        // does); the volume part is folded into the one weight.
        let lame = s.params.effective_lame();
        let modulus = lame.lambda + 2.0 * lame.mu + s.params.volume_k;
        let weight: Vec<f64> = (0..n)
            .map(|i| match s.op.point(i).rank {
                PointRank::Orphan => 0.0,
                _ => modulus * s.volume[i],
            })
            .collect();
        // M/dt'² with dt' = h/√(1 + hγ) is (1 + hγ)M/h²: the matrix is the preconditioner
        // over h².
        let dt_mass = dt / damping.sqrt();
        let columns = || assemble_columns(s, dt_mass, &weight, &vec![0.0; n]);
        let (factor, coarse) = match s.config.implicit_preconditioner {
            ImplicitPreconditioner::Jacobi => (None, None),
            ImplicitPreconditioner::Factored => (Some(factor_systems(s, &columns())?), None),
            ImplicitPreconditioner::TwoLevel => (None, Some(Coarse::build(s, &columns())?)),
        };
        let zeros = vec![Vec3::zeros(); n];
        Ok(Self {
            dt,
            warm: zeros.clone(),
            r: zeros.clone(),
            z: zeros.clone(),
            d: zeros.clone(),
            q: zeros.clone(),
            start: zeros.clone(),
            target_y: zeros.clone(),
            step_dv: zeros,
            factor,
            coarse,
        })
    }

    fn step(&mut self, s: &mut Solver, dt: f64) -> StepReport {
        // The awake points only, as in the explicit mode: the rest of the body is at rest
        // and holds its place (a fixed dof of this tick's system).
        let active = std::mem::take(&mut s.active_list);
        let mut report = self.step_active(s, dt, &active);
        s.active_list = active;
        if !report.diverged {
            report.kinetic_energy = s.active_kinetic_energy();
        }
        report
    }

    /// Drops point i's first guess: it has left the awake region, and its last Δv belongs
    /// to another motion when it wakes again.
    pub(super) fn forget_guess(&mut self, i: usize) {
        self.warm[i] = Vec3::zeros();
    }

    fn step_active(&mut self, s: &mut Solver, dt: f64, active: &[u32]) -> StepReport {
        let h = dt;
        let damping = 1.0 + h * s.config.damping_per_s;
        let mut kinetic = 0.0;
        for &i in active {
            let i = i as usize;
            for a in 0..3 {
                if s.fixed[i][a] {
                    s.p[i][a] = s.target[i][a];
                }
            }
            self.start[i] = s.p[i];
            self.warm[i] = free_part(&s.fixed[i], self.warm[i]);
            s.v[i] = free_part(&s.fixed[i], s.v[i]);
            // y, the inertial target of the tick's incremental potential.
            self.target_y[i] = s.p[i] + s.v[i] * (h / damping);
            kinetic += s.mass[i] * s.v[i].norm_squared();
        }
        // Φ at the tick's start: its elastic and supports' energy, and the inertial term
        // ½ Σ m|v|²/(1 + hγ).
        let (phi0, stats, stored) = self.potential(s, h, active, true);
        // r = b − A Δv₀ with b = h(f − γMv) − h²Kv: one product, K(v + Δv₀).
        for &i in active {
            let i = i as usize;
            self.d[i] = s.v[i] + self.warm[i];
        }
        self.apply_k(s, active);
        let gamma = s.config.damping_per_s;
        for &i in active {
            let i = i as usize;
            let f = s.force[i] + s.applied_load(i) + s.contact_force[i];
            let r = (f - s.v[i] * (gamma * s.mass[i])) * h
                - self.warm[i] * (damping * s.mass[i])
                - self.q[i] * (h * h);
            self.r[i] = free_part(&s.fixed[i], r);
            self.step_dv[i] = self.warm[i];
        }
        // What the step's error is measured against: the tick's kinetic energy (doubled) or
        // the energy stored in the body and its supports, whichever is larger.
        let iterations = self.conjugate_gradients(s, h, kinetic.max(stored), active);
        // Backtrack along the step on the incremental potential, to no more than it was at
        // the start: one linearised step gained energy on the stiff near-incompressible
        // block (ν = 0.499, E = 1 MPa: energy ×7.7 in 100 ticks). Halved up to four
        // times; then the body stays where it is this tick (v = 0), which can only lose
        // energy.
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..5 {
            for &i in active {
                let i = i as usize;
                s.p[i] = self.start[i] + (s.v[i] + self.step_dv[i]) * (alpha * h);
            }
            let (phi, _, _) = self.potential(s, h, active, false);
            if phi <= phi0 + 1e-12 * phi0.abs() {
                accepted = true;
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            for &i in active {
                let i = i as usize;
                s.p[i] = self.start[i];
            }
        }
        let mut finite = true;
        let mut work = 0.0;
        for &i in active {
            let i = i as usize;
            let v = (s.p[i] - self.start[i]) / h;
            finite &= v.iter().all(|x| x.is_finite()) && s.p[i].iter().all(|x| x.is_finite());
            self.warm[i] = free_part(&s.fixed[i], v - s.v[i]);
            s.v[i] = free_part(&s.fixed[i], v);
            work += s.applied_load(i).dot(&(s.p[i] - self.start[i]));
        }
        s.slaves.interpolate(&mut s.p);
        if !finite {
            for &i in active {
                let i = i as usize;
                s.p[i] = self.start[i];
                s.v[i] = Vec3::zeros();
                self.warm[i] = Vec3::zeros();
            }
            s.events.push(SolverEvent::Diverged {
                tick: s.tick,
                reason: DivergenceReason::NonFinite,
            });
            return StepReport {
                diverged: true,
                ..StepReport::default()
            };
        }
        s.note_clamping(&stats);
        StepReport {
            substeps: 1,
            dt_sub_s: dt,
            rollbacks: 0,
            diverged: false,
            // Set by `step` once the awake list is back.
            kinetic_energy: 0.0,
            elastic_energy: stats.energy(),
            min_det_f: stats.min_det_f,
            clamped_points: stats.clamped_points,
            iterations,
            work_j: work,
        }
    }

    /// The tick's incremental potential at the current positions,
    /// Φ = (1 + hγ)/(2h²) ‖x − y‖²_M + E_elastic + E_supports + E_tool − f_applied·x, and
    /// the elastic forces' statistics. `first` writes the forces (elastic into `s.force`,
    /// the supports' letting vertices slide on the tray); a trial point of the line
    /// search only reads the friction state.
    fn potential(
        &mut self,
        s: &mut Solver,
        h: f64,
        active: &[u32],
        first: bool,
    ) -> (f64, crate::mls::forces::ForceStats, f64) {
        let damping = 1.0 + h * s.config.damping_per_s;
        let buffer = if first {
            super::ForceBuffer::Force
        } else {
            super::ForceBuffer::Scratch(0)
        };
        let stats = s.evaluate_elastic(buffer);
        let mut stored = stats.energy();
        if !stats.finite {
            return (f64::INFINITY, stats, f64::INFINITY);
        }
        if let Some(held) = &mut s.held {
            stored += held.forces(&s.p, &mut s.held_force, first, Vertices::Awake);
        }
        if let Some(contact) = &s.contact {
            stored += contact.forces(&s.p, &mut s.contact_force);
        }
        let mut phi = stored;
        for &i in active {
            let i = i as usize;
            let load = s.body_load(i);
            let offset = free_part(&s.fixed[i], s.p[i] - self.target_y[i]);
            phi += 0.5 * damping * s.mass[i] / (h * h) * offset.norm_squared() - load.dot(&s.p[i]);
        }
        (phi, stats, stored)
    }

    /// Solves A δv = r (A = (1 + hγ)M + h²K at x⁰) from zero into `step_dv`. Stops when the
    /// residual's energy rᵀP⁻¹r (≈ the step error's, eᵀAe, as P ≈ A) is within tolerance²
    /// of the tick's energy (`scale`), at the iteration cap, or at negative curvature (a
    /// compressed StVK tangent at a huge step), keeping the progress so far. A good first
    /// guess may need no iteration. Tried and not kept: an impulse scale Σ|hf|²/m (for stiff
    /// tissue it is measured in M⁻¹, far larger than the residual's P⁻¹ energy: ν = 0.499
    /// stopped at no iteration); a reduction relative to the first residual (near rest it
    /// chased what the tray's stiff springs leave in the Jacobi-preconditioned residual,
    /// 70–200 iterations a tick at the end of the liver's cut); the explicit guard's 1 nJ
    /// floor (the cantilever, which stores 25 nJ, stopped settling 2 % short).
    fn conjugate_gradients(&mut self, s: &mut Solver, h: f64, scale: f64, active: &[u32]) -> u32 {
        let dot = |a: &[Vec3], b: &[Vec3]| -> f64 {
            active
                .iter()
                .map(|&i| a[i as usize].dot(&b[i as usize]))
                .sum()
        };
        self.precondition(s, h, active);
        let mut rz = dot(&self.r, &self.z);
        let limit = s.config.implicit_tolerance.powi(2) * scale;
        if rz <= limit {
            return 0;
        }
        for &i in active {
            self.d[i as usize] = self.z[i as usize];
        }
        let mut iterations = 0;
        let damping = 1.0 + h * s.config.damping_per_s;
        for k in 0..s.config.implicit_max_iterations {
            iterations = k + 1;
            self.apply_k(s, active);
            for &i in active {
                let i = i as usize;
                let q = self.q[i] * (h * h) + self.d[i] * (damping * s.mass[i]);
                self.q[i] = free_part(&s.fixed[i], q);
            }
            let dq = dot(&self.d, &self.q);
            if dq <= 0.0 || !dq.is_finite() {
                break;
            }
            let alpha = rz / dq;
            for &i in active {
                let i = i as usize;
                self.step_dv[i] += self.d[i] * alpha;
                self.r[i] -= self.q[i] * alpha;
            }
            self.precondition(s, h, active);
            let rz_new = dot(&self.r, &self.z);
            if rz_new <= limit {
                break;
            }
            let beta = rz_new / rz;
            rz = rz_new;
            for &i in active {
                let i = i as usize;
                self.d[i] = self.z[i] + self.d[i] * beta;
            }
        }
        iterations
    }

    /// z = P⁻¹ r on the free dofs of the awake points.
    fn precondition(&mut self, s: &Solver, h: f64, active: &[u32]) {
        // (1 + hγ) m + h² diag K: the Jacobi preconditioner, and the fallback for a dof the
        // factor holds fixed but the body no longer does. Read now: cuts change both.
        let damping = 1.0 + h * s.config.damping_per_s;
        let diagonal = |i: usize| damping * s.mass[i] + h * h * s.precond[i];
        match &mut self.factor {
            None => {
                for &i in active {
                    let i = i as usize;
                    self.z[i] = self.r[i] / diagonal(i);
                }
                if let Some(coarse) = &mut self.coarse {
                    coarse.add_correction(&self.r, &mut self.z, h, active);
                }
            }
            Some(systems) => {
                // The factor is (1 + hγ)M/h² + wGᵀG: P⁻¹r = solve(r/h²) over the whole
                // body, the asleep points' residual zero. A dof the factor holds fixed but
                // the body frees (a node released since it was built) takes the diagonal
                // instead; a dof fixed since is dropped below.
                self.q.iter_mut().for_each(|x| *x = Vec3::zeros());
                self.z.iter_mut().for_each(|x| *x = Vec3::zeros());
                for &i in active {
                    self.q[i as usize] = self.r[i as usize] / (h * h);
                }
                for sys in systems.iter_mut() {
                    sys.solve(&self.q, &mut self.z);
                }
                for sys in systems.iter() {
                    for &c in &sys.components {
                        for &i in active {
                            let i = i as usize;
                            if sys.row_of[i] == u32::MAX && !s.fixed[i][c] {
                                self.z[i][c] = self.r[i][c] / diagonal(i);
                            }
                        }
                    }
                }
            }
        }
        for &i in active {
            let i = i as usize;
            self.z[i] = free_part(&s.fixed[i], self.z[i]);
        }
    }
}

impl Implicit {
    /// q = K d at the tick's start (`start`, whose forces are in `s.force`) on the awake
    /// points: the elastic part as the forces' directional difference through the
    /// evaluation kernel (the stencil passes over the awake region, on the pool when there
    /// is one), the supports' and the pressed tool's exact. An exact product with F and the
    /// stress held per point cost 1.4× as much per tick for the same iterations
    /// (docs/CUTTING-DECISIONS.md).
    fn apply_k(&mut self, s: &mut Solver, active: &[u32]) {
        let largest = active
            .iter()
            .map(|&i| self.d[i as usize].amax())
            .fold(0.0, f64::max);
        if largest == 0.0 {
            for &i in active {
                self.q[i as usize] = Vec3::zeros();
            }
            return;
        }
        // A millionth of a spacing at the largest entry: far above rounding in the
        // stencils' differences, far below any strain that bends the response.
        let eps = 1e-6 * s.spacing_m / largest;
        for &i in active {
            let i = i as usize;
            s.p[i] = self.start[i] + self.d[i] * eps;
        }
        s.evaluate_elastic(super::ForceBuffer::Scratch(0));
        for &i in active {
            let i = i as usize;
            self.q[i] = (s.force[i] - s.scratch[0][i]) / eps;
            s.p[i] = self.start[i];
        }
        // Slaved nodes back where their masters are.
        s.slaves.interpolate(&mut s.p);
        if let Some(held) = &s.held {
            held.add_stiffness_product(&s.p, &self.d, &mut self.q, Vertices::Awake);
        }
        if let Some(contact) = &s.contact {
            contact.add_stiffness_product(&s.p, &self.d, &mut self.q);
        }
    }
}

/// `x` with the fixed components zeroed.
fn free_part(fixed: &[bool; 3], mut x: Vec3) -> Vec3 {
    for a in 0..3 {
        if fixed[a] {
            x[a] = 0.0;
        }
    }
    x
}
