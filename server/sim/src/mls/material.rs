//! Constitutive models on the MLS deformation gradient (physics.md §1.6, §1.8, §1.10).
//!
//! * St. Venant–Kirchhoff (default): `E = ½(FᵀF − I)`, `S = λ tr E I + 2μ E`, `P = F S`.
//! * MuellerCompat: Müller 2004 as written (`ε = FᵀF − I`, `P = 2 F σ`). It is StVK with
//!   λ and μ multiplied by 4 (E_eff = 4E, same ν), kept so that old scenes can be compared.
//! * Corotated linear: `F = R S`, `e = S − I`, `P = R (λ tr e I + 2μ e)`. It does not soften
//!   in compression, which makes it the robust choice for large squashes.
//!
//! Optionally strain-stiffening (Fung's exponential on the distortional energy, the bulk
//! term as it is: the decoupled volumetric–isochoric idea of tissue laws, here as the
//! additive split of the strain into deviator and trace), and
//! Müller's volume term `½ k_v (det F − 1)²` is added. When det F leaves
//! [0.2, 5] the stress is evaluated at F with its singular values clamped to that range (and
//! an inversion undone): a robust fallback, not an energy gradient, reported as such.

use serde::Serialize;

use crate::math::Mat3;

/// The constitutive law.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ElasticModel {
    /// St. Venant–Kirchhoff with Green strain.
    #[default]
    StVK,
    /// Müller 2004 as written: StVK with four times the stiffness.
    MuellerCompat,
    /// Corotated linear elasticity.
    Corotated,
}

/// Lamé parameters (Pa).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Lame {
    /// λ.
    pub lambda: f64,
    /// μ (shear modulus).
    pub mu: f64,
}

impl Lame {
    /// From Young's modulus (Pa) and Poisson's ratio.
    pub fn from_young_poisson(e: f64, nu: f64) -> Self {
        Self {
            lambda: e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            mu: e / (2.0 * (1.0 + nu)),
        }
    }

    /// P-wave modulus λ + 2μ.
    pub fn p_wave_modulus(&self) -> f64 {
        self.lambda + 2.0 * self.mu
    }
}

/// Singular values of F are kept in this range when det F leaves it.
pub const DET_RANGE: (f64, f64) = (0.2, 5.0);

/// Everything the force evaluation needs to know about the material.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ElasticParams {
    /// Constitutive law.
    pub model: ElasticModel,
    /// Lamé parameters (Pa).
    pub lame: Lame,
    /// Young's modulus (Pa), for the hourglass stiffness.
    pub youngs_modulus_pa: f64,
    /// Hourglass coefficient α (physics.md §1.9; 0.05–0.1 recommended, 0 disables).
    pub hourglass_alpha: f64,
    /// Volume-term stiffness k_v (Pa); 0 disables.
    pub volume_k: f64,
    /// Evaluate the stress at F with clamped singular values when det F leaves
    /// [`DET_RANGE`] (the guard's inversion fallback). Off only to show what plain StVK does.
    pub clamp_inversion: bool,
    /// Strain-stiffening β (dimensionless; 0: none): Fung's exponential on the law's
    /// distortional energy ψ₀ (the strain's deviator), ψ = (c/2)(e^Q − 1) + ψ_vol with
    /// Q = 2βψ₀/E and c = E/β; the volumetric part ψ_vol stays as it is (see
    /// [`Self::stiffened`]).
    pub stiffening: f64,
}

impl ElasticParams {
    /// StVK with the given E (Pa) and ν, hourglass α = 0.1, no volume term.
    pub fn stvk(e: f64, nu: f64) -> Self {
        Self {
            model: ElasticModel::StVK,
            lame: Lame::from_young_poisson(e, nu),
            youngs_modulus_pa: e,
            hourglass_alpha: 0.1,
            volume_k: 0.0,
            clamp_inversion: true,
            stiffening: 0.0,
        }
    }

    /// The Lamé parameters the model actually uses (×4 for MuellerCompat).
    pub fn effective_lame(&self) -> Lame {
        match self.model {
            ElasticModel::MuellerCompat => Lame {
                lambda: 4.0 * self.lame.lambda,
                mu: 4.0 * self.lame.mu,
            },
            _ => self.lame,
        }
    }

    /// Young's modulus the model actually has (×4 for MuellerCompat), which sets the
    /// hourglass stiffness so that MuellerCompat with E/4 equals StVK with E throughout.
    pub fn effective_youngs_modulus(&self) -> f64 {
        match self.model {
            ElasticModel::MuellerCompat => 4.0 * self.youngs_modulus_pa,
            _ => self.youngs_modulus_pa,
        }
    }

    /// Modulus governing the fastest wave, including the volume term (Pa).
    pub fn wave_modulus(&self) -> f64 {
        self.effective_lame().p_wave_modulus() + self.volume_k
    }

    /// How much faster the fastest wave's ω² is where the stiffening multiplies the
    /// distortional tangent by `factor`: (K + 4μ·factor/3) / (K + 4μ/3), the bulk modulus K
    /// unstiffened.
    #[inline]
    pub fn wave_factor(&self, factor: f64) -> f64 {
        let lame = self.effective_lame();
        let bulk = lame.lambda + 2.0 * lame.mu / 3.0 + self.volume_k;
        let shear = 4.0 * lame.mu / 3.0;
        (bulk + shear * factor) / (bulk + shear)
    }
}

/// Past this exponent the tissue stiffens no further: the distortional part e^Q times over
/// (7.4 at 2), so a point crushed or torn at the blade's edge does not take the explicit
/// step down with an unbounded tangent. Q = 2 is a uniaxial stretch of about √(2/β): 45 %
/// at β = 10 (ψ₀ is (1 + ν)/3 · Eε² there, 0.97 × the whole law's ½Eε² at ν = 0.45).
const MOST_STIFFENING_EXPONENT: f64 = 2.0;

/// What the strain-stiffening makes of a point with base energy density ψ₀.
#[derive(Debug, Clone, Copy)]
pub struct Stiffened {
    /// dψ/dψ₀: the factor on the base law's stress.
    pub slope: f64,
    /// ψ (J/m³).
    pub psi: f64,
    /// The factor on the distortional tangent, at most: e^Q (1 + 2Q) below the cap,
    /// e^Qmax past it.
    pub tangent_factor: f64,
}

impl ElasticParams {
    /// The stiffening at base energy density `psi0` (call only with `stiffening` > 0).
    #[inline]
    pub fn stiffened(&self, psi0: f64) -> Stiffened {
        let q = self.stiffening_exponent(psi0);
        let slope = stiffening_slope(q);
        Stiffened {
            slope,
            psi: self.stiffened_energy(q),
            tangent_factor: slope + 2.0 * q * stiffening_curvature(q),
        }
    }

    /// Q = 2βψ₀/E for the base law's energy density ψ₀.
    #[inline]
    fn stiffening_exponent(&self, psi0: f64) -> f64 {
        2.0 * self.stiffening * psi0 / self.effective_youngs_modulus()
    }

    /// ψ = (c/2)(e^Q − 1), c = E/β, continued past [`MOST_STIFFENING_EXPONENT`] at the
    /// slope it reached there.
    #[inline]
    fn stiffened_energy(&self, q: f64) -> f64 {
        let c = self.effective_youngs_modulus() / self.stiffening;
        let qm = MOST_STIFFENING_EXPONENT;
        if q <= qm {
            0.5 * c * q.exp_m1()
        } else {
            0.5 * c * (qm.exp_m1() + qm.exp() * (q - qm))
        }
    }
}

/// dψ/dψ₀ = g'(Q) = e^min(Q, Qmax).
#[inline]
fn stiffening_slope(q: f64) -> f64 {
    q.min(MOST_STIFFENING_EXPONENT).exp()
}

/// d g'/dQ: e^Q, none past the cap.
#[inline]
fn stiffening_curvature(q: f64) -> f64 {
    if q < MOST_STIFFENING_EXPONENT {
        q.exp()
    } else {
        0.0
    }
}

/// First Piola–Kirchhoff stress and energy density at F.
#[derive(Debug, Clone, Copy)]
pub struct StressSample {
    /// P (Pa).
    pub p: Mat3,
    /// Energy density ψ (J/m³).
    pub psi: f64,
    /// det F before any clamping.
    pub det: f64,
    /// True when the singular values were clamped.
    pub clamped: bool,
    /// How much the stiffening raises the fastest wave's ω² here, at most (1 without
    /// stiffening): [`ElasticParams::wave_factor`] of the distortional tangent's e^Q (1 + 2Q).
    pub stiffening: f64,
}

/// P(F) and ψ(F) for the model, plus the volume term.
#[inline]
pub fn stress(params: &ElasticParams, f: &Mat3) -> StressSample {
    let det = f.determinant();
    let (lo, hi) = DET_RANGE;
    let outside = det < lo || det > hi || !det.is_finite();
    // By reference, not a copy: the caller has just written F with scalar stores, and a
    // vector copy of it stalls on store forwarding (14 % of a liver cut step, perf).
    let clamped_f;
    let (f_eval, clamped) = if outside && params.clamp_inversion {
        clamped_f = clamp_singular_values(f);
        (&clamped_f, true)
    } else {
        (f, false)
    };
    let (mut p, mut psi, stiffening) = if params.stiffening > 0.0 {
        let split = split_law(params, f_eval);
        let s = params.stiffened(split.psi_dev);
        (
            split.p_dev * s.slope + split.p_vol,
            s.psi + split.psi_vol,
            params.wave_factor(s.tangent_factor),
        )
    } else {
        let (p, psi) = base_law(params, f_eval);
        (p, psi, 1.0)
    };
    if params.volume_k > 0.0 {
        let j = f_eval.determinant();
        p += cofactor(f_eval) * (params.volume_k * (j - 1.0));
        psi += 0.5 * params.volume_k * (j - 1.0) * (j - 1.0);
    }
    StressSample {
        p,
        psi,
        det,
        clamped,
        stiffening,
    }
}

/// P and ψ of the model's own law, before the stiffening and the volume term.
#[inline]
fn base_law(params: &ElasticParams, f: &Mat3) -> (Mat3, f64) {
    match params.model {
        ElasticModel::StVK => stvk(&params.lame, f, 1.0),
        ElasticModel::MuellerCompat => mueller(&params.lame, f),
        ElasticModel::Corotated => corotated(&params.lame, f),
    }
}

/// A base law split by the strain's deviator and trace, which the stiffening needs: tissue
/// stiffens as its fibres straighten under distortion, while its bulk response (water) does
/// not. At ν = 0.499 λ is 166 E, and with the trace's term in Q = 2βψ/E a 2 % change of
/// volume at a lip multiplied the whole tangent, bulk included, by 2.6 (Q = 0.66), 3.5 % by
/// the cap's 37.
struct SplitLaw {
    p_dev: Mat3,
    psi_dev: f64,
    p_vol: Mat3,
    psi_vol: f64,
}

/// The model's law as [`SplitLaw`]: with T(e) = 2μ e + λ tr e I on its strain e (Green's,
/// Müller's FᵀF − I, or the corotated S − I), T_dev = 2μ dev e and T_vol = K tr e I
/// (K = λ + 2μ/3), P = G T with G = F, 2F or R, and ψ = μ dev e : dev e + ½ K (tr e)².
#[inline]
fn split_law(params: &ElasticParams, f: &Mat3) -> SplitLaw {
    let (g, e) = law_map_and_strain(params.model, f);
    let (t_dev, t_vol, psi_dev, psi_vol) = split_measure(&params.lame, &e);
    SplitLaw {
        p_dev: g * t_dev,
        psi_dev,
        p_vol: g * t_vol,
        psi_vol,
    }
}

/// The model's G and strain e at F (see [`split_law`]).
#[inline]
fn law_map_and_strain(model: ElasticModel, f: &Mat3) -> (Mat3, Mat3) {
    match model {
        ElasticModel::StVK => (*f, (f.transpose() * f - Mat3::identity()) * 0.5),
        ElasticModel::MuellerCompat => (f * 2.0, f.transpose() * f - Mat3::identity()),
        ElasticModel::Corotated => {
            let (r, s) = polar(f);
            (r, s - Mat3::identity())
        }
    }
}

/// T_dev, T_vol, ψ_dev and ψ_vol of a strain `e` (see [`split_law`]).
#[inline]
fn split_measure(lame: &Lame, e: &Mat3) -> (Mat3, Mat3, f64, f64) {
    let tr = e.trace();
    let dev = e - Mat3::identity() * (tr / 3.0);
    let bulk = lame.lambda + 2.0 * lame.mu / 3.0;
    (
        dev * (2.0 * lame.mu),
        Mat3::identity() * (bulk * tr),
        lame.mu * dev.component_mul(&dev).sum(),
        0.5 * bulk * tr * tr,
    )
}

/// StVK stress scaled by `scale` (1 for StVK).
#[inline]
fn stvk(lame: &Lame, f: &Mat3, scale: f64) -> (Mat3, f64) {
    let e = (f.transpose() * f - Mat3::identity()) * 0.5;
    let tr = e.trace();
    let s = Mat3::identity() * (lame.lambda * tr) + e * (2.0 * lame.mu);
    let psi = lame.mu * e.component_mul(&e).sum() + 0.5 * lame.lambda * tr * tr;
    (f * s * scale, psi * scale)
}

/// Müller 2004 literally: ε = FᵀF − I (no ½), σ = λ tr ε I + 2μ ε, P = 2Fσ, ψ = ½ ε:σ.
#[inline]
fn mueller(lame: &Lame, f: &Mat3) -> (Mat3, f64) {
    let eps = f.transpose() * f - Mat3::identity();
    let tr = eps.trace();
    let sigma = Mat3::identity() * (lame.lambda * tr) + eps * (2.0 * lame.mu);
    (f * sigma * 2.0, 0.5 * eps.component_mul(&sigma).sum())
}

#[inline]
fn corotated(lame: &Lame, f: &Mat3) -> (Mat3, f64) {
    let (r, s) = polar(f);
    let e = s - Mat3::identity();
    let tr = e.trace();
    let sigma = Mat3::identity() * (lame.lambda * tr) + e * (2.0 * lame.mu);
    let psi = lame.mu * e.component_mul(&e).sum() + 0.5 * lame.lambda * tr * tr;
    (r * sigma, psi)
}

/// Differential of P at F along dF (StVK exact; MuellerCompat ×4; corotated with the rotation
/// held fixed, which is the symmetric "warped stiffness"). The volume term is included.
#[inline]
pub fn stress_differential(params: &ElasticParams, f: &Mat3, df: &Mat3) -> Mat3 {
    let mut dp = if params.stiffening > 0.0 {
        stiffened_differential(params, f, df)
    } else {
        base_differential(params, f, df)
    };
    if params.volume_k > 0.0 {
        // d[(J − 1) cof F] = (cof F : dF) cof F + (J − 1) d(cof F).
        let j = f.determinant();
        let cof = cofactor(f);
        let dj = cof.component_mul(df).sum();
        dp += cof * (params.volume_k * dj)
            + cofactor_differential(f, df) * (params.volume_k * (j - 1.0));
    }
    dp
}

/// dP of the base law alone.
#[inline]
fn base_differential(params: &ElasticParams, f: &Mat3, df: &Mat3) -> Mat3 {
    match params.model {
        ElasticModel::StVK | ElasticModel::MuellerCompat => {
            let lame = params.effective_lame();
            let e = (f.transpose() * f - Mat3::identity()) * 0.5;
            let s = Mat3::identity() * (lame.lambda * e.trace()) + e * (2.0 * lame.mu);
            let de = (df.transpose() * f + f.transpose() * df) * 0.5;
            let ds = Mat3::identity() * (lame.lambda * de.trace()) + de * (2.0 * lame.mu);
            df * s + f * ds
        }
        ElasticModel::Corotated => {
            let (r, _) = polar(f);
            let rt_df = r.transpose() * df;
            let de = (rt_df + rt_df.transpose()) * 0.5;
            r * (Mat3::identity() * (params.lame.lambda * de.trace()) + de * (2.0 * params.lame.mu))
        }
    }
}

/// dP of the stiffened law P = g'(Q) P_dev + P_vol, Q = 2βψ_dev/E:
/// dP = g' dP_dev + g''(Q) (2β/E)(P_dev : dF) P_dev + dP_vol (the same approximations as
/// [`base_differential`]: exact for StVK and Müller, the rotation held for corotated).
fn stiffened_differential(params: &ElasticParams, f: &Mat3, df: &Mat3) -> Mat3 {
    let lame = params.lame;
    // P_x = G T_x(e): dP_x = dG T_x(e) + G T_x(de); G = R is held for corotated.
    let (g, e) = law_map_and_strain(params.model, f);
    let (dg, de) = match params.model {
        ElasticModel::StVK => (*df, (df.transpose() * f + f.transpose() * df) * 0.5),
        ElasticModel::MuellerCompat => (df * 2.0, df.transpose() * f + f.transpose() * df),
        ElasticModel::Corotated => {
            let rt_df = g.transpose() * df;
            (Mat3::zeros(), (rt_df + rt_df.transpose()) * 0.5)
        }
    };
    let (t_dev, t_vol, psi_dev, _) = split_measure(&lame, &e);
    let (dt_dev, dt_vol, _, _) = split_measure(&lame, &de);
    let p_dev = g * t_dev;
    let dp_dev = dg * t_dev + g * dt_dev;
    let dp_vol = dg * t_vol + g * dt_vol;
    let q = params.stiffening_exponent(psi_dev);
    let dq =
        2.0 * params.stiffening / params.effective_youngs_modulus() * p_dev.component_mul(df).sum();
    dp_dev * stiffening_slope(q) + p_dev * (stiffening_curvature(q) * dq) + dp_vol
}

/// cof(F) = det(F) F⁻ᵀ, written with rows: rows of cof are r1×r2, r2×r0, r0×r1.
#[inline]
pub fn cofactor(f: &Mat3) -> Mat3 {
    let r0 = f.row(0).transpose();
    let r1 = f.row(1).transpose();
    let r2 = f.row(2).transpose();
    Mat3::from_rows(&[
        r1.cross(&r2).transpose(),
        r2.cross(&r0).transpose(),
        r0.cross(&r1).transpose(),
    ])
}

#[inline]
fn cofactor_differential(f: &Mat3, df: &Mat3) -> Mat3 {
    let r = |m: &Mat3, k: usize| m.row(k).transpose();
    let row =
        |a: usize, b: usize| (r(df, a).cross(&r(f, b)) + r(f, a).cross(&r(df, b))).transpose();
    Mat3::from_rows(&[row(1, 2), row(2, 0), row(0, 1)])
}

/// Polar decomposition F = R S with det R = +1 (via SVD, reflection moved into S).
pub fn polar(f: &Mat3) -> (Mat3, Mat3) {
    let svd = nalgebra::SVD::new(*f, true, true);
    let (Some(mut u), Some(v_t)) = (svd.u, svd.v_t) else {
        return (Mat3::identity(), *f);
    };
    let mut sigma = svd.singular_values;
    if (u * v_t).determinant() < 0.0 {
        // Flip the axis of the smallest singular value so that R is a rotation.
        let k = sigma.imin();
        u.column_mut(k).neg_mut();
        sigma[k] = -sigma[k];
    }
    let r = u * v_t;
    let s = v_t.transpose() * Mat3::from_diagonal(&sigma) * v_t;
    (r, s)
}

/// F with its singular values clamped to [`DET_RANGE`]; an inversion (det < 0) is undone by
/// flipping the smallest singular direction first.
pub fn clamp_singular_values(f: &Mat3) -> Mat3 {
    if !f.iter().all(|x| x.is_finite()) {
        return Mat3::identity();
    }
    let svd = nalgebra::SVD::new(*f, true, true);
    let (Some(mut u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Mat3::identity();
    };
    let mut sigma = svd.singular_values;
    if (u * v_t).determinant() < 0.0 {
        let k = sigma.imin();
        u.column_mut(k).neg_mut();
    }
    let (lo, hi) = DET_RANGE;
    for s in sigma.iter_mut() {
        *s = s.clamp(lo, hi);
    }
    u * Mat3::from_diagonal(&sigma) * v_t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_f() -> Mat3 {
        Mat3::new(1.05, 0.02, -0.01, 0.03, 0.97, 0.04, -0.02, 0.01, 1.02)
    }

    fn energy(params: &ElasticParams, f: &Mat3) -> f64 {
        stress(params, f).psi
    }

    /// P = ∂ψ/∂F by central differences, for every model.
    #[test]
    fn stress_is_the_energy_gradient() {
        for model in [
            ElasticModel::StVK,
            ElasticModel::MuellerCompat,
            ElasticModel::Corotated,
        ] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.model = model;
            params.volume_k = 2000.0;
            assert_energy_gradient(&params, &sample_f(), 1e-4);
        }
    }

    /// P at `f` against central differences of ψ, within `tol` of |P| (at least 1 Pa).
    fn assert_energy_gradient(params: &ElasticParams, f: &Mat3, tol: f64) {
        let p = stress(params, f).p;
        let h = 1e-6;
        for a in 0..3 {
            for b in 0..3 {
                let mut fp = *f;
                let mut fm = *f;
                fp[(a, b)] += h;
                fm[(a, b)] -= h;
                let fd = (energy(params, &fp) - energy(params, &fm)) / (2.0 * h);
                assert!(
                    (fd - p[(a, b)]).abs() < tol * p.norm().max(1.0),
                    "{:?} ({a},{b})",
                    params.model
                );
            }
        }
    }

    /// The differential along a fixed dF at `f` against central differences of P.
    fn assert_exact_differential(params: &ElasticParams, f: &Mat3) {
        let df = Mat3::new(0.3, -0.1, 0.2, 0.05, 0.4, -0.3, 0.1, 0.2, -0.2);
        let h = 1e-6;
        let fd = (stress(params, &(f + df * h)).p - stress(params, &(f - df * h)).p) / (2.0 * h);
        let an = stress_differential(params, f, &df);
        assert!((fd - an).norm() < 1e-5 * an.norm(), "{:?}", params.model);
    }

    /// The differential matches finite differences of P (StVK and MuellerCompat exactly).
    #[test]
    fn differential_matches_finite_differences() {
        for model in [ElasticModel::StVK, ElasticModel::MuellerCompat] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.model = model;
            params.volume_k = 1000.0;
            assert_exact_differential(&params, &sample_f());
        }
    }

    /// Strain-stiffening keeps P = ∂ψ/∂F and its differential exact, below and past the
    /// cap on the exponent.
    #[test]
    fn stiffened_stress_is_the_energy_gradient() {
        let stretched = |x: f64| {
            Mat3::new(
                x,
                0.05,
                -0.02,
                0.03,
                1.0 / x.sqrt(),
                0.04,
                -0.02,
                0.01,
                1.0 / x.sqrt(),
            )
        };
        for model in [
            ElasticModel::StVK,
            ElasticModel::MuellerCompat,
            ElasticModel::Corotated,
        ] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.model = model;
            params.stiffening = 10.0;
            // Q ≈ 0.9 and ≈ 5 (past the cap).
            for f in [stretched(1.3), stretched(1.8)] {
                assert_energy_gradient(&params, &f, 1e-5);
            }
        }
        for model in [ElasticModel::StVK, ElasticModel::MuellerCompat] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.model = model;
            params.stiffening = 10.0;
            params.volume_k = 1000.0;
            assert_exact_differential(&params, &stretched(1.3));
        }
    }

    /// At small strain the stiffened law is the base law. Stretched, its distortional part
    /// is e^Q times the base law's (Q = 2βψ_dev/E) and no more than e^2 times past the cap,
    /// while its volumetric part is the base law's: a pure change of volume does not
    /// stiffen. The reported factor is the fastest wave's: the distortional tangent's
    /// e^Q (1 + 2Q) on 4μ/3, the bulk modulus as it is.
    #[test]
    fn stiffening_is_exponential_in_the_distortional_energy_and_capped() {
        let base = ElasticParams::stvk(5000.0, 0.45);
        let stiff = ElasticParams {
            stiffening: 10.0,
            ..base
        };
        let (lambda, mu) = (base.lame.lambda, base.lame.mu);
        let bulk = lambda + 2.0 * mu / 3.0;
        // P_dev and P_vol of StVK written out, and ψ_dev.
        let parts = |f: &Mat3| {
            let e = (f.transpose() * f - Mat3::identity()) * 0.5;
            let tr = e.trace();
            let dev = e - Mat3::identity() * (tr / 3.0);
            let p_dev = f * dev * (2.0 * mu);
            let p_vol = f * (bulk * tr);
            (p_dev, p_vol, mu * dev.norm_squared())
        };
        let small = Mat3::from_diagonal(&crate::math::Vec3::new(1.001, 1.0, 1.0));
        let (a, b) = (stress(&base, &small), stress(&stiff, &small));
        assert!((b.p - a.p).norm() < 1e-3 * a.p.norm());
        let f = Mat3::from_diagonal(&crate::math::Vec3::new(1.2, 1.0, 1.0));
        let (a, b) = (stress(&base, &f), stress(&stiff, &f));
        let (p_dev, p_vol, psi_dev) = parts(&f);
        assert!((a.p - p_dev - p_vol).norm() < 1e-12 * a.p.norm());
        let q = 2.0 * 10.0 * psi_dev / 5000.0;
        assert!((b.p - p_dev * q.exp() - p_vol).norm() < 1e-12 * b.p.norm());
        let tangent = q.exp() * (1.0 + 2.0 * q);
        let wave = (bulk + 4.0 * mu / 3.0 * tangent) / (lambda + 2.0 * mu);
        assert!((b.stiffening - wave).abs() < 1e-12 * wave);
        assert_eq!(a.stiffening, 1.0);
        let far = Mat3::from_diagonal(&crate::math::Vec3::new(2.0, 1.0, 1.0));
        let b = stress(&stiff, &far);
        let (p_dev, p_vol, _) = parts(&far);
        assert!((b.p - p_dev * 2f64.exp() - p_vol).norm() < 1e-12 * b.p.norm());
        let wave = (bulk + 4.0 * mu / 3.0 * 2f64.exp()) / (lambda + 2.0 * mu);
        assert!((b.stiffening - wave).abs() < 1e-12 * wave);
        // A pure dilation of 5 % in volume: no stiffening at all, even nearly incompressible.
        let tight = ElasticParams {
            stiffening: 10.0,
            ..ElasticParams::stvk(5000.0, 0.499)
        };
        let swell = Mat3::identity() * 1.05f64.cbrt();
        let (a, b) = (
            stress(&ElasticParams::stvk(5000.0, 0.499), &swell),
            stress(&tight, &swell),
        );
        assert!((b.p - a.p).norm() < 1e-12 * a.p.norm() && b.stiffening == 1.0);
    }

    #[test]
    fn mueller_is_stvk_with_four_times_the_stiffness() {
        let f = sample_f();
        let stvk = ElasticParams::stvk(20000.0, 0.3);
        let mut m = ElasticParams::stvk(5000.0, 0.3);
        m.model = ElasticModel::MuellerCompat;
        let (a, b) = (stress(&stvk, &f), stress(&m, &f));
        assert!((a.p - b.p).norm() < 1e-12 * a.p.norm());
        assert!((a.psi - b.psi).abs() < 1e-12 * a.psi);
    }

    #[test]
    fn rotations_carry_no_stress() {
        let r = *nalgebra::Rotation3::from_euler_angles(0.4, 1.3, -2.0).matrix();
        for model in [
            ElasticModel::StVK,
            ElasticModel::MuellerCompat,
            ElasticModel::Corotated,
        ] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.model = model;
            params.volume_k = 1000.0;
            let s = stress(&params, &r);
            assert!(s.p.norm() < 1e-10 && s.psi.abs() < 1e-12, "{model:?}");
        }
    }

    #[test]
    fn inverted_gradient_is_clamped_to_a_proper_one() {
        let f = Mat3::from_diagonal(&crate::math::Vec3::new(1.0, 1.0, -0.5));
        let c = clamp_singular_values(&f);
        assert!(c.determinant() > 0.0);
        let s = stress(&ElasticParams::stvk(5000.0, 0.45), &f);
        assert!(s.clamped && s.det < 0.0 && s.p.iter().all(|x| x.is_finite()));
    }

    #[test]
    fn polar_is_a_rotation_times_symmetric() {
        let f = sample_f();
        let (r, s) = polar(&f);
        assert!((r * s - f).norm() < 1e-12);
        assert!((r.transpose() * r - Mat3::identity()).norm() < 1e-12);
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!((s - s.transpose()).norm() < 1e-12);
    }
}
