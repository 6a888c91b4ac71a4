//! Static equilibrium by Newton's method with Jacobi-preconditioned conjugate gradients on
//! the exact tangent (the quasi-static mode, used by the validation benchmarks).

use serde::Serialize;

use super::held::Vertices;
use super::{ForceBuffer, Solver};
use crate::math::Vec3;
use crate::mls::forces::{hourglass_stiffness, stiffness_product};
use crate::mls::{ElasticParams, MlsOperator, PointRank};

/// Outcome of a static solve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StaticReport {
    /// Residual fell below the tolerance.
    pub converged: bool,
    /// Newton iterations.
    pub newton_iterations: u32,
    /// Conjugate-gradient iterations over all Newton steps.
    pub cg_iterations: u32,
    /// Final residual force norm (N).
    pub residual_n: f64,
    /// Elastic energy at the solution (J).
    pub elastic_energy: f64,
    /// Newton solves on a frozen contact set after the first (0 when the first converged).
    pub contact_rounds: u32,
}

const MAX_NEWTON: u32 = 40;
/// Contact-set updates before a static solve gives up.
const MAX_CONTACT_ROUNDS: u32 = 30;
const MAX_CG: u32 = 20_000;
const CG_TOLERANCE: f64 = 1e-10;

/// A scalar per point approximating the diagonal of K (N/m), for Jacobi preconditioning:
/// `Σ V (λ + 2μ + k_v) |c|²` over every stencil the point appears in, plus hourglass terms.
pub(super) fn diagonal_stiffness(
    op: &MlsOperator,
    params: &ElasticParams,
    volume: &[f64],
) -> Vec<f64> {
    let mut d = vec![0.0; op.len()];
    let modulus = params.wave_modulus();
    for i in 0..op.len() {
        let term = op.point(i);
        if let PointRank::Orphan = term.rank {
            continue;
        }
        let v = volume[i];
        let k = hourglass_stiffness(params, v, term.trace_a);
        let dii = -(term.a_pinv * term.sum_wx);
        d[i] += v * modulus * dii.norm_squared();
        for (j, pair) in op.neighbours(i).iter().zip(op.pair_terms(i)) {
            let dij = term.a_pinv * pair.wx;
            d[*j as usize] += v * modulus * dij.norm_squared() + k * pair.w;
            d[i] += k * pair.w;
        }
    }
    // Points no stencil touches keep a unit diagonal so the preconditioner stays finite.
    for x in &mut d {
        if *x <= 0.0 {
            *x = 1.0;
        }
    }
    d
}

/// The same diagonal estimate for one point, from its own row and its neighbours' rows
/// (local: used after a cut changed a few rows).
pub(super) fn diagonal_stiffness_of(
    op: &MlsOperator,
    params: &ElasticParams,
    volume: &[f64],
    a: usize,
) -> f64 {
    let modulus = params.wave_modulus();
    let mut d = 0.0;
    let own = op.point(a);
    if !matches!(own.rank, PointRank::Orphan) {
        let k = hourglass_stiffness(params, volume[a], own.trace_a);
        let daa = -(own.a_pinv * own.sum_wx);
        d += volume[a] * modulus * daa.norm_squared() + k * own.sum_w;
    }
    for &i in op.neighbours(a) {
        let i = i as usize;
        let term = op.point(i);
        if matches!(term.rank, PointRank::Orphan) {
            continue;
        }
        if let Some(slot) = op.neighbours(i).iter().position(|&j| j as usize == a) {
            let pair = op.pair(i, slot);
            let k = hourglass_stiffness(params, volume[i], term.trace_a);
            d += volume[i] * modulus * (term.a_pinv * pair.wx).norm_squared() + k * pair.w;
        }
    }
    if d > 0.0 { d } else { 1.0 }
}

impl Solver {
    /// Solves for static equilibrium under the current loads and constraints, starting from
    /// the current positions (fixed dofs go to their targets). Velocities are zeroed.
    /// One-sided contacts (a tray, a pressed tool) are solved by an active set
    /// (`contact_set`): if a first Newton solve with each contact following its gap
    /// stalls, Newton on a frozen set, the set updated from the gaps, until it stops
    /// changing.
    pub fn solve_static(&mut self) -> StaticReport {
        let n = self.p.len();
        for i in 0..n {
            for a in 0..3 {
                if self.fixed[i][a] {
                    self.p[i][a] = self.target[i][a];
                }
            }
        }
        self.v.iter_mut().for_each(|v| *v = Vec3::zeros());
        let mut report = StaticReport {
            converged: false,
            newton_iterations: 0,
            cg_iterations: 0,
            residual_n: f64::INFINITY,
            elastic_energy: 0.0,
            contact_rounds: 0,
        };
        // First with each contact following its gap's sign: from a body that has not met
        // its supports yet, a set frozen at the start would let it fall through them.
        self.newton(&mut report);
        let mut settled = report.converged || self.freeze_contacts() == 0;
        for _ in 0..MAX_CONTACT_ROUNDS {
            if settled {
                break;
            }
            report.contact_rounds += 1;
            self.newton(&mut report);
            settled = self.freeze_contacts() == 0;
        }
        self.thaw_contacts();
        report.converged &= settled;
        if let Some(stats) = self.last_stats {
            self.note_clamping(&stats);
        }
        report
    }

    /// Freezes the contact sets at the current positions; how many contacts changed.
    fn freeze_contacts(&mut self) -> usize {
        let held = self.held.as_mut().map_or(0, |h| h.freeze(&self.p));
        held + self.contact.as_mut().map_or(0, |c| c.freeze(&self.p))
    }

    fn thaw_contacts(&mut self) {
        if let Some(held) = &mut self.held {
            held.thaw();
        }
        if let Some(contact) = &mut self.contact {
            contact.thaw();
        }
    }

    /// Newton's method with a backtracking line search on the potential energy, adding its
    /// iterations to `report`.
    fn newton(&mut self, report: &mut StaticReport) {
        let n = self.p.len();
        report.converged = false;
        let loads: f64 = (0..n)
            .map(|i| self.body_load(i).norm_squared())
            .sum::<f64>()
            .sqrt();
        let mut reference = loads;
        for it in 0..MAX_NEWTON {
            let (residual, energy) = self.residual_into_scratch();
            report.residual_n = residual;
            report.elastic_energy = energy;
            if it == 0 {
                reference = reference.max(residual);
            }
            if residual <= self.config.static_tolerance * reference || residual == 0.0 {
                report.converged = true;
                return;
            }
            report.newton_iterations += 1;
            let cg = self.conjugate_gradients();
            report.cg_iterations += cg;
            // Backtrack on the potential energy if the full Newton step does not decrease it.
            let potential0 = self.potential_energy();
            let mut alpha = 1.0;
            for _ in 0..12 {
                for i in 0..n {
                    let step = self.scratch[1][i] * alpha;
                    self.scratch[4][i] = self.p[i];
                    self.p[i] += step;
                }
                if self.potential_energy() <= potential0 + 1e-12 * potential0.abs() {
                    break;
                }
                self.p.copy_from_slice(&self.scratch[4]);
                alpha *= 0.5;
            }
        }
    }

    /// Writes the out-of-balance force (elastic + applied) on the free dofs into scratch[0];
    /// returns its norm and the elastic energy.
    fn residual_into_scratch(&mut self) -> (f64, f64) {
        let n = self.p.len();
        let stats = self.evaluate_elastic(ForceBuffer::Scratch(0));
        if let Some(held) = &mut self.held {
            held.forces(&self.p, &mut self.held_force, false, Vertices::All);
        }
        if let Some(contact) = &self.contact {
            contact.forces(&self.p, &mut self.contact_force);
        }
        let r = &mut self.scratch[0];
        self.last_stats = Some(stats);
        let mut norm = 0.0;
        for i in 0..n {
            r[i] += self.external[i]
                + self.config.gravity * self.base_mass[i]
                + self.held_force[i]
                + self.contact_force[i];
            for a in 0..3 {
                if self.fixed[i][a] {
                    r[i][a] = 0.0;
                }
            }
            norm += r[i].norm_squared();
        }
        (norm.sqrt(), stats.energy())
    }

    /// Elastic energy minus the work of the applied loads.
    fn potential_energy(&mut self) -> f64 {
        let n = self.p.len();
        let stats = self.evaluate_elastic(ForceBuffer::Scratch(3));
        let mut potential = stats.energy();
        if let Some(held) = &mut self.held {
            potential += held.forces(&self.p, &mut self.held_force, false, Vertices::All);
        }
        if let Some(contact) = &self.contact {
            potential += contact.forces(&self.p, &mut self.contact_force);
        }
        for i in 0..n {
            potential -= self.body_load(i).dot(&self.p[i]);
        }
        if stats.finite {
            potential
        } else {
            f64::INFINITY
        }
    }

    /// Solves K x = r (r in scratch[0]) for x in scratch[1] by Jacobi-PCG on the free dofs.
    /// Stops at negative curvature (keeping the progress so far). Returns the iterations.
    fn conjugate_gradients(&mut self) -> u32 {
        let n = self.p.len();
        let [r, x, d, q, z] = &mut self.scratch;
        let fixed = &self.fixed;
        let mask = |v: &mut [Vec3]| {
            for i in 0..n {
                for a in 0..3 {
                    if fixed[i][a] {
                        v[i][a] = 0.0;
                    }
                }
            }
        };
        let dot = |a: &[Vec3], b: &[Vec3]| (0..n).map(|i| a[i].dot(&b[i])).sum::<f64>();
        x.iter_mut().for_each(|v| *v = Vec3::zeros());
        let b_norm = dot(r, r).sqrt();
        if b_norm == 0.0 {
            return 0;
        }
        for i in 0..n {
            z[i] = r[i] / self.precond[i];
        }
        d.copy_from_slice(z);
        let mut rz = dot(r, z);
        let mut iterations = 0;
        for k in 0..MAX_CG {
            iterations = k + 1;
            let pre = Some(&self.prestress);
            stiffness_product(&self.op, &self.params, &self.volume, pre, &self.p, d, q);
            if let Some(held) = &self.held {
                held.add_stiffness_product(&self.p, d, q, Vertices::All);
            }
            if let Some(contact) = &self.contact {
                contact.add_stiffness_product(&self.p, d, q);
            }
            mask(q);
            let dq = dot(d, q);
            if dq <= 0.0 {
                if k == 0 {
                    // No curvature information at all: take a preconditioned gradient step.
                    x.copy_from_slice(z);
                }
                break;
            }
            let alpha = rz / dq;
            for i in 0..n {
                x[i] += d[i] * alpha;
                r[i] -= q[i] * alpha;
            }
            if dot(r, r).sqrt() <= CG_TOLERANCE * b_norm {
                break;
            }
            for i in 0..n {
                z[i] = r[i] / self.precond[i];
            }
            let rz_new = dot(r, z);
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..n {
                d[i] = z[i] + d[i] * beta;
            }
        }
        iterations
    }
}
