//! The swept cut surface Σ and the visibility criterion (physics.md §4.1–4.2).
//!
//! Each tick the immersed part of the cutting edge sweeps a ruled quad between its previous
//! and current positions; its two triangles are appended to Σ, kept in **rest** coordinates so
//! that the test below does not change as the tissue deforms. A neighbour pair (i, j) is
//! disconnected when the rest segment `[X_i, X_j]` crosses a triangle of Σ (Belytschko's
//! visibility criterion): j leaves N(i) and i leaves N(j). Only the points whose lists changed
//! need their MLS rows recomputed.

use crate::geometry::predicates::segment_meets_triangle;
use crate::math::{Aabb, Vec3};
use crate::model::{Neighbourhoods, RestGrid};

/// Σ as a triangle soup in rest coordinates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SweptSurface {
    /// Triangles (m, rest space).
    pub triangles: Vec<[Vec3; 3]>,
    /// Each triangle's box: Σ only grows, and the queries for the part of Σ near a point
    /// (the crack share every cutting tick, new wound vertices and virtual points at every
    /// re-mesh) test these first.
    pub boxes: Vec<Aabb>,
}

/// Triangles Σ has room for before it grows, so that it grows without reallocating on the
/// simulation thread: the default cuts add 120 (liver), 259 (shoulder) and 372
/// (cerebroma), a six-stroke liver session 404 (`scalpel cut ... --json`,
/// `sigma_triangles`). Past it, Σ doubles like any vector.
pub const SIGMA_ROOM: usize = 4096;

impl SweptSurface {
    /// An empty Σ with room for [`SIGMA_ROOM`] triangles.
    pub fn with_room() -> Self {
        Self {
            triangles: Vec::with_capacity(SIGMA_ROOM),
            boxes: Vec::with_capacity(SIGMA_ROOM),
        }
    }

    /// Appends the quad swept by an edge moving from `(tip0, entry0)` to `(tip1, entry1)`;
    /// returns how many triangles were added (0 for a degenerate sweep).
    pub fn add_sweep(&mut self, tip0: Vec3, entry0: Vec3, tip1: Vec3, entry1: Vec3) -> usize {
        let mut added = 0;
        for tri in [[tip0, entry0, entry1], [tip0, entry1, tip1]] {
            let area2 = (tri[1] - tri[0]).cross(&(tri[2] - tri[0])).norm();
            let scale = (tri[1] - tri[0]).norm().max((tri[2] - tri[0]).norm());
            if area2 > 1e-12 * scale * scale && area2 > 0.0 {
                self.triangles.push(tri);
                self.boxes.push(Aabb::around(&tri));
                added += 1;
            }
        }
        added
    }

    /// Appends the part of the blade's flat between `tip` and `top` (up its edge): what a
    /// blade pushed in point first slits. The flat reaches `width` behind the edge along
    /// `toward_back` (unit, across the edge), narrowing at 45° to the tip — a scalpel's
    /// point, as the cutting stage's crack share counts it. Returns the triangles added.
    pub fn add_blade_flat(&mut self, tip: Vec3, top: Vec3, toward_back: Vec3, width: f64) -> usize {
        let up = top - tip;
        let reach = up.norm().min(width);
        let Some(up) = up.try_normalize(1e-12) else {
            return 0;
        };
        let across = toward_back * reach;
        // Past a blade width up, the back runs parallel to the edge; below, it is the
        // point's 45° taper (when the flat is shorter than its width, this corner is the
        // slit's end and the second triangle is empty).
        let corner = tip + up * reach + across;
        self.add_sweep(tip, top, corner, top + across)
    }
}

/// Removes every neighbour pair whose rest segment meets `triangle`; the points whose lists
/// changed are appended to `changed` (unsorted, possibly repeated). `candidates` is scratch.
pub fn cut_pairs(
    triangle: &[Vec3; 3],
    rest: &[Vec3],
    grid: &RestGrid,
    neighbours: &mut Neighbourhoods,
    support_m: f64,
    changed: &mut Vec<u32>,
    candidates: &mut Vec<u32>,
) -> usize {
    let mut removed = 0;
    visit_crossing_pairs(
        triangle,
        rest,
        grid,
        neighbours,
        support_m,
        candidates,
        |neighbours, i, j, _| {
            neighbours.remove(i as usize, j);
            neighbours.remove(j as usize, i);
            changed.push(i);
            changed.push(j);
            removed += 1;
            true
        },
    );
    removed
}

/// Calls `act(neighbours, i, j, crossing)` for every neighbour pair (i < j) whose rest
/// segment meets `triangle`, with the rest point where it does; `act` returns whether it
/// removed the pair from N(i). `candidates` is scratch.
pub fn visit_crossing_pairs(
    triangle: &[Vec3; 3],
    rest: &[Vec3],
    grid: &RestGrid,
    neighbours: &mut Neighbourhoods,
    support_m: f64,
    candidates: &mut Vec<u32>,
    mut act: impl FnMut(&mut Neighbourhoods, u32, u32, Vec3) -> bool,
) {
    // Both ends of a crossing pair are within h of the triangle: look around its box.
    let lo = triangle[0].inf(&triangle[1]).inf(&triangle[2]);
    let hi = triangle[0].sup(&triangle[1]).sup(&triangle[2]);
    let centre = (lo + hi) * 0.5;
    let reach = (hi - lo).norm() * 0.5 + support_m;
    candidates.clear();
    grid.for_each_within(rest, &centre, reach, |i, _| candidates.push(i));
    for &i in candidates.iter() {
        let i = i as usize;
        let mut k = 0;
        while k < neighbours.of(i).len() {
            let j = neighbours.of(i)[k];
            let (a, b) = (rest[i], rest[j as usize]);
            let removed = (j as usize) > i
                && segment_meets_triangle(&a, &b, triangle)
                && act(
                    neighbours,
                    i as u32,
                    j,
                    segment_plane_point(&a, &b, triangle),
                );
            if !removed {
                k += 1;
            }
        }
    }
}

/// Where the segment a–b meets the plane of `triangle` (its midpoint when it lies in it).
fn segment_plane_point(a: &Vec3, b: &Vec3, triangle: &[Vec3; 3]) -> Vec3 {
    let n = (triangle[1] - triangle[0]).cross(&(triangle[2] - triangle[0]));
    let along = n.dot(&(b - a));
    if along.abs() <= 1e-300 {
        return (a + b) * 0.5;
    }
    let t = (n.dot(&(triangle[0] - a)) / along).clamp(0.0, 1.0);
    a + (b - a) * t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seams_and_corners_do_not_leak() {
        let t1 = [
            Vec3::new(0., 0., 0.),
            Vec3::new(1., 0., 0.),
            Vec3::new(1., 1., 0.),
        ];
        let t2 = [
            Vec3::new(0., 0., 0.),
            Vec3::new(1., 1., 0.),
            Vec3::new(0., 1., 0.),
        ];
        // Through the shared diagonal, and through a shared vertex.
        for x in [
            Vec3::new(0.5, 0.5, 0.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.3, 0.7, 0.0),
        ] {
            let (p, q) = (x + Vec3::new(0.0, 0.0, -1.0), x + Vec3::new(0.0, 0.0, 1.0));
            assert!(
                segment_meets_triangle(&p, &q, &t1) || segment_meets_triangle(&p, &q, &t2),
                "{x}"
            );
        }
        let (p, q) = (Vec3::new(2.0, 0.5, -1.0), Vec3::new(2.0, 0.5, 1.0));
        assert!(!segment_meets_triangle(&p, &q, &t1) && !segment_meets_triangle(&p, &q, &t2));
        // Same side: no crossing.
        assert!(!segment_meets_triangle(
            &Vec3::new(0.5, 0.2, 0.1),
            &Vec3::new(0.5, 0.2, 2.0),
            &t1
        ));
    }
}
