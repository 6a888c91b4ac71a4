//! Tests of `stencil_kernel`.

use crate::math::Vec3;
use crate::mls::forces::{EvalSet, ForceScratch, ForceStats, add_elastic_forces};
use crate::mls::material::{ElasticModel, ElasticParams};
use crate::mls::operator::{LatticeOffsets, MlsOperator};
use crate::model::{Kernel, Neighbourhoods, RestGrid};

const S: f64 = 0.002;

/// An egg of lattice points, off the origin (every kind of missing neighbour on its
/// rough boundary), longest along z (so the box's rows run along z, not x), and volumes
/// that differ from point to point.
pub(crate) fn ball() -> (Vec<Vec3>, Neighbourhoods, Kernel, LatticeOffsets, Vec<f64>) {
    let (mut rest, mut coords, mut volumes) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..15u32 {
        for j in 0..11u32 {
            for i in 0..11u32 {
                let d = Vec3::new(i as f64 - 5.0, j as f64 - 4.6, 0.7 * (k as f64 - 7.3));
                if d.norm() <= 4.8 {
                    rest.push(
                        Vec3::new(0.031, -0.017, 0.052)
                            + Vec3::new(i as f64, j as f64, k as f64) * S,
                    );
                    coords.push([i, j, k]);
                    volumes.push(S * S * S * (0.3 + 0.7 * ((i * 7 + j * 3 + k) % 5) as f64 / 4.0));
                }
            }
        }
    }
    let kernel = Kernel { support_m: 2.0 * S };
    let grid = RestGrid::build(&rest, kernel.support_m);
    let nb = Neighbourhoods::build(&rest, &grid, kernel.support_m, 4);
    let lattice = LatticeOffsets { coords, spacing: S };
    (rest, nb, kernel, lattice, volumes)
}

/// A rigid turn and shift of the rest shape, with a deformation of `amplitude` (m) on top.
fn deformed(rest: &[Vec3], amplitude: f64) -> Vec<Vec3> {
    let turn = *nalgebra::Rotation3::new(Vec3::new(0.3, -0.4, 0.5)).matrix();
    rest.iter()
        .enumerate()
        .map(|(i, x)| {
            let t = i as f64;
            turn * x
                + Vec3::new(0.004, -0.002, 0.001)
                + Vec3::new((t * 0.7).sin(), (t * 1.3).cos(), (t * 0.37).sin()) * amplitude
        })
        .collect()
}

/// Forces and statistics of one evaluation, with the stencil or without.
fn evaluate(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    p: &[Vec3],
    stencil: bool,
) -> (Vec<Vec3>, ForceStats) {
    let mut scratch = ForceScratch::new(p.len());
    if !stencil {
        scratch = scratch.without_stencil();
    }
    evaluate_in(op, params, volumes, p, None, &mut scratch)
}

/// Forces and statistics of one evaluation over `set` in `scratch`.
fn evaluate_in(
    op: &MlsOperator,
    params: &ElasticParams,
    volumes: &[f64],
    p: &[Vec3],
    set: Option<&EvalSet>,
    scratch: &mut ForceScratch,
) -> (Vec<Vec3>, ForceStats) {
    let mut f = vec![Vec3::zeros(); p.len()];
    let stats = add_elastic_forces(op, params, volumes, None, p, set, &mut f, scratch);
    (f, stats)
}

fn assert_same(op: &MlsOperator, params: &ElasticParams, volumes: &[f64], p: &[Vec3], what: &str) {
    let (fs, a) = evaluate(op, params, volumes, p, true);
    let (fp, b) = evaluate(op, params, volumes, p, false);
    let scale = fp.iter().map(|x| x.norm()).fold(0.0, f64::max);
    assert!(scale > 0.0, "{what}: no force");
    for i in 0..p.len() {
        assert!(
            (fs[i] - fp[i]).norm() <= 1e-10 * scale,
            "{what}, point {i}: {} against {}",
            fs[i],
            fp[i]
        );
    }
    assert!(
        (a.strain_energy - b.strain_energy).abs() <= 1e-10 * b.strain_energy,
        "{what}: strain energy {} against {}",
        a.strain_energy,
        b.strain_energy
    );
    assert!(
        (a.hourglass_energy - b.hourglass_energy).abs() <= 1e-6 * b.energy(),
        "{what}: hourglass energy {} against {}",
        a.hourglass_energy,
        b.hourglass_energy
    );
    assert!((a.min_det_f - b.min_det_f).abs() <= 1e-12, "{what}");
    assert!((a.max_det_f - b.max_det_f).abs() <= 1e-12, "{what}");
    assert_eq!(a.clamped_points, b.clamped_points, "{what}");
    assert!(a.finite && b.finite, "{what}");
}

/// Every constitutive model, with and without the volume term, near rest and far enough
/// out that some points take the inversion clamp: the stencil gives the pair kernels'
/// forces to rounding, on a body turned and shifted away from its rest place.
#[test]
fn the_stencil_gives_the_forces_of_the_pair_kernels() {
    let (rest, nb, kernel, lattice, volumes) = ball();
    let op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
    let stencil = op.stencil().expect("a lattice with h = 2s");
    assert_eq!(stencil.evaluated_count(), op.rank_counts().full);
    assert_eq!(
        stencil.axes()[0],
        2,
        "the rows run along the egg's long axis"
    );
    for model in [
        ElasticModel::StVK,
        ElasticModel::MuellerCompat,
        ElasticModel::Corotated,
    ] {
        for volume_k in [0.0, 3000.0] {
            for amplitude in [1e-5, 2e-4, 1.5e-3] {
                let mut params = ElasticParams::stvk(5000.0, 0.45);
                params.model = model;
                params.volume_k = volume_k;
                let p = deformed(&rest, amplitude);
                let what = format!("{model:?}, k_v {volume_k}, amplitude {amplitude}");
                assert_same(&op, &params, &volumes, &p, &what);
            }
        }
    }
    let clamped = evaluate(
        &op,
        &ElasticParams::stvk(5000.0, 0.45),
        &volumes,
        &deformed(&rest, 1.5e-3),
        true,
    )
    .1;
    assert!(
        clamped.clamped_points > 0,
        "the largest deformation should reach the clamp"
    );
}

/// Evaluations over sets of active points, between whole-body ones in the same scratch
/// (what one leaves in the box fields must not reach the next): the stencil gives the
/// pair kernels' forces on every active point, and their statistics.
#[test]
fn evaluation_sets_take_the_stencil_over_their_chunks() {
    let (rest, nb, kernel, lattice, volumes) = ball();
    let op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
    let params = ElasticParams::stvk(5000.0, 0.45);
    let n = rest.len();
    let near = |centre: usize, radius: f64| -> Vec<u32> {
        (0..n as u32)
            .filter(|&i| (rest[i as usize] - rest[centre]).norm() < radius)
            .collect()
    };
    let sets = [
        Some(EvalSet::for_active(&op, &near(n / 2, 3.0 * S))),
        None,
        Some(EvalSet::for_active(&op, &near(n / 5, 2.0 * S))),
        Some(EvalSet::for_active(&op, &near(n / 2, 4.5 * S))),
        None,
        Some(EvalSet::for_active(&op, &near(4 * n / 5, 2.5 * S))),
    ];
    let mut scratch = ForceScratch::new(n);
    for (step, set) in sets.iter().enumerate() {
        let p = deformed(&rest, 2e-4 * (1.0 + step as f64));
        let (fs, a) = evaluate_in(&op, &params, &volumes, &p, set.as_ref(), &mut scratch);
        let mut pairs = ForceScratch::new(n).without_stencil();
        let (fp, b) = evaluate_in(&op, &params, &volumes, &p, set.as_ref(), &mut pairs);
        let scale = fp.iter().map(|x| x.norm()).fold(0.0, f64::max);
        // A set's forces are whole on its active points (the others are not read).
        let whole = |i: usize| {
            set.as_ref()
                .is_none_or(|s| s.active.binary_search(&(i as u32)).is_ok())
        };
        for i in (0..n).filter(|&i| whole(i)) {
            assert!(
                (fs[i] - fp[i]).norm() <= 1e-10 * scale,
                "evaluation {step}, point {i}: {} against {}",
                fs[i],
                fp[i]
            );
        }
        assert!((a.strain_energy - b.strain_energy).abs() <= 1e-10 * b.strain_energy);
        assert!((a.hourglass_energy - b.hourglass_energy).abs() <= 1e-6 * b.energy());
        assert!((a.min_det_f - b.min_det_f).abs() <= 1e-12);
        if let Some(set) = set {
            let outside = (0..n).filter(|&i| set.touched.binary_search(&(i as u32)).is_err());
            assert!(
                outside.clone().count() > 0,
                "evaluation {step} covers the ball"
            );
            assert!(outside.clone().all(|i| fs[i] == Vec3::zeros()));
        }
    }
}

/// A cut through the ball: the points whose rows it changes leave the stencil for the pair
/// kernels, and the forces are still those of the pair kernels alone.
#[test]
fn points_a_cut_changes_go_to_the_pair_kernels() {
    let (rest, mut nb, kernel, lattice, volumes) = ball();
    let coords = lattice.coords.clone();
    let mut op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
    let before = op.stencil().expect("a stencil").evaluated_count();
    // Cut every pair across the plane x = 5.5 s in the upper half.
    let mut changed = Vec::new();
    for i in 0..rest.len() {
        for &j in op.neighbours(i).to_vec().iter() {
            let (a, b) = (coords[i], coords[j as usize]);
            if a[0] <= 5 && b[0] >= 6 && a[2] >= 5 && b[2] >= 5 {
                nb.remove(i, j);
                nb.remove(j as usize, i as u32);
                changed.extend([i as u32, j]);
            }
        }
    }
    changed.sort_unstable();
    changed.dedup();
    assert!(changed.len() > 20, "{} points cut", changed.len());
    op.update_points(&changed, &rest, &nb, &kernel);
    let after = op.stencil().expect("a stencil").evaluated_count();
    assert_eq!(before - after, changed.len());
    let params = ElasticParams::stvk(5000.0, 0.45);
    for amplitude in [1e-5, 2e-4] {
        assert_same(
            &op,
            &params,
            &volumes,
            &deformed(&rest, amplitude),
            "after the cut",
        );
    }
}
