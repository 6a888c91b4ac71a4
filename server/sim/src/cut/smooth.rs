//! Moving the region's new vertices where their cells came out poorly on the surface.
//!
//! The incision region is triangulated to the angle limit in its chart (super::chart) and
//! lifted onto the surface. A conformal chart keeps angles only triangle by triangle, and
//! where the region has no such chart it is projected onto one plane: where it runs onto a
//! steep side (the ends of a stroke over the deltoid sheet, faces 70–80° from the plane's
//! normal) a cell fine in the plane is then a needle or a flat cap on the surface (the
//! chart's kinks, across the surface's own edges, do the same on a smaller scale); flips
//! and collapses leave those whose
//! neighbours are no better. A new vertex inside the region can move instead: within its
//! ring in the plane, lifted back onto the surface, to where the smallest angle of its
//! cells on the surface is largest — optimisation-based smoothing, restricted to the
//! surface as it was, so the organ's shape does not change.

use std::collections::{HashMap, HashSet};

use crate::math::Vec3;

use super::cells::{cell_min_angle_deg, cell_normal};

/// Cells whose smallest angle is under this are worked on.
const SMOOTH_BELOW_DEG: f64 = 20.0;
/// A move must raise the smallest angle around the vertex by this much.
const SMOOTH_GAIN_DEG: f64 = 1.0;
/// Largest turn of a cell's normal that a move may cause (as for flips and collapses).
const SMOOTH_MAX_TURN_DEG: f64 = 30.0;
/// An equilateral triangle's height over its side.
const HALF_SQRT_3: f64 = 0.866_025_403_784_438_6;
/// Passes over the vertices (a move changes its neighbours' rings).
const SMOOTH_PASSES: usize = 3;

/// Moves vertices of `movable` (new vertices inside the region, off its boundary and the
/// lips) where the smallest angle of their cells on the surface is under
/// [`SMOOTH_BELOW_DEG`], to the place among a few candidates in the region's chart
/// (toward the centroid of the ring, and the ring cells' own best places) that raises it
/// most — by [`SMOOTH_GAIN_DEG`] at least. `project` maps a point of the region to the
/// chart and `lift` back onto the surface (inverse of each other on the region). A move
/// keeps every ring cell the same way round in the plane and turning on the surface by at
/// most [`SMOOTH_MAX_TURN_DEG`]. The vertices moved.
pub(crate) fn smooth_to_quality(
    positions: &mut [Vec3],
    triangles: &[[u32; 3]],
    movable: &HashSet<u32>,
    project: impl Fn(&Vec3) -> [f64; 2],
    lift: impl Fn([f64; 2]) -> Vec3,
) -> Vec<u32> {
    let mut ring: HashMap<u32, Vec<usize>> = HashMap::new();
    for (t, tri) in triangles.iter().enumerate() {
        for v in tri {
            if movable.contains(v) {
                ring.entry(*v).or_default().push(t);
            }
        }
    }
    let mut order: Vec<u32> = ring.keys().copied().collect();
    order.sort_unstable();
    let max_turn = SMOOTH_MAX_TURN_DEG.to_radians().cos();
    let mut moved = Vec::new();
    for _pass in 0..SMOOTH_PASSES {
        let mut any = false;
        for &v in &order {
            let cells = &ring[&v];
            let worst = |positions: &[Vec3]| {
                cells
                    .iter()
                    .map(|&t| cell_min_angle_deg(positions, triangles[t]))
                    .fold(180.0, f64::min)
            };
            let before = worst(positions);
            if before >= SMOOTH_BELOW_DEG {
                continue;
            }
            let here = positions[v as usize];
            let normals: Vec<Option<Vec3>> = cells
                .iter()
                .map(|&t| cell_normal(positions, triangles[t]))
                .collect();
            let area2 = |tri: [u32; 3], at: [f64; 2], positions: &[Vec3]| {
                let [a, b, c] = tri.map(|w| {
                    if w == v {
                        at
                    } else {
                        project(&positions[w as usize])
                    }
                });
                (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
            };
            let p0 = project(&here);
            let signs: Vec<f64> = cells
                .iter()
                .map(|&t| area2(triangles[t], p0, positions).signum())
                .collect();
            // Candidates: toward the centroid of the ring, and toward each cell's
            // equilateral apex on its far edge (where that cell alone would be best).
            let mut neighbours: Vec<u32> = cells
                .iter()
                .flat_map(|&t| triangles[t])
                .filter(|&w| w != v)
                .collect();
            neighbours.sort_unstable();
            neighbours.dedup();
            let centroid = neighbours.iter().fold([0.0, 0.0], |s, &w| {
                let q = project(&positions[w as usize]);
                [s[0] + q[0], s[1] + q[1]]
            });
            let centroid = centroid.map(|x| x / neighbours.len() as f64);
            let mut candidates: Vec<[f64; 2]> = [1.0, 0.5, 0.25]
                .iter()
                .map(|&f| {
                    [
                        p0[0] + f * (centroid[0] - p0[0]),
                        p0[1] + f * (centroid[1] - p0[1]),
                    ]
                })
                .collect();
            for (&t, &sign) in cells.iter().zip(&signs) {
                let tri = triangles[t];
                let k = tri.iter().position(|&w| w == v).unwrap_or(0);
                let a = project(&positions[tri[(k + 1) % 3] as usize]);
                let b = project(&positions[tri[(k + 2) % 3] as usize]);
                // The apex of the equilateral triangle on (a, b), on v's side.
                let mid = [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
                let perp = [-(b[1] - a[1]) * HALF_SQRT_3, (b[0] - a[0]) * HALF_SQRT_3];
                let apex = [mid[0] + sign * perp[0], mid[1] + sign * perp[1]];
                for f in [0.5, 0.25] {
                    candidates.push([p0[0] + f * (apex[0] - p0[0]), p0[1] + f * (apex[1] - p0[1])]);
                }
            }
            let mut best: Option<(f64, Vec3)> = None;
            for at in candidates {
                // (Where the lift puts it: a point outside the region is clamped onto it.)
                let x = lift(at);
                let at = project(&x);
                let keeps_sides = cells.iter().zip(&signs).all(|(&t, &sign)| {
                    let a = area2(triangles[t], at, positions);
                    a * sign > 0.0
                });
                if !keeps_sides {
                    continue;
                }
                positions[v as usize] = x;
                let faces_ok = cells.iter().zip(&normals).all(|(&t, old)| {
                    match (cell_normal(positions, triangles[t]), old) {
                        (Some(n), Some(old)) => n.dot(old) >= max_turn,
                        _ => false,
                    }
                });
                let after = worst(positions);
                positions[v as usize] = here;
                if faces_ok
                    && after >= before + SMOOTH_GAIN_DEG
                    && best.as_ref().is_none_or(|(b, _)| after > *b)
                {
                    best = Some((after, x));
                }
            }
            if let Some((_, x)) = best {
                positions[v as usize] = x;
                moved.push(v);
                any = true;
            }
        }
        if !any {
            break;
        }
    }
    moved.sort_unstable();
    moved.dedup();
    moved
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vertex pushed next to one side of its hexagonal ring on a face 72° from the
    /// projection plane (z = 3x): its cells are slivers on the surface (5.7°). Moved
    /// within the ring in the plane and lifted, its smallest angle rises past 40° (58.7°);
    /// it stays on the face and every cell the same way round; the ring does not move. A
    /// vertex not allowed to move stays.
    #[test]
    fn a_vertex_next_to_a_side_of_its_ring_moves_to_better_cells_on_a_steep_face() {
        let lift = |p: [f64; 2]| Vec3::new(p[0], p[1], 3.0 * p[0]);
        let project = |x: &Vec3| [x.x, x.y];
        let mut positions: Vec<Vec3> = (0..6)
            .map(|k| {
                let a = k as f64 * std::f64::consts::FRAC_PI_3;
                lift([0.001 * a.cos() / 3.0, 0.001 * a.sin()])
            })
            .collect();
        positions.push(lift([0.00019, 0.0006]));
        let triangles: Vec<[u32; 3]> = (0..6).map(|k| [6, k, (k + 1) % 6]).collect();
        let worst = |positions: &[Vec3]| {
            triangles
                .iter()
                .map(|&t| cell_min_angle_deg(positions, t))
                .fold(180.0, f64::min)
        };
        let normals = |positions: &[Vec3]| -> Vec<Vec3> {
            triangles
                .iter()
                .map(|&t| cell_normal(positions, t).expect("area"))
                .collect()
        };
        let before = worst(&positions);
        assert!(before < 6.0, "{before}");

        let mut kept = positions.clone();
        let none = HashSet::new();
        assert!(smooth_to_quality(&mut kept, &triangles, &none, project, lift).is_empty());
        assert_eq!(kept, positions);

        let old_normals = normals(&positions);
        let ring = positions[..6].to_vec();
        let movable = HashSet::from([6]);
        let moved = smooth_to_quality(&mut positions, &triangles, &movable, project, lift);
        assert_eq!(moved, [6]);
        let after = worst(&positions);
        assert!(after > 40.0, "{before}° → {after}°");
        assert_eq!(positions[..6], ring[..]);
        let v = positions[6];
        assert!((v.z - 3.0 * v.x).abs() < 1e-15, "{v:?}");
        let max_turn = SMOOTH_MAX_TURN_DEG.to_radians().cos();
        for (new, old) in normals(&positions).iter().zip(&old_normals) {
            assert!(new.dot(old) >= max_turn);
        }
    }
}
