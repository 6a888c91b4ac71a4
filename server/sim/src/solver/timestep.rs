//! The stable explicit step from the largest eigenvalue of M⁻¹K (physics.md §2.2): power
//! iteration with the matrix-free tangent product, over the free dofs.

use super::Solver;
use crate::math::Vec3;
use crate::mls::forces::stiffness_product;

/// Power iteration converges from below; this covers the remaining underestimate of ω².
const RAYLEIGH_MARGIN: f64 = 1.1;

/// Largest step allowed when the body has no stiffness at all (s).
const MAX_DT: f64 = 1.0;

/// `2/ω_max` at the current positions (s), and the ω² it comes from.
pub(super) fn critical_time_step(s: &mut Solver) -> (f64, f64) {
    let omega_sq = largest_eigenvalue(s);
    if omega_sq <= 0.0 || !omega_sq.is_finite() {
        return (MAX_DT, 0.0);
    }
    (dt_of(omega_sq), omega_sq)
}

/// The critical step for ω² (with the power iteration's margin), capped.
pub(super) fn dt_of(omega_sq: f64) -> f64 {
    if omega_sq <= 0.0 {
        return MAX_DT;
    }
    (2.0 / (omega_sq * RAYLEIGH_MARGIN).sqrt()).min(MAX_DT)
}

/// The ω² a critical step corresponds to (inverse of [`dt_of`]).
pub(super) fn omega_sq_of(dt: f64) -> f64 {
    (2.0 / dt).powi(2) / RAYLEIGH_MARGIN
}

/// λ_max(M⁻¹K) by power iteration with Rayleigh quotients in the M inner product.
fn largest_eigenvalue(s: &mut Solver) -> f64 {
    let n = s.p.len();
    let [x, y, ..] = &mut s.scratch;
    // A deterministic vector with energy in every mode, the fastest included.
    for (i, xi) in x.iter_mut().enumerate() {
        let t = i as f64;
        *xi = Vec3::new(
            (1.7 * t + 0.3).sin(),
            (2.9 * t + 1.1).sin(),
            (0.61 * t + 2.3).sin(),
        );
        for a in 0..3 {
            if s.fixed[i][a] {
                xi[a] = 0.0;
            }
        }
    }
    let m_norm = |x: &[Vec3]| {
        (0..n)
            .map(|i| s.mass[i] * x[i].norm_squared())
            .sum::<f64>()
            .sqrt()
    };
    let norm = m_norm(x);
    if norm == 0.0 {
        return 0.0;
    }
    x.iter_mut().for_each(|v| *v /= norm);
    let mut lambda = 0.0;
    for _ in 0..s.config.power_iterations {
        // Slaved nodes move with their masters and hand their forces back: the product
        // is the one the masters feel (Pᵀ K P).
        s.slaves.interpolate_vectors(x);
        stiffness_product(&s.op, &s.params, &s.volume, Some(&s.prestress), &s.p, x, y);
        if let Some(held) = &s.held {
            held.add_stiffness_product(&s.p, x, y, super::held::Vertices::All);
        }
        s.slaves.hand_back(y);
        for i in 0..n {
            for a in 0..3 {
                if s.fixed[i][a] {
                    y[i][a] = 0.0;
                }
            }
        }
        // x is M-normalised, so the Rayleigh quotient is xᵀ K x.
        lambda = (0..n).map(|i| x[i].dot(&y[i])).sum::<f64>();
        for i in 0..n {
            x[i] = y[i] / s.mass[i];
        }
        let norm = m_norm(x);
        if norm == 0.0 || !norm.is_finite() {
            break;
        }
        x.iter_mut().for_each(|v| *v /= norm);
    }
    lambda
}
