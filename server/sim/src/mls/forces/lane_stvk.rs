//! StVK stress per lane (four points at a time), shared by the pair and the stencil kernels.

use super::*;

/// StVK (strain-stiffened where the material is) for one point whose F is given as column
/// vectors (x, y, z, 0): P as column vectors, ψ and its check; `None` when the model is not
/// StVK or det F needs the clamp.
#[inline]
pub(crate) fn point_stvk(
    params: &ElasticParams,
    fc: &[f64x4; 3],
) -> Option<([f64x4; 3], f64, PointCheck)> {
    if params.model != ElasticModel::StVK || params.volume_k != 0.0 {
        return None;
    }
    // f[c][r] = F[r][c].
    let f = fc.map(|c| c.to_array());
    let det = f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1])
        - f[1][0] * (f[0][1] * f[2][2] - f[0][2] * f[2][1])
        + f[2][0] * (f[0][1] * f[1][2] - f[0][2] * f[1][1]);
    let (lo, hi) = DET_RANGE;
    if !(det >= lo && det <= hi) {
        return None;
    }
    // E = ½ (FᵀF − I): entries are dot products of columns.
    let dot = |a: usize, b: usize| f[a][0] * f[b][0] + f[a][1] * f[b][1] + f[a][2] * f[b][2];
    let mut e = [[0.0f64; 3]; 3];
    for r in 0..3 {
        for c in r..3 {
            let v = 0.5 * (dot(r, c) - if r == c { 1.0 } else { 0.0 });
            e[r][c] = v;
            e[c][r] = v;
        }
    }
    let tr = e[0][0] + e[1][1] + e[2][2];
    let (lambda, mu) = (params.lame.lambda, params.lame.mu);
    let ee: f64 = e.iter().flatten().map(|x| x * x).sum();
    // S = slope · 2μ dev E + K tr E I (`material::split_law`); without stiffening the
    // plain form, bit for bit the scalar law's.
    let (psi, factor, two_mu, diagonal) = match params.stiffening > 0.0 {
        true => {
            let bulk = lambda + 2.0 * mu / 3.0;
            let s = params.stiffened(mu * (ee - tr * tr / 3.0));
            let two_mu = 2.0 * mu * s.slope;
            let psi = s.psi + 0.5 * bulk * tr * tr;
            let factor = params.wave_factor(s.tangent_factor);
            (psi, factor, two_mu, bulk * tr - two_mu * tr / 3.0)
        }
        false => (mu * ee + 0.5 * lambda * tr * tr, 1.0, 2.0 * mu, lambda * tr),
    };
    let sm = |r: usize, c: usize| two_mu * e[r][c] + if r == c { diagonal } else { 0.0 };
    // P = F S, column by column: P[:, c] = Σ_k F[:, k] S[k][c].
    let pc = std::array::from_fn(|c| {
        fc[0].mul_add(
            f64x4::splat(sm(0, c)),
            fc[1].mul_add(f64x4::splat(sm(1, c)), fc[2] * f64x4::splat(sm(2, c))),
        )
    });
    Some((pc, psi, PointCheck::plain(det, factor)))
}

/// StVK stress (strain-stiffened where the material is), energy density and checks for
/// four lanes, or `None` when the model is not StVK or some lane needs the clamp fallback.
#[inline]
pub(crate) fn lane_stvk(
    params: &ElasticParams,
    f: &[[f64x4; 3]; 3],
) -> Option<([[f64x4; 3]; 3], f64x4, [PointCheck; LANES])> {
    if params.model != ElasticModel::StVK || params.volume_k != 0.0 {
        return None;
    }
    let det = f[0][0] * (f[1][1] * f[2][2] - f[1][2] * f[2][1])
        - f[0][1] * (f[1][0] * f[2][2] - f[1][2] * f[2][0])
        + f[0][2] * (f[1][0] * f[2][1] - f[1][1] * f[2][0]);
    let (lo, hi) = DET_RANGE;
    if det.to_array().iter().any(|d| !(*d >= lo && *d <= hi)) {
        return None;
    }
    // E = ½ (FᵀF − I), symmetric.
    let half = f64x4::splat(0.5);
    let mut e = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in r..3 {
            let cc = f[0][r].mul_add(f[0][c], f[1][r].mul_add(f[1][c], f[2][r] * f[2][c]));
            let v = if r == c {
                (cc - f64x4::ONE) * half
            } else {
                cc * half
            };
            e[r][c] = v;
            e[c][r] = v;
        }
    }
    let tr = e[0][0] + e[1][1] + e[2][2];
    let lambda = f64x4::splat(params.lame.lambda);
    let mu = f64x4::splat(params.lame.mu);
    let mut ee = f64x4::ZERO;
    for row in &e {
        for x in row {
            ee = x.mul_add(*x, ee);
        }
    }
    let mut two_mu = f64x4::splat(2.0 * params.lame.mu);
    let mut diagonal = lambda * tr;
    let mut psi = mu * ee + half * lambda * tr * tr;
    let mut factor = [1.0; LANES];
    if params.stiffening > 0.0 {
        // S = slope · 2μ dev E + K tr E I (`material::split_law`). Per lane: one exponential
        // each, against some 150 multiply-adds of the stress.
        let bulk = lambda + mu * f64x4::splat(2.0 / 3.0);
        let third = f64x4::splat(1.0 / 3.0);
        let psi_dev = mu * (ee - tr * tr * third);
        let s = psi_dev.to_array().map(|p| params.stiffened(p));
        let slope = f64x4::from(s.map(|x| x.slope));
        psi = f64x4::from(s.map(|x| x.psi)) + half * bulk * tr * tr;
        factor = s.map(|x| params.wave_factor(x.tangent_factor));
        two_mu *= slope;
        diagonal = bulk * tr - two_mu * tr * third;
    }
    let mut sm = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            sm[r][c] = two_mu * e[r][c] + if r == c { diagonal } else { f64x4::ZERO };
        }
    }
    let mut p = [[f64x4::ZERO; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            p[r][c] = f[r][0].mul_add(sm[0][c], f[r][1].mul_add(sm[1][c], f[r][2] * sm[2][c]));
        }
    }
    let det = det.to_array();
    Some((
        p,
        psi,
        std::array::from_fn(|l| PointCheck::plain(det[l], factor[l])),
    ))
}

/// Per-lane stress through the general (scalar) constitutive code.
pub(crate) fn lane_stress_scalar(
    params: &ElasticParams,
    f: &[[f64x4; 3]; 3],
) -> ([[f64x4; 3]; 3], f64x4, [PointCheck; LANES]) {
    let fa: [[[f64; 4]; 3]; 3] =
        std::array::from_fn(|r| std::array::from_fn(|c| f[r][c].to_array()));
    let samples: [_; LANES] =
        std::array::from_fn(|lane| stress(params, &Mat3::from_fn(|r, c| fa[r][c][lane])));
    (
        std::array::from_fn(|r| std::array::from_fn(|c| f64x4::from(samples.map(|s| s.p[(r, c)])))),
        f64x4::from(samples.map(|s| s.psi)),
        samples.map(|s| PointCheck::of(&s)),
    )
}
