//! Stiff mode: projective dynamics (Bouaziz et al. 2014) on the MLS operator
//! (physics.md §2.4, option 2).
//!
//! Why this was the stiff mode before the implicit mode (`implicit`): at E = 1 MPa and
//! ν = 0.499 the implicit system `M + dt²K` at dt = 1 ms has a condition number near 10⁵,
//! so CG from nothing needs well over a thousand iterations and a truncated solve is not
//! guaranteed stable (the implicit mode warm-starts it and guards it with a line search).
//! Projective dynamics solves with
//! one constant matrix, `M/dt² + Σ_i w_i G_iᵀ G_i (+ hourglass)`, factored once (sparse
//! Cholesky, AMD ordering) and reused every tick; each local/global iteration decreases the
//! step's energy, so it is stable for any stiffness and any ν, at a fixed cost per tick.
//!
//! Energy per point: `μ V ‖F − R‖² + (3λ/2) V ‖F − F/∛det F‖²` (at small strain the linear
//! elastic energy `μ ε:ε + λ/2 (tr ε)²`), plus the exact hourglass quadratic. R comes from a
//! warm-started rotation extraction (Müller et al. 2016), cheap enough for every point every
//! iteration. The scalar system is `L ⊗ I₃`: one N×N factor serves the three components when
//! they share their fixed dofs (otherwise one factor per pattern).

use nalgebra::UnitQuaternion;

use super::Solver;
use super::blade::Field;
use super::events::{SolverEvent, StepReport};
use super::projective_contact::FaceContacts;
use crate::math::{Mat3, Vec3};
use crate::mls::forces::hourglass_stiffness;
use crate::mls::operator::{PointRank, complete};
use crate::sparse_llt::{LltError, SparseLlt};

/// Rotation-extraction iterations per local step (warm-started from the last rotation).
const ROTATION_ITERATIONS: usize = 4;

/// One reduced linear system (the free dofs of the components sharing a fixed pattern).
pub(super) struct ComponentSystem {
    pub(super) components: Vec<usize>,
    /// Point → row in the reduced system, or `u32::MAX` if the dof is fixed.
    pub(super) row_of: Vec<u32>,
    /// Row → point.
    point_of: Vec<u32>,
    /// Entries L[row, fixed point] that move to the right-hand side.
    coupling: Vec<(u32, u32, f64)>,
    llt: SparseLlt,
    rhs: Vec<f64>,
}

pub(super) struct Projective {
    dt: f64,
    systems: Vec<ComponentSystem>,
    strain_weight: Vec<f64>,
    volume_weight: Vec<f64>,
    rotations: Vec<UnitQuaternion<f64>>,
    rhs: Vec<Vec3>,
    start: Vec<Vec3>,
    /// The blade's faces in the global solve; `None` when the components do not share one
    /// system (rollers), where the faces are projected after the step instead.
    contacts: Option<FaceContacts>,
}

impl Solver {
    pub(super) fn tick_projective(&mut self, dt: f64) -> StepReport {
        let mut pd = match self.projective.take() {
            Some(pd) if pd.dt == dt => pd,
            _ => match Projective::build(self, dt) {
                Ok(pd) => pd,
                Err(message) => return self.unbuilt_step(&message),
            },
        };
        self.begin_one_step_tick();
        if pd.contacts.is_some()
            && let Some(blade) = &mut self.blade
        {
            blade.take_up_slack(dt);
        }
        let report = pd.step(self, dt);
        let in_solve = pd.contacts.is_some();
        self.projective = Some(pd);
        if !in_solve {
            // The faces push the tissue out after the step (a projection with the step's
            // velocities updated): weak, the rest of the body does not take part.
            self.project_blade(dt, false);
        }
        self.end_one_step_tick(dt);
        if let Some(blade) = &mut self.blade {
            blade.end_tick();
        }
        report
    }
}

impl Projective {
    fn build(s: &Solver, dt: f64) -> Result<Self, String> {
        let n = s.p.len();
        let lame = s.params.effective_lame();
        let mut strain_weight = vec![0.0; n];
        let mut volume_weight = vec![0.0; n];
        for i in 0..n {
            match s.op.point(i).rank {
                PointRank::Full => {
                    strain_weight[i] = 2.0 * lame.mu * s.volume[i];
                    volume_weight[i] = 3.0 * (lame.lambda + s.params.volume_k) * s.volume[i];
                }
                PointRank::Planar { .. } => strain_weight[i] = 2.0 * lame.mu * s.volume[i],
                PointRank::Orphan => {}
            }
        }
        let columns = assemble_columns(s, dt, &strain_weight, &volume_weight);
        let systems = factor_systems(s, &columns)?;
        let contacts = match systems.as_slice() {
            [one] => Some(FaceContacts::with_room(one.point_of.len())),
            _ => None,
        };
        Ok(Self {
            contacts,
            dt,
            systems,
            strain_weight,
            volume_weight,
            rotations: vec![UnitQuaternion::identity(); n],
            rhs: vec![Vec3::zeros(); n],
            start: vec![Vec3::zeros(); n],
        })
    }

    fn step(&mut self, s: &mut Solver, dt: f64) -> StepReport {
        let n = s.p.len();
        let h2 = dt * dt;
        self.start.copy_from_slice(&s.p);
        if let Some(held) = &mut s.held {
            // Taken at the step's start: explicit in the implicit step.
            held.forces(&s.p, &mut s.held_force, true, super::held::Vertices::All);
        }
        if let Some(blade) = &mut s.blade {
            // The lips' push on the flats, at the step's start too.
            blade.lip_forces(&s.p, &s.mass, &mut s.lip_force, dt, Field::Implicit);
        }
        // The inertial prediction y (with the applied loads) goes into the right-hand side; the
        // iterations start from p + dt·v instead. With a truncated number of iterations the
        // tick map's steady state is then the true equilibrium: started from y, a resting
        // body would settle where the unfinished iterations balance the load, not at rest.
        for i in 0..n {
            let applied = s.applied_load(i) + s.lip_force[i];
            for a in 0..3 {
                if s.fixed[i][a] {
                    s.scratch[0][i][a] = s.target[i][a];
                    s.p[i][a] = s.target[i][a];
                } else {
                    let coast = self.start[i][a] + dt * s.v[i][a];
                    s.scratch[0][i][a] = coast + h2 * applied[a] / s.mass[i];
                    s.p[i][a] = coast;
                }
            }
        }
        let iterations = s.config.projective_iterations;
        for iteration in 0..iterations {
            self.local_step(s, h2);
            for sys in &mut self.systems {
                sys.solve(&self.rhs, &mut s.p);
            }
            if let (Some(contacts), Some(blade), [sys]) = (
                &mut self.contacts,
                &mut s.blade,
                self.systems.as_mut_slice(),
            ) {
                contacts.resolve(
                    blade,
                    &mut s.p,
                    &s.rest,
                    &mut sys.llt,
                    &sys.row_of,
                    &sys.point_of,
                    iteration + 1 == iterations,
                );
            }
        }
        if let (Some(contacts), Some(blade)) = (&self.contacts, &mut s.blade) {
            blade.add_step_force(contacts.on_tissue);
        }
        let decay = (-s.config.damping_per_s * dt).exp();
        // Work of the applied loads over the step (moving constraints are not tracked here).
        let mut work = 0.0;
        for i in 0..n {
            work += (s.applied_load(i) + s.lip_force[i]).dot(&(s.p[i] - self.start[i]));
        }
        let mut finite = true;
        for i in 0..n {
            let v = (s.p[i] - self.start[i]) / dt * decay;
            finite &= v.iter().all(|x| x.is_finite());
            s.v[i] = v;
            for a in 0..3 {
                if s.fixed[i][a] {
                    s.v[i][a] = 0.0;
                }
            }
        }
        if !finite {
            s.p.copy_from_slice(&self.start);
            s.v.iter_mut().for_each(|v| *v = Vec3::zeros());
            s.events.push(SolverEvent::Diverged {
                tick: s.tick,
                reason: super::DivergenceReason::NonFinite,
            });
            return StepReport {
                diverged: true,
                ..StepReport::default()
            };
        }
        let stats = s.evaluate_elastic(super::ForceBuffer::Force);
        s.note_clamping(&stats);
        StepReport {
            substeps: 1,
            dt_sub_s: dt,
            rollbacks: 0,
            diverged: false,
            kinetic_energy: s.kinetic_energy(),
            elastic_energy: stats.energy(),
            min_det_f: stats.min_det_f,
            clamped_points: stats.clamped_points,
            iterations: s.config.projective_iterations,
            work_j: work,
        }
    }

    /// Right-hand side `M/dt² y + Σ_i w_i G_iᵀ T_i`, with the targets T_i (nearest rotation,
    /// and F scaled to det 1) at the current positions, and the surface layer's residual
    /// tension `−V_i G_iᵀ (F S₀)` there too: a force at the iterate, not in the matrix (its
    /// Hessian V Gᵀ(S₀ ⊗ I)G is constant and small beside 2μV GᵀG: σ/2μ ≈ 0.13 at a 5 %
    /// prestrain, so the iterations still contract), exact at their fixed point.
    fn local_step(&mut self, s: &Solver, h2: f64) {
        let (op, p, y, mass) = (&s.op, &s.p, &s.scratch[0], &s.mass);
        for (i, r) in self.rhs.iter_mut().enumerate() {
            *r = y[i] * (mass[i] / h2);
        }
        for i in 0..op.len() {
            let ws = self.strain_weight[i];
            if ws == 0.0 {
                continue;
            }
            let term = op.point(i);
            let fp = op.fitted_gradient(i, p);
            let f = complete(fp, &term.rank);
            let q = &mut self.rotations[i];
            extract_rotation(&f, q);
            let mut target = q.to_rotation_matrix().into_inner() * ws;
            // The completion column is not part of G_i p; take it out of the target.
            let completion = f - fp;
            target -= completion * ws;
            if let Some(s0) = s.prestress.stress_of(i) {
                target -= f * s0 * s.volume[i];
            }
            let wv = self.volume_weight[i];
            if wv > 0.0 {
                let det = f.determinant();
                let iso = if det > 0.0 {
                    f / det.cbrt()
                } else {
                    q.to_rotation_matrix().into_inner()
                };
                target += iso * wv;
            }
            // Σ_k c_ik (T c_ik)ᵀ-style scatter: rhs_k += T c_ik.
            let cii = -(term.a_pinv * term.sum_wx);
            self.rhs[i] += target * cii;
            for (j, pair) in op.neighbours(i).iter().zip(op.pair_terms(i)) {
                self.rhs[*j as usize] += target * (term.a_pinv * pair.wx);
            }
        }
    }
}

/// Closest rotation to `f`, refined from `q` in place (Müller, Bender, Chentanez, Macklin,
/// "A robust method to extract the rotational part of deformations", MIG 2016).
fn extract_rotation(f: &Mat3, q: &mut UnitQuaternion<f64>) {
    for _ in 0..ROTATION_ITERATIONS {
        let r = q.to_rotation_matrix().into_inner();
        let mut num = Vec3::zeros();
        let mut den = 0.0;
        for c in 0..3 {
            num += r.column(c).cross(&f.column(c));
            den += r.column(c).dot(&f.column(c));
        }
        let omega = num / (den.abs() + 1e-9);
        let w = omega.norm();
        if w < 1e-12 {
            break;
        }
        let axis = nalgebra::Unit::new_unchecked(omega / w);
        *q = UnitQuaternion::from_axis_angle(&axis, w) * *q;
        *q = UnitQuaternion::new_normalize(q.into_inner());
    }
}

/// A scalar matrix given by its full columns, factored once per fixed pattern of the three
/// components (usually all three share one).
pub(super) fn factor_systems(
    s: &Solver,
    columns: &[Vec<(u32, f64)>],
) -> Result<Vec<ComponentSystem>, String> {
    let n = s.p.len();
    let mut systems: Vec<ComponentSystem> = Vec::new();
    for c in 0..3 {
        let pattern: Vec<bool> = s.fixed.iter().map(|f| f[c]).collect();
        if let Some(sys) = systems
            .iter_mut()
            .find(|sys| (0..n).all(|i| (sys.row_of[i] == u32::MAX) == pattern[i]))
        {
            sys.components.push(c);
            continue;
        }
        systems.push(ComponentSystem::factor(columns, &pattern, c)?);
    }
    Ok(systems)
}

/// The full symmetric scalar matrix `M/dt² + Σ_i (w_s + w_v) G_iᵀG_i + hourglass`, by column:
/// `columns[k]` lists (row, value) with rows sorted.
pub(super) fn assemble_columns(
    s: &Solver,
    dt: f64,
    strain_weight: &[f64],
    volume_weight: &[f64],
) -> Vec<Vec<(u32, f64)>> {
    let n = s.p.len();
    let op = &s.op;
    let mut acc = vec![0.0; n];
    let mut listed = vec![false; n];
    let mut touched: Vec<usize> = Vec::new();
    let mut columns = Vec::with_capacity(n);
    for k in 0..n {
        touched.clear();
        let mut add = |row: usize, v: f64, acc: &mut Vec<f64>, touched: &mut Vec<usize>| {
            if !std::mem::replace(&mut listed[row], true) {
                touched.push(row);
            }
            acc[row] += v;
        };
        add(k, s.mass[k] / (dt * dt), &mut acc, &mut touched);
        let owners = std::iter::once(k as u32).chain(op.neighbours(k).iter().copied());
        for i in owners {
            let i = i as usize;
            let term = op.point(i);
            if let PointRank::Orphan = term.rank {
                continue;
            }
            let w = strain_weight[i] + volume_weight[i];
            let khg = hourglass_stiffness(&s.params, s.volume[i], term.trace_a);
            // The coefficient of point k in point i's gradient: c_ik = A⁺ β_k with β = w x
            // for a neighbour and β = −Σ w x for i itself.
            let slot = (k != i).then(|| {
                op.neighbours(i)
                    .iter()
                    .position(|&j| j as usize == k)
                    .expect("neighbourhoods are symmetric")
            });
            let beta_k = slot.map_or(-term.sum_wx, |sl| op.pair(i, sl).wx);
            let c_k = term.a_pinv * beta_k;
            // Stencil of i: i itself and its neighbours.
            let stencil = std::iter::once((i, -term.sum_wx, 0.0)).chain(
                op.neighbours(i)
                    .iter()
                    .zip(op.pair_terms(i))
                    .map(|(j, pr)| (*j as usize, pr.wx, pr.w)),
            );
            for (l, beta_l, w_l) in stencil {
                let c_l = term.a_pinv * beta_l;
                // Strain/volume: w c_l·c_k. Hourglass: −k β_lᵀ A⁺ β_k.
                let mut v = w * c_l.dot(&c_k) - khg * beta_l.dot(&c_k);
                // Hourglass Laplacian part Σ_j w_ij (e_j − e_i)(e_j − e_i)ᵀ.
                if l == k && l != i {
                    v += khg * w_l;
                } else if k == i && l != i {
                    v -= khg * w_l;
                }
                add(l, v, &mut acc, &mut touched);
            }
            match slot {
                None => add(i, khg * term.sum_w, &mut acc, &mut touched),
                Some(sl) => add(i, -khg * op.pair(i, sl).w, &mut acc, &mut touched),
            }
        }
        touched.sort_unstable();
        let column: Vec<(u32, f64)> = touched.iter().map(|&r| (r as u32, acc[r])).collect();
        for &r in &touched {
            acc[r] = 0.0;
            listed[r] = false;
        }
        columns.push(column);
    }
    columns
}

impl ComponentSystem {
    pub(super) fn factor(
        columns: &[Vec<(u32, f64)>],
        fixed: &[bool],
        component: usize,
    ) -> Result<Self, String> {
        let n = fixed.len();
        let mut row_of = vec![u32::MAX; n];
        let mut point_of = Vec::new();
        for i in 0..n {
            if !fixed[i] {
                row_of[i] = point_of.len() as u32;
                point_of.push(i as u32);
            }
        }
        let m = point_of.len();
        // Lower triangle of the reduced matrix, and the free–fixed coupling.
        let mut col_ptr = Vec::with_capacity(m + 1);
        let mut row_idx = Vec::new();
        let mut values = Vec::new();
        let mut coupling = Vec::new();
        col_ptr.push(0usize);
        for (k, column) in columns.iter().enumerate() {
            let ck = row_of[k];
            for &(r, v) in column {
                let rr = row_of[r as usize];
                if ck != u32::MAX {
                    if rr != u32::MAX && rr >= ck {
                        row_idx.push(rr as usize);
                        values.push(v);
                    }
                } else if rr != u32::MAX {
                    coupling.push((rr, k as u32, v));
                }
            }
            if ck != u32::MAX {
                col_ptr.push(row_idx.len());
            }
        }
        // Rows within a column must be sorted in the reduced numbering: row_of is monotone,
        // so the original order is kept.
        let llt = SparseLlt::factor(m, &col_ptr, &row_idx, &values, 3).map_err(|e| match e {
            LltError::Symbolic(_) => e.to_string(),
            LltError::NotPositiveDefinite(detail) => {
                format!("the projective-dynamics matrix is not positive definite: {detail}")
            }
        })?;
        Ok(Self {
            components: vec![component],
            row_of,
            point_of,
            coupling,
            llt,
            rhs: vec![0.0; 3 * m],
        })
    }

    /// Solves for this system's components and writes them into `p` (fixed dofs are read
    /// from `p`, where the step put their targets).
    pub(super) fn solve(&mut self, rhs: &[Vec3], p: &mut [Vec3]) {
        let m = self.point_of.len();
        let k = self.components.len();
        for (col, &c) in self.components.iter().enumerate() {
            let b = &mut self.rhs[col * m..(col + 1) * m];
            for (row, &i) in self.point_of.iter().enumerate() {
                b[row] = rhs[i as usize][c];
            }
            for &(row, fixed_point, v) in &self.coupling {
                b[row as usize] -= v * p[fixed_point as usize][c];
            }
        }
        self.llt.solve_in_place(&mut self.rhs, k);
        for (col, &c) in self.components.iter().enumerate() {
            for (row, &i) in self.point_of.iter().enumerate() {
                p[i as usize][c] = self.rhs[col * m + row];
            }
        }
    }
}
