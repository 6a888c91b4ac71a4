//! Smooth implicit shapes (negative inside) that the built-in organs are made of.
//!
//! Each organ is a field `base(q)` that is star-shaped around a known centre in its own
//! "base" space, plus a smooth invertible warp from base space to the world (a bend and a
//! per-axis scale). Star-shapedness is what lets a sphere triangulation be mapped onto the
//! surface without folds; the warp then gives the organ its final pose and proportions.

use crate::math::{Mat3, Vec3};

/// An ellipsoid, possibly rotated, as an approximate signed distance (mm or any unit).
#[derive(Debug, Clone, Copy)]
pub struct Ellipsoid {
    /// Centre.
    pub center: Vec3,
    /// Semi-axes.
    pub radii: Vec3,
    /// Rotation from the ellipsoid's frame to the shape's frame.
    pub rotation: Mat3,
}

impl Ellipsoid {
    /// Axis-aligned ellipsoid.
    pub fn new(center: [f64; 3], radii: [f64; 3]) -> Self {
        Self {
            center: Vec3::from(center),
            radii: Vec3::from(radii),
            rotation: Mat3::identity(),
        }
    }

    /// The same ellipsoid rotated by `deg` degrees about the z axis.
    pub fn rotated_z(mut self, deg: f64) -> Self {
        self.rotation =
            *nalgebra::Rotation3::from_axis_angle(&Vec3::z_axis(), deg.to_radians()).matrix();
        self
    }

    /// Approximate signed distance (exact on the surface's zero set, smooth elsewhere).
    pub fn distance(&self, p: &Vec3) -> f64 {
        let q = self.rotation.transpose() * (p - self.center);
        let k0 = q.component_div(&self.radii).norm();
        let k1 = q
            .component_div(&self.radii.component_mul(&self.radii))
            .norm();
        if k1 < 1e-12 {
            return -self.radii.min();
        }
        k0 * (k0 - 1.0) / k1
    }
}

/// Polynomial smooth minimum: blends two fields over a band of width `k`.
pub fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

/// A circular bend about an axis parallel to y: base-space z runs along an arc of radius
/// `radius` around (x = −radius, z = 0), base-space x becomes the radial offset.
#[derive(Debug, Clone, Copy)]
pub struct Bend {
    /// Radius of the arc followed by the base-space z axis.
    pub radius: f64,
}

impl Bend {
    /// Base space → bent space.
    pub fn forward(&self, q: &Vec3) -> Vec3 {
        let r = self.radius + q.x;
        let theta = q.z / self.radius;
        Vec3::new(r * theta.cos() - self.radius, q.y, r * theta.sin())
    }

    /// Bent space → base space.
    pub fn inverse(&self, p: &Vec3) -> Vec3 {
        let x = p.x + self.radius;
        let r = (x * x + p.z * p.z).sqrt();
        let theta = p.z.atan2(x);
        Vec3::new(r - self.radius, p.y, theta * self.radius)
    }
}

/// An organ: a star-shaped field in base space and the warp to world space (metres).
pub struct OrganShape {
    /// Field in base space, negative inside.
    pub base: Box<dyn Fn(&Vec3) -> f64 + Send + Sync>,
    /// A point the base shape is star-shaped around.
    pub star_center: Vec3,
    /// No surface point is farther than this from `star_center` (base units).
    pub reach: f64,
    /// Optional bend applied after the base field.
    pub bend: Option<Bend>,
    /// Per-axis scale from (bent) base units to metres.
    pub scale: Vec3,
}

impl OrganShape {
    /// Base space → world (m).
    pub fn to_world(&self, q: &Vec3) -> Vec3 {
        let b = self.bend.map_or(*q, |bend| bend.forward(q));
        b.component_mul(&self.scale)
    }

    /// World (m) → base space.
    pub fn to_base(&self, p: &Vec3) -> Vec3 {
        let b = p.component_div(&self.scale);
        self.bend.map_or(b, |bend| bend.inverse(&b))
    }

    /// Field value at a world point (negative inside; not a distance).
    pub fn value(&self, p: &Vec3) -> f64 {
        (self.base)(&self.to_base(p))
    }

    /// Central-difference gradient of [`OrganShape::value`] with step `h` (m).
    pub fn gradient(&self, p: &Vec3, h: f64) -> Vec3 {
        let mut g = Vec3::zeros();
        for a in 0..3 {
            let mut d = Vec3::zeros();
            d[a] = h;
            g[a] = (self.value(&(p + d)) - self.value(&(p - d))) / (2.0 * h);
        }
        g
    }

    /// The outermost surface point along the ray from the star centre in direction `dir`
    /// (base space), found by marching inward from `reach` and bisecting.
    pub fn ray_to_surface(&self, dir: &Vec3) -> Vec3 {
        let at = |t: f64| self.star_center + dir * t;
        let steps = 64;
        let mut outside = self.reach;
        let mut inside = 0.0;
        for k in (0..steps).rev() {
            let t = self.reach * k as f64 / steps as f64;
            if (self.base)(&at(t)) < 0.0 {
                inside = t;
                break;
            }
            outside = t;
        }
        for _ in 0..48 {
            let mid = 0.5 * (inside + outside);
            if (self.base)(&at(mid)) < 0.0 {
                inside = mid;
            } else {
                outside = mid;
            }
        }
        at(0.5 * (inside + outside))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ellipsoid_distance_is_zero_on_surface_and_signed() {
        let e = Ellipsoid::new([1.0, 2.0, 3.0], [4.0, 2.0, 1.0]).rotated_z(30.0);
        let on = e.center + e.rotation * Vec3::new(4.0, 0.0, 0.0);
        assert!(e.distance(&on).abs() < 1e-12);
        assert!(e.distance(&e.center) < 0.0);
        assert!(e.distance(&(e.center + Vec3::new(0.0, 0.0, 5.0))) > 0.0);
    }

    #[test]
    fn bend_round_trips() {
        let b = Bend { radius: 60.0 };
        let q = Vec3::new(7.0, -3.0, 50.0);
        assert!((b.inverse(&b.forward(&q)) - q).norm() < 1e-12);
    }
}
