//! Elastic forces as the exact negative gradient of the MLS energy, with hourglass
//! stabilisation (physics.md §1.7, §1.9), and the matrix-free tangent product.
//!
//! Per point i with `u_ij = p_j − p_i`:
//!
//! ```text
//! B_i  = Σ_j u_ij ⊗ (w_ij x_ij)          F_p = B_i A_i⁺    F = complete(F_p)
//! Fe_i = −V_i P(F)                       k_i = α E V_i / tr A_i
//! M_i  = Fe_i A_i⁺ + k_i F_p
//! g_ij = M_i (w_ij x_ij) − k_i w_ij u_ij ;   f_j += g_ij ,   f_i −= g_ij
//! ```
//!
//! `M_i (w x)` is `Fe_i d_ij` (the stress term) plus `k_i w F_p x` (from the hourglass residual
//! `e_ij = u_ij − F_p x_ij`, whose force is `−k_i w_ij e_ij` on j). Every pair term is
//! antisymmetric, so Σf = 0 and Σ p × f = 0 hold to rounding. No allocation.

use crate::math::{Mat3, Vec3};
use crate::mls::material::{ElasticParams, stress, stress_differential};
use crate::mls::operator::{MlsOperator, PointRank, complete};

/// Figures from one force evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceStats {
    /// Strain energy Σ V_i ψ(F_i) (J).
    pub strain_energy: f64,
    /// Hourglass energy (J).
    pub hourglass_energy: f64,
    /// Smallest det F over points with stress.
    pub min_det_f: f64,
    /// Largest det F.
    pub max_det_f: f64,
    /// Points whose F was clamped (det F outside [0.2, 5]).
    pub clamped_points: u32,
    /// False if any F was not finite.
    pub finite: bool,
}

impl ForceStats {
    /// Total elastic energy (J).
    pub fn energy(&self) -> f64 {
        self.strain_energy + self.hourglass_energy
    }
}

/// Hourglass stiffness k_i = α E V_i / tr(A_i) (N/m).
#[inline]
pub fn hourglass_stiffness(params: &ElasticParams, volume: f64, trace_a: f64) -> f64 {
    if trace_a > 0.0 {
        params.hourglass_alpha * params.youngs_modulus_pa * volume / trace_a
    } else {
        0.0
    }
}

/// Adds the elastic forces at positions `p` to `f` (N). Only points with `active[i]` carry
/// their own stress when a mask is given (frozen points still act through their neighbours).
pub fn add_elastic_forces(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    p: &[Vec3],
    active: Option<&[bool]>,
    f: &mut [Vec3],
) -> ForceStats {
    let mut stats = ForceStats {
        strain_energy: 0.0,
        hourglass_energy: 0.0,
        min_det_f: f64::INFINITY,
        max_det_f: f64::NEG_INFINITY,
        clamped_points: 0,
        finite: true,
    };
    let mut offsets = [[0.0f64; 3]; BUFFERED];
    for i in 0..op.len() {
        if active.is_some_and(|a| !a[i]) {
            continue;
        }
        let term = op.point(i);
        if let PointRank::Orphan = term.rank {
            continue;
        }
        let (ids, wx, w) = op.padded_row(i);
        let used = op.neighbours(i).len();
        let (b, sum_wuu) = accumulate_fit(ids, wx, w, used, p, p[i], &mut offsets);
        let fp = b * term.a_pinv;
        let full = complete(fp, &term.rank);
        let s = stress(params, &full);
        let v = volumes[i];
        let k = hourglass_stiffness(params, v, term.trace_a);
        stats.strain_energy += v * s.psi;
        // Σ w |u − F_p x|² = Σ w |u|² − F_p : B for the least-squares F_p.
        stats.hourglass_energy += 0.5 * k * (sum_wuu - fp.component_mul(&b).sum()).max(0.0);
        stats.min_det_f = stats.min_det_f.min(s.det);
        stats.max_det_f = stats.max_det_f.max(s.det);
        stats.clamped_points += u32::from(s.clamped);
        stats.finite &= s.det.is_finite() && s.p.iter().all(|x| x.is_finite());
        let m = s.p * (-v) * term.a_pinv + fp * k;
        scatter_pair_forces(ids, wx, w, used, &m, k, p, i, &offsets, f);
    }
    stats
}

/// Offsets `u_ij = p_j − p_i` kept between the two passes over a row; rows longer than
/// this (support ratios above ~3) are recomputed in the second pass instead.
const BUFFERED: usize = 64;

/// `B = Σ_j u_ij ⊗ (w x)_ij` and `Σ_j w |u_ij|²` over the row (padding adds zero), leaving
/// the offsets in `u` for the scatter.
#[inline]
fn accumulate_fit(
    ids: &[u32],
    wx: [&[f64]; 3],
    w: &[f64],
    used: usize,
    p: &[Vec3],
    pi: Vec3,
    u: &mut [[f64; 3]; BUFFERED],
) -> (Mat3, f64) {
    let mut b = [0.0f64; 9];
    let mut wuu = 0.0;
    for k in 0..used {
        let q = p[ids[k] as usize];
        let d = [q.x - pi.x, q.y - pi.y, q.z - pi.z];
        if k < BUFFERED {
            u[k] = d;
        }
        let (a, bb, c) = (wx[0][k], wx[1][k], wx[2][k]);
        for r in 0..3 {
            b[3 * r] = d[r].mul_add(a, b[3 * r]);
            b[3 * r + 1] = d[r].mul_add(bb, b[3 * r + 1]);
            b[3 * r + 2] = d[r].mul_add(c, b[3 * r + 2]);
        }
        wuu = w[k].mul_add(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], wuu);
    }
    (Mat3::from_row_slice(&b), wuu)
}

/// Adds `g_ij = M (w x)_ij − k w_ij u_ij` to `f_j` and subtracts their sum from `f_i`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn scatter_pair_forces(
    ids: &[u32],
    wx: [&[f64]; 3],
    w: &[f64],
    used: usize,
    m: &Mat3,
    k: f64,
    p: &[Vec3],
    i: usize,
    u: &[[f64; 3]; BUFFERED],
    f: &mut [Vec3],
) {
    let pi = p[i];
    let mm = [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ];
    let mut acc = [0.0f64; 3];
    for k_slot in 0..used {
        let j = ids[k_slot] as usize;
        let d = if k_slot < BUFFERED {
            u[k_slot]
        } else {
            let q = p[j];
            [q.x - pi.x, q.y - pi.y, q.z - pi.z]
        };
        let (a, b, c) = (wx[0][k_slot], wx[1][k_slot], wx[2][k_slot]);
        let kw = -k * w[k_slot];
        let mut g = [0.0f64; 3];
        for r in 0..3 {
            g[r] = kw.mul_add(d[r], mm[r][0].mul_add(a, mm[r][1].mul_add(b, mm[r][2] * c)));
            acc[r] -= g[r];
        }
        f[j] += Vec3::new(g[0], g[1], g[2]);
    }
    f[i] += Vec3::new(acc[0], acc[1], acc[2]);
}

/// `out = K v`, where K = −∂f/∂p is the tangent stiffness of the elastic forces at `p`
/// (the rank-2 completion's dependence on p is left out, as in the force).
pub fn stiffness_product(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    p: &[Vec3],
    v: &[Vec3],
    out: &mut [Vec3],
) {
    for o in out.iter_mut() {
        *o = Vec3::zeros();
    }
    for i in 0..op.len() {
        let term = op.point(i);
        if let PointRank::Orphan = term.rank {
            continue;
        }
        let ids = op.neighbours(i);
        let (pi, vi) = (p[i], v[i]);
        let mut b = Mat3::zeros();
        let mut db = Mat3::zeros();
        for (j, pair) in ids.iter().zip(op.pair_terms(i)) {
            let j = *j as usize;
            b += (p[j] - pi) * pair.wx.transpose();
            db += (v[j] - vi) * pair.wx.transpose();
        }
        let fp = b * term.a_pinv;
        let dfp = db * term.a_pinv;
        let full = complete(fp, &term.rank);
        let vol = volumes[i];
        let k = hourglass_stiffness(params, vol, term.trace_a);
        let dp = stress_differential(params, &full, &dfp);
        let dm = dp * (-vol) * term.a_pinv + dfp * k;
        let mut acc = Vec3::zeros();
        for (j, pair) in ids.iter().zip(op.pair_terms(i)) {
            let j = *j as usize;
            let dg = dm * pair.wx - (v[j] - vi) * (k * pair.w);
            // K v = −δf.
            out[j] -= dg;
            acc += dg;
        }
        out[i] += acc;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mls::material::ElasticModel;
    use crate::model::{Kernel, Neighbourhoods, RestGrid};

    /// A jittered 4³ lattice with unit-ish volumes.
    fn cloud() -> (Vec<Vec3>, MlsOperator, Vec<f64>) {
        let s = 0.002;
        let mut rest = Vec::new();
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 33) as f64 / (1u64 << 31) as f64) - 0.5
        };
        for k in 0..4 {
            for j in 0..4 {
                for i in 0..4 {
                    rest.push(
                        Vec3::new(
                            i as f64 + 0.2 * rnd(),
                            j as f64 + 0.2 * rnd(),
                            k as f64 + 0.2 * rnd(),
                        ) * s,
                    );
                }
            }
        }
        let kernel = Kernel { support_m: 2.0 * s };
        let grid = RestGrid::build(&rest, kernel.support_m);
        let nb = Neighbourhoods::build(&rest, &grid, kernel.support_m, 0);
        let op = MlsOperator::build(&rest, &nb, &kernel);
        let volumes = vec![s * s * s; rest.len()];
        (rest, op, volumes)
    }

    fn deformed(rest: &[Vec3]) -> Vec<Vec3> {
        rest.iter()
            .enumerate()
            .map(|(i, x)| {
                let t = i as f64;
                x + Vec3::new((t * 0.7).sin(), (t * 1.3).cos(), (t * 0.37).sin()) * 2e-4
            })
            .collect()
    }

    fn energy(op: &MlsOperator, params: &ElasticParams, vol: &[f64], p: &[Vec3]) -> f64 {
        let mut f = vec![Vec3::zeros(); p.len()];
        add_elastic_forces(op, params, vol, p, None, &mut f).energy()
    }

    /// f = −∂U/∂p to finite-difference accuracy, for each model, with hourglass and volume term.
    #[test]
    fn forces_are_the_negative_energy_gradient() {
        let (rest, op, vol) = cloud();
        let p = deformed(&rest);
        for model in [
            ElasticModel::StVK,
            ElasticModel::MuellerCompat,
            ElasticModel::Corotated,
        ] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.model = model;
            params.volume_k = 3000.0;
            let mut f = vec![Vec3::zeros(); p.len()];
            add_elastic_forces(&op, &params, &vol, &p, None, &mut f);
            let scale = f.iter().map(|x| x.norm()).fold(0.0, f64::max);
            let h = 1e-8;
            for i in [0usize, 5, 21, 42, 63] {
                for a in 0..3 {
                    let mut pp = p.clone();
                    let mut pm = p.clone();
                    pp[i][a] += h;
                    pm[i][a] -= h;
                    let fd = -(energy(&op, &params, &vol, &pp) - energy(&op, &params, &vol, &pm))
                        / (2.0 * h);
                    assert!(
                        (fd - f[i][a]).abs() < 1e-6 * scale,
                        "{model:?} point {i} axis {a}: {fd} vs {}",
                        f[i][a]
                    );
                }
            }
        }
    }

    /// K v matches the finite-difference change of the forces (StVK, exact tangent).
    #[test]
    fn stiffness_product_matches_finite_differences() {
        let (rest, op, vol) = cloud();
        let p = deformed(&rest);
        let mut params = ElasticParams::stvk(5000.0, 0.45);
        params.volume_k = 1000.0;
        let dir: Vec<Vec3> = (0..p.len())
            .map(|i| Vec3::new((i as f64).cos(), (i as f64 * 2.1).sin(), 0.3))
            .collect();
        let mut kv = vec![Vec3::zeros(); p.len()];
        stiffness_product(&op, &params, &vol, &p, &dir, &mut kv);
        let h = 1e-7;
        let force_at = |s: f64| {
            let q: Vec<Vec3> = p.iter().zip(&dir).map(|(x, d)| x + d * s).collect();
            let mut f = vec![Vec3::zeros(); p.len()];
            add_elastic_forces(&op, &params, &vol, &q, None, &mut f);
            f
        };
        let (fp, fm) = (force_at(h), force_at(-h));
        let scale = kv.iter().map(|x| x.norm()).fold(0.0, f64::max);
        for i in 0..p.len() {
            let fd = -(fp[i] - fm[i]) / (2.0 * h);
            assert!((fd - kv[i]).norm() < 1e-5 * scale, "point {i}");
        }
    }

    #[test]
    fn momentum_is_conserved_exactly() {
        let (rest, op, vol) = cloud();
        let p = deformed(&rest);
        let params = ElasticParams::stvk(5000.0, 0.45);
        let mut f = vec![Vec3::zeros(); p.len()];
        add_elastic_forces(&op, &params, &vol, &p, None, &mut f);
        let scale: f64 = f.iter().map(|x| x.norm()).sum();
        let total: Vec3 = f.iter().sum();
        let torque: Vec3 = p.iter().zip(&f).map(|(x, g)| x.cross(g)).sum();
        let arm = p.iter().map(|x| x.norm()).fold(0.0, f64::max);
        assert!(total.norm() < 1e-13 * scale, "{total}");
        assert!(torque.norm() < 1e-13 * scale * arm, "{torque}");
    }
}
