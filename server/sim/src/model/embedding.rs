//! Surface vertices embedded in the meshless field (physics.md §5.3): each vertex follows
//! `x_v = Σ_k ŵ_vk (p_k + F_k (X_v − X_k))` over the interior points k within the support
//! radius of its rest position, with normalised kernel weights. A point only counts if the
//! rest segment from the vertex to it does not pass through the surface, so a vertex never
//! couples to tissue across a fold or a gap.

use serde::Serialize;

use super::neighbours::{Kernel, RestGrid};
use crate::geometry::TriMesh;
use crate::geometry::parry_adapter::TriangleBvh;
use crate::geometry::predicates::{segment_crosses_triangle, segment_meets_triangle};
use crate::math::{Aabb, Vec3};

/// Embedding weights of every surface vertex, in compressed rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurfaceEmbedding {
    /// `points[start[v]..start[v + 1]]` are the interior points vertex v follows.
    pub start: Vec<u32>,
    /// Interior point indices.
    pub points: Vec<u32>,
    /// Normalised weights, summing to 1 per vertex.
    pub weights: Vec<f64>,
    /// Vertices whose support had to be widened to find a visible point.
    pub widened: usize,
}

/// Cut triangles that hide points from a vertex, each with its box.
#[derive(Debug, Clone, Copy)]
pub struct Blockers<'a> {
    /// The triangles (rest space).
    pub triangles: &'a [[Vec3; 3]],
    /// Their boxes, one each.
    pub boxes: &'a [Aabb],
}

/// How well the surface is tied to the interior.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EmbeddingStats {
    /// Fewest points any vertex follows.
    pub min_points: usize,
    /// Mean points per vertex.
    pub mean_points: f64,
    /// Vertices that needed a widened support.
    pub widened: usize,
}

impl SurfaceEmbedding {
    /// Embeds every vertex of `surface` in the points at `positions`.
    pub fn build(surface: &TriMesh, positions: &[Vec3], grid: &RestGrid, kernel: &Kernel) -> Self {
        let bvh = TriangleBvh::build(surface);
        let mut incident: Vec<Vec<u32>> = vec![Vec::new(); surface.positions.len()];
        for (t, tri) in surface.triangles.iter().enumerate() {
            for &v in tri {
                incident[v as usize].push(t as u32);
            }
        }
        let mut start = vec![0u32];
        let mut points = Vec::new();
        let mut weights = Vec::new();
        let mut widened = 0;
        let mut found: Vec<(u32, f64)> = Vec::new();
        for (v, x) in surface.positions.iter().enumerate() {
            let mut radius = kernel.support_m;
            for attempt in 0..4 {
                found.clear();
                let wider = Kernel { support_m: radius };
                grid.for_each_within(positions, x, radius, |k, d2| {
                    let w = wider.weight_sq(d2);
                    if w > 0.0 && visible(surface, &bvh, &incident[v], x, &positions[k as usize]) {
                        found.push((k, w));
                    }
                });
                if !found.is_empty() {
                    if attempt > 0 {
                        widened += 1;
                    }
                    break;
                }
                radius *= 1.5;
            }
            if found.is_empty() {
                // No visible point within 3.4 h: follow the nearest point rigidly.
                let nearest = positions
                    .iter()
                    .enumerate()
                    .min_by(|a, b| {
                        (a.1 - x)
                            .norm_squared()
                            .total_cmp(&(b.1 - x).norm_squared())
                    })
                    .map(|(k, _)| k as u32);
                if let Some(k) = nearest {
                    found.push((k, 1.0));
                }
                widened += 1;
            }
            found.sort_unstable_by_key(|(k, _)| *k);
            let total: f64 = found.iter().map(|(_, w)| w).sum();
            for &(k, w) in &found {
                points.push(k);
                weights.push(w / total);
            }
            start.push(points.len() as u32);
        }
        Self {
            start,
            points,
            weights,
            widened,
        }
    }

    /// The points and weights vertex `v` follows.
    pub fn of(&self, v: usize) -> (&[u32], &[f64]) {
        let r = self.start[v] as usize..self.start[v + 1] as usize;
        (&self.points[r.clone()], &self.weights[r])
    }

    /// Stops vertex `v` (rest position `x`) from following points across the cut triangle
    /// `cut`: their weights drop to zero and the rest are renormalised. A vertex whose every
    /// point lies across keeps its weights (it must follow something; the cut is then
    /// thinner than the sampling there). Returns whether anything changed.
    pub fn drop_across(&mut self, v: usize, x: &Vec3, points: &[Vec3], cut: &[Vec3; 3]) -> bool {
        let r = self.start[v] as usize..self.start[v + 1] as usize;
        let crosses = |k: u32| segment_meets_triangle(x, &points[k as usize], cut);
        let mut kept = 0.0;
        let mut dropped = false;
        for (&k, &w) in self.points[r.clone()].iter().zip(&self.weights[r.clone()]) {
            if w > 0.0 {
                if crosses(k) {
                    dropped = true;
                } else {
                    kept += w;
                }
            }
        }
        if !dropped || kept <= 0.0 {
            return false;
        }
        for idx in r {
            let w = &mut self.weights[idx];
            if *w > 0.0 {
                *w = if crosses(self.points[idx]) {
                    0.0
                } else {
                    *w / kept
                };
            }
        }
        true
    }

    /// Embedding rows given per vertex (weights are normalised here).
    pub fn from_rows(rows: &[Vec<(u32, f64)>], widened: usize) -> Self {
        let mut out = Self {
            start: Vec::with_capacity(rows.len() + 1),
            points: Vec::new(),
            weights: Vec::new(),
            widened,
        };
        out.restart(widened);
        for row in rows {
            out.push_row(row.iter().copied());
        }
        out
    }

    /// Empties the embedding (keeping its buffers) for rows pushed with
    /// [`Self::push_row`].
    pub fn restart(&mut self, widened: usize) {
        self.start.clear();
        self.start.push(0);
        self.points.clear();
        self.weights.clear();
        self.widened = widened;
    }

    /// Appends the next vertex's row, its weights normalised.
    pub fn push_row(&mut self, row: impl Iterator<Item = (u32, f64)> + Clone) {
        let total: f64 = row.clone().map(|(_, w)| w).sum();
        for (k, w) in row {
            self.points.push(k);
            self.weights.push(if total > 0.0 { w / total } else { 0.0 });
        }
        self.start.push(self.points.len() as u32);
    }

    /// Kernel weights of a new vertex at `x` over the points within the support whose rest
    /// segment to it crosses none of `blockers` (the cut surface, each triangle with its
    /// box). The support widens up to three times when nothing is visible; the nearest
    /// point is the last resort.
    pub fn row_for(
        x: &Vec3,
        positions: &[Vec3],
        grid: &RestGrid,
        kernel: &Kernel,
        blockers: &[[Vec3; 3]],
        blocker_boxes: &[Aabb],
    ) -> Vec<(u32, f64)> {
        let mut row = Vec::new();
        let blockers = Blockers {
            triangles: blockers,
            boxes: blocker_boxes,
        };
        Self::row_into(
            x,
            positions,
            grid,
            kernel,
            blockers,
            &mut Vec::new(),
            &mut row,
        );
        row
    }

    /// The normalised kernel row (weights summing to 1) of a sample at rest position `x`
    /// of an uncut body: what a new material sample of its surface follows (the tray's
    /// samples, a probe's).
    pub fn sample_row(
        x: &Vec3,
        positions: &[Vec3],
        grid: &RestGrid,
        kernel: &Kernel,
    ) -> Vec<(u32, f64)> {
        let mut row = Self::row_for(x, positions, grid, kernel, &[], &[]);
        let total: f64 = row.iter().map(|(_, w)| w).sum();
        row.iter_mut().for_each(|(_, w)| *w /= total);
        row
    }

    /// [`Self::row_for`] into `row`, with `within` as scratch: for the simulation thread,
    /// which keeps both.
    pub fn row_into(
        x: &Vec3,
        positions: &[Vec3],
        grid: &RestGrid,
        kernel: &Kernel,
        blockers: Blockers<'_>,
        within: &mut Vec<u32>,
        row: &mut Vec<(u32, f64)>,
    ) {
        let mut radius = kernel.support_m;
        row.clear();
        // Only the blockers whose box comes within the search radius can hide a point
        // found, and only those are tested against each of them (every cut triangle
        // against each of tens of points was most of a re-mesh on a fine model).
        for _ in 0..4 {
            let wider = Kernel { support_m: radius };
            within.clear();
            within.extend(
                (blockers.boxes.iter().enumerate())
                    .filter(|(_, b)| b.distance_sq(x) <= radius * radius)
                    .map(|(t, _)| t as u32),
            );
            grid.for_each_within(positions, x, radius, |k, d2| {
                let w = wider.weight_sq(d2);
                if w <= 0.0 {
                    return;
                }
                let p = &positions[k as usize];
                let segment = Aabb::around([x, p]);
                let blocker = within.iter().position(|&t| {
                    let t = t as usize;
                    hides(&blockers.triangles[t], &blockers.boxes[t], x, p, &segment)
                });
                match blocker {
                    None => row.push((k, w)),
                    // The triangle that hid this point likely hides the next ones too (a
                    // vertex walled in by a shredded wound sees little): tried first from now
                    // on. Which points are found does not depend on the order.
                    Some(j) => within[..=j].rotate_right(1),
                }
            });
            if !row.is_empty() {
                row.sort_unstable_by_key(|(k, _)| *k);
                return;
            }
            radius *= 1.5;
        }
        let nearest = positions.iter().enumerate().min_by(|a, b| {
            (a.1 - x)
                .norm_squared()
                .total_cmp(&(b.1 - x).norm_squared())
        });
        if let Some((k, _)) = nearest {
            row.push((k as u32, 1.0));
        }
    }

    /// Whether one of `blockers` (with their boxes) hides rest point `p` from a vertex at
    /// `x`: the test [`Self::row_for`] drops points by.
    pub fn hidden(x: &Vec3, p: &Vec3, blockers: &[[Vec3; 3]], blocker_boxes: &[Aabb]) -> bool {
        let segment = Aabb::around([x, p]);
        blockers
            .iter()
            .zip(blocker_boxes)
            .any(|(tri, b)| hides(tri, b, x, p, &segment))
    }

    /// Summary for reports.
    pub fn stats(&self) -> EmbeddingStats {
        let n = self.start.len() - 1;
        let counts = (0..n).map(|v| (self.start[v + 1] - self.start[v]) as usize);
        EmbeddingStats {
            min_points: counts.clone().min().unwrap_or(0),
            mean_points: if n == 0 {
                0.0
            } else {
                self.points.len() as f64 / n as f64
            },
            widened: self.widened,
        }
    }

    /// Positions of the vertices when the points are at `current` and have deformation
    /// gradients given by `gradient(k)`. At rest (current = rest, F = I) this returns the
    /// rest positions exactly up to rounding.
    pub fn vertex_position(
        &self,
        v: usize,
        rest_vertex: &Vec3,
        rest: &[Vec3],
        current: &[Vec3],
        gradient: impl Fn(usize) -> crate::math::Mat3,
    ) -> Vec3 {
        let (pts, ws) = self.of(v);
        pts.iter()
            .zip(ws)
            .map(|(&k, &w)| {
                let k = k as usize;
                (current[k] + gradient(k) * (rest_vertex - rest[k])) * w
            })
            .sum()
    }
}

/// Whether the rest segment from a surface vertex to a point stays clear of the surface.
fn visible(surface: &TriMesh, bvh: &TriangleBvh, own: &[u32], x: &Vec3, p: &Vec3) -> bool {
    let lo = x.inf(p);
    let hi = x.sup(p);
    let mut clear = true;
    bvh.for_each_overlapping(&lo, &hi, |t| {
        if clear
            && !own.contains(&(t as u32))
            && segment_crosses_triangle(x, p, &surface.corners(t))
        {
            clear = false;
        }
    });
    clear
}

/// Whether the cut triangle `tri` (box `b`) crosses the segment from `x` to `p` (box
/// `segment`).
fn hides(tri: &[Vec3; 3], b: &Aabb, x: &Vec3, p: &Vec3, segment: &Aabb) -> bool {
    b.overlaps(segment) && segment_meets_triangle(x, p, tri)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 9×9×9 lattice of 1 cm, a vertex at its centre, and a wall of blockers at x = +4 mm
    /// (two triangles per cell face of a 6 cm square, in a shuffled order) with shreds
    /// around it.
    fn walled() -> (Vec<Vec3>, RestGrid, Kernel, Vec<[Vec3; 3]>) {
        let s = 0.01;
        let positions: Vec<Vec3> = (0..729)
            .map(|i| Vec3::new((i % 9) as f64, (i / 9 % 9) as f64, (i / 81) as f64) * s)
            .map(|p| p - Vec3::repeat(4.0 * s))
            .collect();
        let grid = RestGrid::build(&positions, 2.0 * s);
        let mut blockers = Vec::new();
        for j in -3..3 {
            for k in -3..3 {
                let (y, z) = (f64::from(j) * s, f64::from(k) * s);
                let c = |dy: f64, dz: f64| Vec3::new(0.004, y + dy * s, z + dz * s);
                blockers.push([c(0.0, 0.0), c(1.0, 0.0), c(1.0, 1.0)]);
                blockers.push([c(0.0, 0.0), c(1.0, 1.0), c(0.0, 1.0)]);
            }
        }
        // Shreds: small triangles scattered on the far side, hiding nothing new.
        for m in 0..40 {
            let a = Vec3::new(
                0.02 + 0.0005 * f64::from(m),
                -0.03 + 0.0015 * f64::from(m),
                0.01,
            );
            blockers.push([
                a,
                a + Vec3::new(0.001, 0.0, 0.0),
                a + Vec3::new(0.0, 0.001, 0.0),
            ]);
        }
        // Shuffled deterministically.
        let n = blockers.len();
        for i in 0..n {
            blockers.swap(i, (i * 37 + 11) % n);
        }
        (positions, grid, Kernel { support_m: 2.5 * s }, blockers)
    }

    #[test]
    fn a_vertex_follows_the_points_it_sees_whatever_the_order_of_the_blockers() {
        let (positions, grid, kernel, blockers) = walled();
        let boxes: Vec<Aabb> = blockers.iter().map(Aabb::around).collect();
        let x = Vec3::new(0.001, 0.0005, 0.0002);
        let row = SurfaceEmbedding::row_for(&x, &positions, &grid, &kernel, &blockers, &boxes);
        assert!(!row.is_empty());
        // Nothing beyond the wall, everything on this side within the support.
        for &(k, _) in &row {
            assert!(
                positions[k as usize].x < 0.004,
                "point {k} is behind the wall"
            );
        }
        let seen = positions
            .iter()
            .filter(|p| p.x < 0.004 && (*p - x).norm() < kernel.support_m)
            .count();
        assert_eq!(row.len(), seen);
        // The blockers the other way round (the search reorders its own copy as it goes):
        // the same row, bit for bit.
        let reversed: Vec<[Vec3; 3]> = blockers.iter().rev().copied().collect();
        let reversed_boxes: Vec<Aabb> = reversed.iter().map(Aabb::around).collect();
        let again =
            SurfaceEmbedding::row_for(&x, &positions, &grid, &kernel, &reversed, &reversed_boxes);
        assert_eq!(row, again);
    }
}
