//! Small math vocabulary shared by every module: f64 vectors (SI units) and axis-aligned boxes.

use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

/// A 3-vector in double precision. Positions are in metres unless a name says otherwise.
pub type Vec3 = Vector3<f64>;
/// A 3×3 matrix in double precision.
pub type Mat3 = Matrix3<f64>;

/// `k` made symmetric with each eigenvalue clamped to `[lo, hi]`; zero if `k` is not
/// finite. (A stiffness bounded to what may be rendered or trusted.)
pub fn clamp_eigenvalues(k: &Mat3, lo: f64, hi: f64) -> Mat3 {
    let sym = (k + k.transpose()) * 0.5;
    if !sym.iter().all(|v| v.is_finite()) {
        return Mat3::zeros();
    }
    let mut eig = nalgebra::SymmetricEigen::new(sym);
    for l in eig.eigenvalues.iter_mut() {
        *l = l.clamp(lo, hi);
    }
    eig.recompose()
}

/// Axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Aabb {
    /// Minimum corner.
    pub min: [f64; 3],
    /// Maximum corner.
    pub max: [f64; 3],
}

impl Aabb {
    /// The empty box: `grow` with any point gives that point.
    pub const EMPTY: Aabb = Aabb {
        min: [f64::INFINITY; 3],
        max: [f64::NEG_INFINITY; 3],
    };

    /// Smallest box around `points`; [`Aabb::EMPTY`] for no points.
    pub fn around<'a>(points: impl IntoIterator<Item = &'a Vec3>) -> Aabb {
        let mut b = Aabb::EMPTY;
        for p in points {
            b.grow(p);
        }
        b
    }

    /// Extends the box to contain `p`.
    pub fn grow(&mut self, p: &Vec3) {
        for a in 0..3 {
            self.min[a] = self.min[a].min(p[a]);
            self.max[a] = self.max[a].max(p[a]);
        }
    }

    /// Edge lengths.
    pub fn size(&self) -> Vec3 {
        Vec3::new(
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        )
    }

    /// Minimum corner as a vector.
    pub fn min_v(&self) -> Vec3 {
        Vec3::from(self.min)
    }

    /// Maximum corner as a vector.
    pub fn max_v(&self) -> Vec3 {
        Vec3::from(self.max)
    }

    /// Centre point.
    pub fn center(&self) -> Vec3 {
        (self.min_v() + self.max_v()) * 0.5
    }

    /// Length of the diagonal.
    pub fn diagonal(&self) -> f64 {
        self.size().norm()
    }

    /// True when no point has been added.
    pub fn is_empty(&self) -> bool {
        (0..3).any(|a| self.min[a] > self.max[a])
    }

    /// Squared distance from `p` to the box (0 inside).
    pub fn distance_sq(&self, p: &Vec3) -> f64 {
        (0..3)
            .map(|a| {
                (self.min[a] - p[a])
                    .max(p[a] - self.max[a])
                    .max(0.0)
                    .powi(2)
            })
            .sum()
    }

    /// The box grown by `margin` on every side.
    pub fn expanded(&self, margin: f64) -> Aabb {
        Aabb {
            min: self.min.map(|c| c - margin),
            max: self.max.map(|c| c + margin),
        }
    }

    /// Whether the two boxes share a point (touching counts).
    pub fn overlaps(&self, other: &Aabb) -> bool {
        (0..3).all(|a| self.min[a] <= other.max[a] && self.max[a] >= other.min[a])
    }

    /// Whether `p` is in the box (its faces count).
    pub fn contains(&self, p: &Vec3) -> bool {
        (0..3).all(|a| p[a] >= self.min[a] && p[a] <= self.max[a])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_grow_overlap_and_contain_with_their_faces() {
        let unit = Aabb::around(&[Vec3::zeros(), Vec3::repeat(1.0)]);
        let beside = Aabb::around(&[Vec3::new(1.5, 0.0, 0.0), Vec3::new(2.0, 1.0, 1.0)]);
        assert!(!unit.overlaps(&beside) && !beside.overlaps(&unit));
        let grown = unit.expanded(0.5);
        assert!(grown.overlaps(&beside) && beside.overlaps(&grown));
        assert!(grown.contains(&Vec3::new(-0.5, 1.5, 0.5)));
        assert!(!grown.contains(&Vec3::new(-0.6, 0.5, 0.5)));
        assert!(Aabb::EMPTY.expanded(1.0).is_empty());
    }
}
