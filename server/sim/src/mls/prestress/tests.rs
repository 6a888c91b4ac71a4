//! The prestress pass: an exact energy gradient with a constant tangent, no net force, and
//! the layer where the surface is.

use super::*;
use crate::mls::ElasticParams;
use crate::mls::forces::tests::{cloud, deformed};
use crate::mls::forces::{EvalSet, ForceScratch, add_elastic_forces, stiffness_product};
use crate::mls::operator::complete;
use crate::mls::operator::{MlsOperator, PointRank};

/// The prestress pass on its own, point by point in plain matrices: what the kernels'
/// fused `F S₀` must equal.
impl Prestress {
    /// Adds the prestress forces at positions `p` to `f` (N) from the layer points whose
    /// stress the evaluation covers (all, or those of `set`), and returns their energy
    /// Σ V S₀ : E (J), negative where the layer has shortened.
    fn reference_forces(
        &self,
        op: &MlsOperator,
        volumes: &[f64],
        p: &[Vec3],
        set: Option<&EvalSet>,
        f: &mut [Vec3],
    ) -> f64 {
        let mut energy = 0.0;
        for &i in &self.points {
            let i = i as usize;
            let s0 = self.stress_of(i).expect("a layer point");
            if set.is_some_and(|s| !s.has_stress(i)) {
                continue;
            }
            let term = op.point(i);
            if let PointRank::Orphan = term.rank {
                continue;
            }
            let ids = op.neighbours(i);
            let pi = p[i];
            let mut b = Mat3::zeros();
            for (j, pair) in ids.iter().zip(op.pair_terms(i)) {
                b += (p[*j as usize] - pi) * pair.wx.transpose();
            }
            let full = complete(b * term.a_pinv, &term.rank);
            let green = (full.transpose() * full - Mat3::identity()) * 0.5;
            energy += volumes[i] * s0.component_mul(&green).sum();
            let m = full * s0 * (-volumes[i]) * term.a_pinv;
            let mut own = Vec3::zeros();
            for (j, pair) in ids.iter().zip(op.pair_terms(i)) {
                let g = m * pair.wx;
                f[*j as usize] += g;
                own += g;
            }
            f[i] -= own;
        }
        energy
    }
}

/// A tangent-plane prestress σ (I − z zᵀ) on every point of the test cloud.
fn everywhere(n: usize, sigma: f64) -> Prestress {
    Prestress {
        points: (0..n as u32).collect(),
        field: vec![[sigma, sigma, 0.0, 0.0, 0.0, 0.0]; n],
    }
}

fn forces(pre: &Prestress, op: &MlsOperator, vol: &[f64], p: &[Vec3]) -> (Vec<Vec3>, f64) {
    let mut f = vec![Vec3::zeros(); p.len()];
    let e = pre.reference_forces(op, vol, p, None, &mut f);
    (f, e)
}

/// The elastic kernels with and without the layer differ by the reference pass's forces
/// and energy: on a jittered cloud (the pair kernels) and on a lattice egg (the stencil),
/// over every point and over a restricted set.
#[test]
fn the_kernels_add_what_the_reference_pass_gives() {
    let (rest, op, vol) = cloud();
    compare_with_reference(&op, &vol, &deformed(&rest));
    let (rest, nb, kernel, lattice, vol) = crate::mls::forces::stencil_kernel::tests::ball();
    let op = MlsOperator::build(&rest, &nb, &kernel, Some(lattice));
    assert!(op.stencil().is_some());
    compare_with_reference(&op, &vol, &deformed(&rest));
}

fn compare_with_reference(op: &MlsOperator, vol: &[f64], p: &[Vec3]) {
    let n = p.len();
    let pre = everywhere(n, 450.0);
    let params = ElasticParams::stvk(5000.0, 0.45);
    let mut set = EvalSet::default();
    let active: Vec<u32> = (0..n as u32).filter(|i| i % 3 == 0).collect();
    set.rebuild(op, &active, true);
    for set in [None, Some(&set)] {
        let run = |with: Option<&Prestress>| {
            let mut f = vec![Vec3::zeros(); n];
            let mut scratch = ForceScratch::new(n);
            let stats = add_elastic_forces(op, &params, vol, with, p, set, &mut f, &mut scratch);
            (f, stats)
        };
        let ((plain, a), (with, b)) = (run(None), run(Some(&pre)));
        let mut reference = vec![Vec3::zeros(); n];
        let e = pre.reference_forces(op, vol, p, set, &mut reference);
        assert_eq!(a.prestress_energy, 0.0);
        assert!(
            e != 0.0 && (b.prestress_energy - e).abs() <= 1e-9 * e.abs(),
            "{e}"
        );
        let scale = reference.iter().map(|x| x.norm()).fold(0.0, f64::max);
        assert!(scale > 0.0);
        let whole: Vec<usize> = match set {
            Some(s) => s.active.iter().map(|&i| i as usize).collect(),
            None => (0..n).collect(),
        };
        for i in whole {
            let got = with[i] - plain[i];
            assert!((got - reference[i]).norm() < 1e-9 * scale, "point {i}");
        }
    }
}

/// f = −∂E/∂p by central differences, and Σf = 0.
#[test]
fn forces_are_the_energy_gradient() {
    let (rest, op, vol) = cloud();
    let pre = everywhere(rest.len(), 450.0);
    let p = deformed(&rest);
    let (f, _) = forces(&pre, &op, &vol, &p);
    let scale = f.iter().map(|x| x.norm()).fold(0.0, f64::max);
    assert!(scale > 0.0);
    let h = 1e-8;
    for i in [0, 5, 21, 42, 63] {
        for a in 0..3 {
            let at = |s: f64| {
                let mut q = p.clone();
                q[i][a] += s;
                forces(&pre, &op, &vol, &q).1
            };
            let fd = -(at(h) - at(-h)) / (2.0 * h);
            assert!((fd - f[i][a]).abs() < 1e-5 * scale, "point {i} axis {a}");
        }
    }
    let net: Vec3 = f.iter().sum();
    assert!(net.norm() < 1e-12 * scale);
}

/// `stiffness_product`'s prestress part (with the layer less without) matches the change
/// of the layer's forces along v (its tangent is constant, so exactly).
#[test]
fn stiffness_product_is_the_forces_differential() {
    let (rest, op, vol) = cloud();
    let pre = everywhere(rest.len(), 450.0);
    let p = deformed(&rest);
    let params = ElasticParams::stvk(5000.0, 0.45);
    let dir: Vec<Vec3> = (0..p.len())
        .map(|i| Vec3::new((i as f64).cos(), (i as f64 * 2.1).sin(), 0.3))
        .collect();
    let product = |with: Option<&Prestress>| {
        let mut kv = vec![Vec3::zeros(); p.len()];
        stiffness_product(&op, &params, &vol, with, &p, &dir, &mut kv);
        kv
    };
    let (with, without) = (product(Some(&pre)), product(None));
    let kv: Vec<Vec3> = with.iter().zip(&without).map(|(a, b)| a - b).collect();
    let h = 1e-6;
    let moved = |s: f64| -> Vec<Vec3> { p.iter().zip(&dir).map(|(x, d)| x + d * s).collect() };
    let (fp, fm) = (
        forces(&pre, &op, &vol, &moved(h)).0,
        forces(&pre, &op, &vol, &moved(-h)).0,
    );
    let scale = kv.iter().map(|x| x.norm()).fold(0.0, f64::max);
    assert!(scale > 0.0);
    for i in 0..p.len() {
        let fd = -(fp[i] - fm[i]) / (2.0 * h);
        assert!((fd - kv[i]).norm() < 1e-6 * scale, "point {i}");
    }
}

/// At rest the layer's tension has no component off its plane, and it pulls the cloud's
/// free faces inwards along it: the x = 0 face towards +x, the x = 3s face towards −x.
#[test]
fn uniform_tension_pulls_the_free_faces_in() {
    let s = 0.002;
    let rest: Vec<Vec3> = (0..64)
        .map(|i| Vec3::new((i % 4) as f64, ((i / 4) % 4) as f64, (i / 16) as f64) * s)
        .collect();
    let kernel = crate::model::Kernel { support_m: 2.0 * s };
    let grid = crate::model::RestGrid::build(&rest, kernel.support_m);
    let nb = crate::model::Neighbourhoods::build(&rest, &grid, kernel.support_m, 0);
    let op = MlsOperator::build(&rest, &nb, &kernel, None);
    let vol = vec![s * s * s; rest.len()];
    let pre = everywhere(rest.len(), 450.0);
    let (f, e) = forces(&pre, &op, &vol, &rest);
    assert!(e.abs() < 1e-15, "{e}");
    let scale = f.iter().map(|x| x.norm()).fold(0.0, f64::max);
    assert!(scale > 0.0);
    assert!(f.iter().all(|x| x.z.abs() < 1e-12 * scale));
    let face = |x: usize| -> f64 { (0..64).filter(|i| i % 4 == x).map(|i| f[i].x).sum() };
    assert!(face(0) > 0.1 * scale && face(3) < -0.1 * scale);
}

/// The layer holds the points within its depth of a cube's faces, each with the tension in
/// its nearest face's plane; deeper points carry none.
#[test]
fn the_layer_follows_the_surface() {
    let cube = crate::geometry::organs::box_mesh(Vec3::repeat(0.02), [4, 4, 4]);
    let s = 0.004;
    let rest: Vec<Vec3> = (0..125)
        .map(|i| Vec3::new((i % 5) as f64, ((i / 5) % 5) as f64, (i / 25) as f64) * s)
        .map(|x| x - Vec3::repeat(0.008))
        .collect();
    let layer = Prestress::surface_layer(&rest, &cube, 0.0035, 100.0);
    // A 5³ lattice 4 mm apart in a 20 mm cube: the outer shell (2 mm deep) is the layer,
    // the 3³ core (6 mm deep) is not.
    assert_eq!(layer.points().len(), 125 - 27);
    for &i in layer.points() {
        let s0 = layer.stress_of(i as usize).expect("a layer point");
        let x = rest[i as usize];
        // On a face (not an edge or a corner) the tension is in the face's plane.
        let on: Vec<usize> = (0..3).filter(|&a| x[a].abs() > 0.007).collect();
        assert!(s0.trace() > 0.0, "point {i}");
        let [axis] = on[..] else { continue };
        assert!(s0[(axis, axis)].abs() < 1e-9, "point {i}");
        assert!((s0.trace() - 200.0).abs() < 1e-9, "point {i}");
    }
    assert!(layer.stress_of(62).is_none(), "the centre");
    assert!(Prestress::surface_layer(&rest, &cube, 0.0035, 0.0).is_empty());
}
