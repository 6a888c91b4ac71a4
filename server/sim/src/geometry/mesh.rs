//! The surface triangle mesh and its measures.

use crate::math::{Aabb, Vec3};

/// A triangle surface mesh: positions in metres, triangles as vertex-index triples.
///
/// Triangles wind counter-clockwise seen from outside once the mesh has been validated
/// (see [`crate::geometry::validate`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions (m).
    pub positions: Vec<Vec3>,
    /// Triangles, three indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Builds a mesh from positions and triangles.
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Self {
        Self {
            positions,
            triangles,
        }
    }

    /// Corner positions of triangle `t`.
    #[inline]
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Area-weighted normal of triangle `t` (length = 2 × area).
    #[inline]
    pub fn doubled_area_normal(&self, t: usize) -> Vec3 {
        let [a, b, c] = self.corners(t);
        (b - a).cross(&(c - a))
    }

    /// Enclosed volume by the divergence theorem (m³). Positive for outward winding.
    pub fn signed_volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t);
                a.dot(&b.cross(&c))
            })
            .sum::<f64>()
            / 6.0
    }

    /// Total surface area (m²).
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| 0.5 * self.doubled_area_normal(t).norm())
            .sum()
    }

    /// Bounding box of the vertices.
    pub fn bbox(&self) -> Aabb {
        Aabb::around(&self.positions)
    }

    /// Mean edge length over all triangle edges (m).
    pub fn mean_edge_length(&self) -> f64 {
        if self.triangles.is_empty() {
            return 0.0;
        }
        let total: f64 = (0..self.triangles.len())
            .map(|t| {
                let [a, b, c] = self.corners(t);
                (b - a).norm() + (c - b).norm() + (a - c).norm()
            })
            .sum();
        total / (3 * self.triangles.len()) as f64
    }

    /// The three interior angles of triangle `t` in degrees.
    pub fn angles_deg(&self, t: usize) -> [f64; 3] {
        triangle_angles_deg(self.corners(t))
    }

    /// Smallest interior angle over all triangles (degrees); 0 for an empty mesh.
    pub fn min_angle_deg(&self) -> f64 {
        if self.triangles.is_empty() {
            return 0.0;
        }
        (0..self.triangles.len())
            .flat_map(|t| self.angles_deg(t))
            .fold(f64::INFINITY, f64::min)
    }

    /// Applies `f` to every position.
    pub fn map_positions(&mut self, mut f: impl FnMut(Vec3) -> Vec3) {
        for p in &mut self.positions {
            *p = f(*p);
        }
    }

    /// Reverses the winding of every triangle.
    pub fn flip_all(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
    }
}

/// The three interior angles of the triangle with corners `[a, b, c]` in degrees.
pub fn triangle_angles_deg([a, b, c]: [Vec3; 3]) -> [f64; 3] {
    [
        angle_deg(b - a, c - a),
        angle_deg(c - b, a - b),
        angle_deg(a - c, b - c),
    ]
}

/// The smallest interior angle of the triangle with corners `[a, b, c]` in degrees.
pub fn triangle_min_angle_deg(corners: [Vec3; 3]) -> f64 {
    triangle_angles_deg(corners)
        .into_iter()
        .fold(f64::INFINITY, f64::min)
}

/// Angle between two vectors in degrees; 0 if either is zero.
pub fn angle_deg(u: Vec3, v: Vec3) -> f64 {
    let n = u.norm() * v.norm();
    if n == 0.0 {
        return 0.0;
    }
    // atan2 of |u×v| and u·v stays accurate for angles near 0 and 180°.
    u.cross(&v).norm().atan2(u.dot(&v)).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> TriMesh {
        TriMesh::new(
            vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 0.0, 1.0),
            ],
            vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
        )
    }

    #[test]
    fn tetra_volume_is_one_sixth_and_outward() {
        assert!((tetra().signed_volume() - 1.0 / 6.0).abs() < 1e-15);
    }

    #[test]
    fn right_triangle_angles() {
        let m = tetra();
        let mut a = m.angles_deg(0);
        a.sort_by(f64::total_cmp);
        assert!((a[0] - 45.0).abs() < 1e-12 && (a[2] - 90.0).abs() < 1e-12);
        assert!((m.min_angle_deg() - 45.0).abs() < 1e-9);
    }
}
