//! The one place where parry3d's glam/f32 types meet our nalgebra/f64 ones.
//!
//! parry3d 0.31 uses glam (f32) for its math. Everything else in scalpel-sim uses nalgebra
//! in f64, so conversions live here only. Boxes are widened by a relative margin when
//! rounded to f32 so that candidate queries stay conservative.

use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as GlamVec;
use parry3d::partitioning::{Bvh, BvhBuildStrategy};

use crate::geometry::TriMesh;
use crate::math::Vec3;

/// Rounds an f64 box outward to an f32 parry box.
fn conservative_box(min: &Vec3, max: &Vec3) -> ParryAabb {
    let widen = |v: f64| (v.abs() * 1e-6 + 1e-12) as f32;
    let lo = GlamVec::new(
        min.x as f32 - widen(min.x),
        min.y as f32 - widen(min.y),
        min.z as f32 - widen(min.z),
    );
    let hi = GlamVec::new(
        max.x as f32 + widen(max.x),
        max.y as f32 + widen(max.y),
        max.z as f32 + widen(max.z),
    );
    ParryAabb::new(lo, hi)
}

/// The conservative box of a triangle.
fn box_around(a: &Vec3, b: &Vec3, c: &Vec3) -> ParryAabb {
    conservative_box(&a.inf(b).inf(c), &a.sup(b).sup(c))
}

/// Bounding-volume hierarchy over a mesh's triangles, for box queries.
pub struct TriangleBvh {
    bvh: Bvh,
}

impl TriangleBvh {
    /// Builds the hierarchy over all triangles of `mesh`.
    pub fn build(mesh: &TriMesh) -> Self {
        let leaves: Vec<ParryAabb> = (0..mesh.triangles.len())
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                box_around(&a, &b, &c)
            })
            .collect();
        Self {
            bvh: Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves),
        }
    }

    /// Moves triangle `t`'s box (after its vertices moved, or a new triangle `t`): the leaf
    /// is updated in place and its ancestors widened, no rebuild. Boxes only grow this way;
    /// queries stay conservative.
    pub fn update(&mut self, t: usize, corners: &[Vec3; 3]) {
        let [a, b, c] = corners;
        self.bvh.insert(box_around(a, b, c), t as u32);
    }

    /// Moves every triangle's box to `mesh`'s positions (the triangles the hierarchy was
    /// built over) and refits the inner boxes: the tree keeps the shape it was built with,
    /// and its boxes are tight again. A few times cheaper than [`Self::build`].
    pub fn refit_to(&mut self, mesh: &TriMesh) {
        for t in 0..mesh.triangles.len() {
            let [a, b, c] = mesh.corners(t);
            let present = (self.bvh)
                .update_partially_if_present(box_around(&a, &b, &c), t as u32, 0.0)
                .is_some();
            assert!(present, "triangle {t} is not in the hierarchy");
        }
        self.bvh.refit_without_opt();
    }

    /// Removes triangle `t`.
    pub fn remove(&mut self, t: usize) {
        self.bvh.remove(t as u32);
    }

    /// Calls `f` with the index of every triangle whose box overlaps `[min, max]`
    /// (conservatively: a few extra candidates are possible, none are missed).
    pub fn for_each_overlapping(&self, min: &Vec3, max: &Vec3, mut f: impl FnMut(usize)) {
        let query = conservative_box(min, max);
        for leaf in self.bvh.intersect_aabb(&query) {
            f(leaf as usize);
        }
    }
}

/// Convex hull of points (used to triangulate a sphere point set). Returns triangles that
/// index into `points`; `None` when the hull does not use every point exactly once.
pub fn convex_hull_of(points: &[Vec3]) -> Option<Vec<[u32; 3]>> {
    let glam: Vec<GlamVec> = points
        .iter()
        .map(|p| GlamVec::new(p.x as f32, p.y as f32, p.z as f32))
        .collect();
    let (hull_pts, hull_tris) = parry3d::transformation::try_convex_hull(&glam).ok()?;
    if hull_pts.len() != points.len() {
        return None;
    }
    // The hull renumbers its vertices but copies their coordinates bit for bit, so the bit
    // patterns map each hull vertex back to its input point.
    let key = |p: &GlamVec| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    let index: std::collections::HashMap<[u32; 3], u32> = glam
        .iter()
        .enumerate()
        .map(|(i, p)| (key(p), i as u32))
        .collect();
    if index.len() != points.len() {
        return None;
    }
    let map: Vec<u32> = hull_pts
        .iter()
        .map(|hp| index.get(&key(hp)).copied())
        .collect::<Option<_>>()?;
    let mut seen = vec![false; points.len()];
    for &m in &map {
        if std::mem::replace(&mut seen[m as usize], true) {
            return None;
        }
    }
    Some(
        hull_tris
            .iter()
            .map(|t| [map[t[0] as usize], map[t[1] as usize], map[t[2] as usize]])
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use parry3d::bounding_volume::BoundingVolume;

    /// A 12 × 12 grid of squares in the plane z = 0, two triangles each.
    fn sheet() -> TriMesh {
        let n = 12;
        let positions = (0..=n)
            .flat_map(|j| (0..=n).map(move |i| Vec3::new(i as f64 * 0.01, j as f64 * 0.01, 0.0)))
            .collect();
        let at = |i: u32, j: u32| j * (n + 1) + i;
        let triangles = (0..n)
            .flat_map(|j| {
                (0..n).flat_map(move |i| {
                    [
                        [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                        [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
                    ]
                })
            })
            .collect();
        TriMesh::new(positions, triangles)
    }

    /// A hierarchy built over the rest shape and refitted to a deformed one answers every box
    /// query exactly as a brute-force pass over the deformed triangles' boxes does (and so as
    /// one built over the deformed shape): no triangle is missed where it moved to, none is
    /// found where it left.
    #[test]
    fn a_hierarchy_refitted_to_moved_vertices_finds_what_a_new_one_finds() {
        let rest = sheet();
        let mut moved = rest.clone();
        for p in &mut moved.positions {
            *p += Vec3::new(
                0.02 * (40.0 * p.y).sin(),
                0.01 * (30.0 * p.x).cos(),
                0.03 * (25.0 * (p.x + p.y)).sin(),
            );
        }
        let mut refitted = TriangleBvh::build(&rest);
        refitted.refit_to(&moved);
        let fresh = TriangleBvh::build(&moved);
        let mut found_any = 0;
        for k in 0..200 {
            let t = k as f64;
            let centre = Vec3::new(
                0.06 + 0.07 * (1.3 * t).sin(),
                0.06 + 0.07 * (0.7 * t).cos(),
                0.03 * (2.1 * t).sin(),
            );
            let side = 0.002 + 0.01 * (0.5 + 0.5 * (3.7 * t).sin());
            // Tall boxes (the sheet rises and falls by 3 cm), some of them flat.
            let half = Vec3::new(side, side, if k % 4 == 0 { side } else { 0.04 });
            let (lo, hi) = (centre - half, centre + half);
            let query = conservative_box(&lo, &hi);
            let mut brute: Vec<usize> = (0..moved.triangles.len())
                .filter(|&t| {
                    let [a, b, c] = moved.corners(t);
                    box_around(&a, &b, &c).intersects(&query)
                })
                .collect();
            let mut from_refit = Vec::new();
            refitted.for_each_overlapping(&lo, &hi, |t| from_refit.push(t));
            let mut from_fresh = Vec::new();
            fresh.for_each_overlapping(&lo, &hi, |t| from_fresh.push(t));
            for list in [&mut brute, &mut from_refit, &mut from_fresh] {
                list.sort_unstable();
            }
            assert_eq!(from_refit, brute, "query {k}");
            assert_eq!(from_fresh, brute, "query {k}");
            found_any += usize::from(!brute.is_empty());
        }
        assert!(found_any > 100, "the queries should mostly hit the sheet");
    }
}
