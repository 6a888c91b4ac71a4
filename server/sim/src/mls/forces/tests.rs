//! The force kernels' tests: energy gradients, invariants, both kernels agreeing.

use super::*;
use crate::mls::material::ElasticModel;
use crate::model::{Kernel, Neighbourhoods, RestGrid};

/// A jittered 4³ lattice with unit-ish volumes.
pub(crate) fn cloud() -> (Vec<Vec3>, MlsOperator, Vec<f64>) {
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
    let op = MlsOperator::build(&rest, &nb, &kernel, None);
    let volumes = vec![s * s * s; rest.len()];
    (rest, op, volumes)
}

pub(crate) fn deformed(rest: &[Vec3]) -> Vec<Vec3> {
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
    add_elastic_forces(
        op,
        params,
        vol,
        None,
        p,
        None,
        &mut f,
        &mut ForceScratch::new(p.len()),
    )
    .energy()
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
        add_elastic_forces(
            &op,
            &params,
            &vol,
            None,
            &p,
            None,
            &mut f,
            &mut ForceScratch::new(p.len()),
        );
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
    stiffness_product(&op, &params, &vol, None, &p, &dir, &mut kv);
    let h = 1e-7;
    let force_at = |s: f64| {
        let q: Vec<Vec3> = p.iter().zip(&dir).map(|(x, d)| x + d * s).collect();
        let mut f = vec![Vec3::zeros(); p.len()];
        add_elastic_forces(
            &op,
            &params,
            &vol,
            None,
            &q,
            None,
            &mut f,
            &mut ForceScratch::new(q.len()),
        );
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
    add_elastic_forces(
        &op,
        &params,
        &vol,
        None,
        &p,
        None,
        &mut f,
        &mut ForceScratch::new(p.len()),
    );
    let scale: f64 = f.iter().map(|x| x.norm()).sum();
    let total: Vec3 = f.iter().sum();
    let torque: Vec3 = p.iter().zip(&f).map(|(x, g)| x.cross(g)).sum();
    let arm = p.iter().map(|x| x.norm()).fold(0.0, f64::max);
    assert!(total.norm() < 1e-13 * scale, "{total}");
    assert!(torque.norm() < 1e-13 * scale * arm, "{torque}");
}

/// The scratch's force buffers are clear after every evaluation (the merge clears what it
/// reads): a full evaluation after one over an evaluation set gives the bits of a full
/// evaluation with fresh buffers.
#[test]
fn scratch_buffers_are_clear_between_evaluations() {
    let (rest, op, vol) = cloud();
    let p = deformed(&rest);
    let params = ElasticParams::stvk(5000.0, 0.45);
    let evaluate = |set: Option<&EvalSet>, scratch: &mut ForceScratch| {
        let mut f = vec![Vec3::zeros(); p.len()];
        add_elastic_forces(&op, &params, &vol, None, &p, set, &mut f, scratch);
        f
    };
    let fresh = evaluate(None, &mut ForceScratch::new(p.len()));
    let some: Vec<u32> = (0..p.len() as u32).step_by(4).collect();
    let set = EvalSet::for_active(&op, &some);
    let mut scratch = ForceScratch::new(p.len());
    let partial = evaluate(Some(&set), &mut scratch);
    assert!(partial.iter().any(|f| f.norm() > 0.0));
    assert_eq!(evaluate(None, &mut scratch), fresh);
    assert_eq!(evaluate(None, &mut scratch), fresh);
}

/// The 4-lane run kernel agrees with the single-point kernel on a lattice body with many runs,
/// for StVK and for a clamped state.
#[test]
fn run_kernel_matches_scalar_kernel() {
    use crate::mls::operator::LatticeOffsets;
    let n = 9;
    let s = 0.002;
    let mut rest = Vec::new();
    let mut coords = Vec::new();
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                rest.push(Vec3::new(i as f64, j as f64, k as f64) * s);
                coords.push([i as u32, j as u32, k as u32]);
            }
        }
    }
    let kernel = Kernel { support_m: 2.0 * s };
    let grid = RestGrid::build(&rest, kernel.support_m);
    let nb = Neighbourhoods::build(&rest, &grid, kernel.support_m, 0);
    let lattice = LatticeOffsets { coords, spacing: s };
    let op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
    assert!(op.runs().len() >= 40, "{} runs", op.runs().len());
    let volumes: Vec<f64> = (0..rest.len())
        .map(|i| s * s * s * (1.0 + 0.01 * (i % 7) as f64))
        .collect();
    let params = ElasticParams::stvk(5000.0, 0.45);
    let everyone: Vec<u32> = (0..rest.len() as u32).collect();
    let scalar = EvalSet::scalar_only(&op, &everyone);
    for amplitude in [1e-4, 2e-3] {
        // The larger displacement pushes some det F below 0.2 (clamp fallback lanes).
        let p: Vec<Vec3> = rest
            .iter()
            .enumerate()
            .map(|(i, x)| {
                x + Vec3::new(
                    (i as f64).sin(),
                    (1.7 * i as f64).cos(),
                    (0.3 * i as f64).sin(),
                ) * amplitude
            })
            .collect();
        let mut scratch = ForceScratch::new(p.len());
        let mut fast = vec![Vec3::zeros(); p.len()];
        let mut slow = vec![Vec3::zeros(); p.len()];
        let a = add_elastic_forces(
            &op,
            &params,
            &volumes,
            None,
            &p,
            None,
            &mut fast,
            &mut scratch,
        );
        let b = add_elastic_forces(
            &op,
            &params,
            &volumes,
            None,
            &p,
            Some(&scalar),
            &mut slow,
            &mut scratch,
        );
        let scale = slow.iter().map(|x| x.norm()).fold(0.0, f64::max);
        for i in 0..p.len() {
            assert!(
                (fast[i] - slow[i]).norm() < 1e-12 * scale,
                "amplitude {amplitude}, point {i}"
            );
        }
        assert!((a.energy() - b.energy()).abs() < 1e-12 * b.energy());
        assert_eq!(a.clamped_points, b.clamped_points);
        assert!((a.min_det_f - b.min_det_f).abs() < 1e-12);
    }
}

/// The tangent is symmetric, at rest and deformed, with and without the hourglass term:
/// the implicit mode's conjugate gradients rely on it.
#[test]
fn the_tangent_is_symmetric() {
    let (rest, op, vol) = cloud();
    let deformed = deformed(&rest);
    let u: Vec<Vec3> = (0..rest.len())
        .map(|i| Vec3::new((i as f64 * 0.7).sin(), 0.2, (i as f64 * 1.3).cos()))
        .collect();
    let w: Vec<Vec3> = (0..rest.len())
        .map(|i| Vec3::new((i as f64 * 0.3).cos(), (i as f64).sin(), 0.1))
        .collect();
    for alpha in [0.0, 0.05] {
        for p in [&rest, &deformed] {
            let mut params = ElasticParams::stvk(5000.0, 0.45);
            params.hourglass_alpha = alpha;
            let mut ku = vec![Vec3::zeros(); rest.len()];
            let mut kw = vec![Vec3::zeros(); rest.len()];
            stiffness_product(&op, &params, &vol, None, p, &u, &mut ku);
            stiffness_product(&op, &params, &vol, None, p, &w, &mut kw);
            let a: f64 = w.iter().zip(&ku).map(|(x, y)| x.dot(y)).sum();
            let b: f64 = u.iter().zip(&kw).map(|(x, y)| x.dot(y)).sum();
            assert!(
                a.abs() > 0.0 && (a - b).abs() <= 1e-12 * a.abs(),
                "α {alpha}: {a} vs {b}"
            );
        }
    }
}

/// The vectorised StVK (four lanes, and one point's columns) gives the general code's
/// stress, energy and tangent factor with the strain-stiffening on, below and past its cap.
#[test]
fn the_vector_stiffened_stress_is_the_scalar_one() {
    let mut params = ElasticParams::stvk(5000.0, 0.45);
    params.stiffening = 10.0;
    let fs = [
        Mat3::identity(),
        Mat3::new(1.1, 0.02, 0.0, 0.0, 0.97, 0.03, 0.01, 0.0, 1.0),
        Mat3::new(1.3, 0.05, -0.02, 0.03, 0.9, 0.04, -0.02, 0.01, 0.9),
        Mat3::new(1.8, 0.0, 0.0, 0.0, 0.8, 0.0, 0.0, 0.0, 0.8),
    ];
    let lanes: [[f64x4; 3]; 3] =
        std::array::from_fn(|r| std::array::from_fn(|c| f64x4::from(fs.map(|f| f[(r, c)]))));
    let (p, psi, checks) = lane_stvk(&params, &lanes).expect("ordinary det F");
    let psi = psi.to_array();
    for (lane, f) in fs.iter().enumerate() {
        let s = stress(&params, f);
        let tol = 1e-12 * s.p.norm().max(1.0);
        for r in 0..3 {
            for c in 0..3 {
                assert!(
                    (p[r][c].to_array()[lane] - s.p[(r, c)]).abs() < tol,
                    "lane {lane}"
                );
            }
        }
        assert!((psi[lane] - s.psi).abs() < 1e-12 * s.psi.max(1.0));
        assert!((checks[lane].stiffening - s.stiffening).abs() < 1e-12 * s.stiffening);
        let cols = std::array::from_fn(|c| f64x4::from([f[(0, c)], f[(1, c)], f[(2, c)], 0.0]));
        let (pc, psi_point, check) = point_stvk(&params, &cols).expect("ordinary det F");
        for c in 0..3 {
            for r in 0..3 {
                assert!(
                    (pc[c].to_array()[r] - s.p[(r, c)]).abs() < tol,
                    "point {lane}"
                );
            }
        }
        assert!((psi_point - s.psi).abs() < 1e-12 * s.psi.max(1.0));
        assert!((check.stiffening - s.stiffening).abs() < 1e-12 * s.stiffening);
    }
}
