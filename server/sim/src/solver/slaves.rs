//! Slaved nodes: zero-volume nodes whose position is an interpolation of body points (a
//! linear multi-point constraint), for the virtual points on the wound walls.
//!
//! A virtual point joins the MLS fits of the interior points around it (physics.md §5.3)
//! and must move with the tissue it sits in. Moving it once a tick to where the drawn wall
//! went (which follows those same points) closes a loop with a tick's lag: the node drives
//! its neighbours, they carry the wall, the wall moves the node. Over a few wounds that
//! loop pumped energy into the walls until the guard rolled every tick back, each retry
//! doubling the sub-steps (half a second per tick on the liver). A slaved node has no
//! loop: in every sub-step its displacement is its masters' interpolated,
//! `x_s = X_s + Σ_k φ_k (x_k − X_k)`, with the linear-precision MLS shape functions φ at its
//! rest position (exact for any affine motion, rotations included; the kernel-weighted mean
//! where those extrapolate, see [`shape_functions`]), and the force the fits put on it is
//! handed back to the masters as `f_k += φ_k f_s` — the transpose of the interpolation.
//! The elastic energy is then a function of the masters alone and those are its exact
//! gradient: the constraint does no work, and the step's stability is the body's.

use crate::math::Vec3;
use crate::model::Kernel;

/// A slaved node's masters: (body point, weight), weights summing to one.
pub type Masters = Vec<(u32, f64)>;

/// The slaved nodes of a solver.
#[derive(Debug, Clone, Default)]
pub struct Slaves {
    /// Node index of the first node that may be slaved.
    first: usize,
    /// Per node from `first` on: its masters (empty when not slaved).
    masters: Vec<Masters>,
    /// Per node from `first` on: `X_s − Σ φ_k X_k`, so that what is interpolated is the
    /// displacement (zero for linear weights; the mean's offset from the node otherwise).
    offsets: Vec<Vec3>,
    /// The slaved nodes, in the order they were slaved.
    list: Vec<u32>,
    /// Where node weights are computed.
    shape: ShapeScratch,
}

impl Slaves {
    /// Room for `count` nodes from index `first` on, with up to `masters` masters each
    /// (more only grow the buffers): slaving a node then does not allocate.
    pub fn new(first: usize, count: usize, masters: usize) -> Self {
        Self {
            first,
            // (Each its own buffer: a cloned empty vector would have no room.)
            masters: (0..count).map(|_| Vec::with_capacity(masters)).collect(),
            offsets: vec![Vec3::zeros(); count],
            list: Vec::with_capacity(count),
            shape: ShapeScratch::with_room(masters),
        }
    }

    /// Slaves node `i` at rest position `x` (`rest[i]` is set to it) to the `candidates`
    /// with weight there ([`shape_functions`]); `false`, leaving it as it was, when none has.
    pub fn fit(
        &mut self,
        i: usize,
        x: Vec3,
        candidates: &[u32],
        rest: &mut [Vec3],
        kernel: &Kernel,
    ) -> bool {
        let mut shape = std::mem::take(&mut self.shape);
        let fitted = match shape_functions(rest, x, candidates, kernel, &mut shape) {
            Some(weights) => {
                rest[i] = x;
                self.slave(i, weights, rest);
                true
            }
            None => false,
        };
        self.shape = shape;
        fitted
    }

    /// The slaved nodes.
    pub fn list(&self) -> &[u32] {
        &self.list
    }

    /// Whether node `i` is slaved now.
    pub fn is_slaved(&self, i: usize) -> bool {
        !self.masters_of(i).is_empty()
    }

    /// The masters of node `i` (empty when it is not slaved).
    pub fn masters_of(&self, i: usize) -> &[(u32, f64)] {
        match i.checked_sub(self.first) {
            Some(k) if k < self.masters.len() => &self.masters[k],
            _ => &[],
        }
    }

    /// Slaves node `i`, at rest at `rest[i]`, to `masters` (weights summing to one; not
    /// empty): its displacement is theirs interpolated.
    pub fn slave(&mut self, i: usize, masters: &[(u32, f64)], rest: &[Vec3]) {
        assert!(
            i >= self.first && i - self.first < self.masters.len(),
            "node {i} cannot be slaved"
        );
        assert!(!masters.is_empty(), "node {i} slaved to nothing");
        let slot = &mut self.masters[i - self.first];
        if slot.is_empty() {
            self.list.push(i as u32);
        }
        slot.clear();
        slot.extend_from_slice(masters);
        self.offsets[i - self.first] = rest[i] - weighted_sum(masters, rest);
    }

    /// Frees node `i` (nothing if it is not slaved).
    pub fn free(&mut self, i: usize) {
        if self.is_slaved(i) {
            self.masters[i - self.first].clear();
            self.list.retain(|&s| s as usize != i);
        }
    }

    /// Puts every slaved node where its masters say: `x_s = X_s + Σ φ_k (x_k − X_k)`.
    pub fn interpolate(&self, x: &mut [Vec3]) {
        for &s in &self.list {
            let k = s as usize - self.first;
            x[s as usize] = self.offsets[k] + weighted_sum(&self.masters[k], x);
        }
    }

    /// The same for a displacement-like vector (no rest offset): `v_s = Σ φ_k v_k`.
    pub fn interpolate_vectors(&self, v: &mut [Vec3]) {
        for &s in &self.list {
            v[s as usize] = weighted_sum(&self.masters[s as usize - self.first], v);
        }
    }

    /// Hands each slaved node's force to its masters (`f_k += φ_k f_s`) and clears it.
    pub fn hand_back(&self, f: &mut [Vec3]) {
        for &s in &self.list {
            let fs = std::mem::replace(&mut f[s as usize], Vec3::zeros());
            for &(k, w) in &self.masters[s as usize - self.first] {
                f[k as usize] += fs * w;
            }
        }
    }
}

fn weighted_sum(masters: &[(u32, f64)], x: &[Vec3]) -> Vec3 {
    masters
        .iter()
        .fold(Vec3::zeros(), |acc, &(k, w)| acc + x[k as usize] * w)
}

/// Most `Σ |φ_k|` a node's linear weights may have (1 for a convex combination).
pub const MAX_ABS_WEIGHT_SUM: f64 = 1.5;

/// Linear-precision MLS shape functions at `x` over the points `candidates` (rest
/// positions `rest`) with `kernel`: `Σ φ_k = 1` and `Σ φ_k X_k = x`, so an affine field is
/// reproduced exactly. Where the candidates do not span 3D (a plane, a line), the fit is
/// too poorly conditioned to trust, or it extrapolates strongly (`Σ |φ_k|` over
/// [`MAX_ABS_WEIGHT_SUM`]: a node beyond a lopsided set of masters, which would move
/// further than any of them and stiffen the fits it is in past the step the solver
/// planned), the kernel-weighted mean (Shepard), a convex combination, instead. Candidates
/// with zero weight are left out; `None` if none has weight.
pub fn shape_functions<'s>(
    rest: &[Vec3],
    x: Vec3,
    candidates: &[u32],
    kernel: &Kernel,
    scratch: &'s mut ShapeScratch,
) -> Option<&'s [(u32, f64)]> {
    let h = kernel.support_m;
    let ShapeScratch { weighted, phi } = scratch;
    weighted.clear();
    weighted.extend(
        candidates
            .iter()
            .map(|&k| {
                let d = rest[k as usize] - x;
                (k, kernel.weight_sq(d.norm_squared()), d / h)
            })
            .filter(|&(_, w, _)| w > 0.0),
    );
    let total: f64 = weighted.iter().map(|&(_, w, _)| w).sum();
    if weighted.is_empty() || total <= 0.0 {
        return None;
    }
    // Moment matrix of the basis (1, d/h).
    let basis = |d: &Vec3| nalgebra::Vector4::new(1.0, d.x, d.y, d.z);
    let moment = weighted
        .iter()
        .fold(nalgebra::Matrix4::zeros(), |m, (_, w, d)| {
            m + basis(d) * basis(d).transpose() * *w
        });
    let linear = moment.symmetric_eigenvalues();
    let (lo, hi) = linear.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &e| {
        (lo.min(e), hi.max(e))
    });
    // Beyond this condition number the fit extrapolates wildly from a near-plane of points.
    const MAX_CONDITION: f64 = 1e6;
    let fit = (lo > 0.0 && hi / lo < MAX_CONDITION)
        .then(|| moment.try_inverse())
        .flatten();
    phi.clear();
    if let Some(inverse) = fit {
        let c = inverse.column(0).into_owned();
        phi.extend(weighted.iter().map(|(k, w, d)| (*k, w * basis(d).dot(&c))));
    }
    let sound = fit.is_some() && phi.iter().map(|p| p.1.abs()).sum::<f64>() <= MAX_ABS_WEIGHT_SUM;
    if !sound {
        phi.clear();
        phi.extend(weighted.iter().map(|&(k, w, _)| (k, w / total)));
    }
    Some(phi)
}

/// The buffers [`shape_functions`] works in, kept by the solver: a node is slaved on the
/// simulation thread.
#[derive(Debug, Clone, Default)]
pub struct ShapeScratch {
    weighted: Vec<(u32, f64, Vec3)>,
    phi: Masters,
}

impl ShapeScratch {
    /// Room for `masters` candidates (more only grow the buffers).
    pub fn with_room(masters: usize) -> Self {
        Self {
            weighted: Vec::with_capacity(masters),
            phi: Vec::with_capacity(masters),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lattice() -> Vec<Vec3> {
        let mut points = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                for k in 0..5 {
                    points.push(Vec3::new(i as f64, j as f64, k as f64) * 0.01);
                }
            }
        }
        points
    }

    /// The shape functions reproduce an affine field at a point inside the points and at
    /// one on their boundary (where a wall node sits: all its masters on one side).
    #[test]
    fn shape_functions_reproduce_affine_motion_at_a_boundary() {
        let rest = lattice();
        let kernel = Kernel { support_m: 0.02 };
        let all: Vec<u32> = (0..rest.len() as u32).collect();
        let affine = |x: &Vec3| {
            nalgebra::Matrix3::new(1.1, 0.2, -0.1, 0.05, 0.9, 0.3, 0.0, -0.2, 1.2) * x
                + Vec3::new(0.003, -0.001, 0.002)
        };
        for x in [
            Vec3::new(0.021, 0.018, 0.022),
            Vec3::new(0.021, 0.018, -0.0005),
        ] {
            let near: Vec<u32> = all
                .iter()
                .copied()
                .filter(|&k| (rest[k as usize] - x).norm() < 0.02)
                .collect();
            let mut scratch = ShapeScratch::default();
            let phi = shape_functions(&rest, x, &near, &kernel, &mut scratch).expect("weights");
            let sum: f64 = phi.iter().map(|p| p.1).sum();
            assert!((sum - 1.0).abs() < 1e-12, "{sum}");
            let moved = phi.iter().fold(Vec3::zeros(), |a, &(k, w)| {
                a + affine(&rest[k as usize]) * w
            });
            assert!(
                (moved - affine(&x)).norm() < 1e-12,
                "{moved} vs {}",
                affine(&x)
            );
        }
    }

    /// Points in a plane cannot fix the normal part of the motion: the mean instead.
    #[test]
    fn a_plane_of_masters_gives_the_weighted_mean() {
        let rest: Vec<Vec3> = lattice().into_iter().filter(|p| p.z == 0.0).collect();
        let kernel = Kernel { support_m: 0.02 };
        let all: Vec<u32> = (0..rest.len() as u32).collect();
        let mut scratch = ShapeScratch::default();
        let phi = shape_functions(
            &rest,
            Vec3::new(0.02, 0.02, 0.001),
            &all,
            &kernel,
            &mut scratch,
        )
        .expect("weights");
        assert!(phi.iter().all(|p| p.1 > 0.0));
        let sum: f64 = phi.iter().map(|p| p.1).sum();
        assert!((sum - 1.0).abs() < 1e-12);
        // What is interpolated is the displacement: at rest the node stays on its rest
        // position (not at its masters' mean, a fit-straining millimetre away), and it
        // follows a translation exactly.
        let mut points = rest.clone();
        let node = Vec3::new(0.02, 0.02, 0.001);
        points.push(node);
        let mut slaves = Slaves::new(rest.len(), 1, 0);
        slaves.slave(rest.len(), phi, &points);
        let mut x = points.clone();
        x[rest.len()] = Vec3::zeros();
        slaves.interpolate(&mut x);
        assert!((x[rest.len()] - node).norm() < 1e-15);
        let shift = Vec3::new(0.001, -0.002, 0.0005);
        x.iter_mut().take(rest.len()).for_each(|p| *p += shift);
        slaves.interpolate(&mut x);
        assert!((x[rest.len()] - (node + shift)).norm() < 1e-15);
    }

    /// Interpolation and hand-back are transposes: the work the slaved node's force does
    /// on an interpolated displacement is the work its masters' shares do.
    #[test]
    fn hand_back_is_the_transpose_of_interpolation() {
        let mut slaves = Slaves::new(3, 2, 0);
        let rest = vec![Vec3::zeros(); 5];
        slaves.slave(3, &[(0, 0.5), (1, 0.7), (2, -0.2)], &rest);
        let mut x = vec![
            Vec3::new(1.0, 2.0, 3.0),
            Vec3::new(-1.0, 0.5, 2.0),
            Vec3::new(0.3, 0.1, -4.0),
            Vec3::zeros(),
            Vec3::new(9.0, 9.0, 9.0),
        ];
        slaves.interpolate(&mut x);
        let mut f = vec![Vec3::zeros(); 5];
        f[3] = Vec3::new(0.2, -1.0, 0.4);
        let work = f[3].dot(&x[3]);
        slaves.hand_back(&mut f);
        assert_eq!(f[3], Vec3::zeros());
        let shared: f64 = (0..3).map(|k| f[k].dot(&x[k])).sum();
        assert!((work - shared).abs() < 1e-12);
        // Node 4 was never slaved: left alone.
        assert_eq!(x[4], Vec3::new(9.0, 9.0, 9.0));
        slaves.free(3);
        assert!(!slaves.is_slaved(3) && slaves.list().is_empty());
    }
}
