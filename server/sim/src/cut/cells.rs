//! The surface's cells: what each triangle is (skin, wall, lid), a cell's smallest angle and
//! normal, flips that raise the quality of created cells, and the corners of a kind.

use std::collections::{HashMap, HashSet};

use serde::Serialize;

use crate::geometry::{TriMesh, triangle_min_angle_deg};
use crate::math::Vec3;

/// What a surface triangle is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FaceKind {
    /// Outer surface of the organ (drawn, touched by the blade).
    Skin,
    /// Wound wall inside an incision (drawn in its own colour; the blade passes it).
    Wall,
    /// The closed-incision lid between two lips (not drawn; closes the envelope for blade
    /// contact).
    Lid,
}

/// Smallest angle of the cell `tri` of `positions` (degrees).
pub(crate) fn cell_min_angle_deg(positions: &[Vec3], tri: [u32; 3]) -> f64 {
    triangle_min_angle_deg(tri.map(|v| positions[v as usize]))
}

/// Unit normal of the cell `tri` of `positions` (none if it has no area).
pub(crate) fn cell_normal(positions: &[Vec3], tri: [u32; 3]) -> Option<Vec3> {
    let [a, b, c] = tri.map(|v| positions[v as usize]);
    (b - a).cross(&(c - a)).try_normalize(1e-300)
}

/// The corners of the triangles of `kind`, with repeats.
pub fn corners_of_kind<'a>(
    mesh: &'a TriMesh,
    kinds: &'a [FaceKind],
    kind: FaceKind,
) -> impl Iterator<Item = Vec3> + 'a {
    mesh.triangles
        .iter()
        .zip(kinds)
        .filter(move |(_, k)| **k == kind)
        .flat_map(|(t, _)| t.map(|v| mesh.positions[v as usize]))
}

/// Largest angle between the two triangles of an edge that may be flipped (degrees): the
/// flip moves the surface no further than the bend between them.
const FLIP_MAX_BEND_DEG: f64 = 30.0;

/// Flips edges between two created triangles of `kind` where that raises the smaller of
/// their smallest angles as they lie on the surface. Skin: the region is triangulated to
/// the angle limit in its chart; lifted back onto a strongly curved surface (a tumour
/// 12 mm across, the rim of a region on a scanned liver) a cell can lose much of its
/// smallest angle where the chart bends across the surface's own edges, and more than
/// half where the region had to be projected onto n̄'s plane. Walls: their grid zips lips
/// and columns spaced differently (a lip graded to quarter-spacing segments at its ends
/// beside columns a gap apart). Edges against another kind or an old triangle (lips, the region's
/// unsplit boundary, a wall's lip) are never flipped, nor those `kept` says (where the
/// two walls meet face to face); neither is a bend over [`FLIP_MAX_BEND_DEG`], nor a flip
/// that would fold a cell over.
pub(crate) fn flip_to_surface_quality(
    positions: &[Vec3],
    triangles: &mut [[u32; 3]],
    kinds: &[FaceKind],
    created: &[u32],
    kind: FaceKind,
    kept: impl Fn(u32, u32) -> bool,
) {
    let free: HashSet<u32> = created
        .iter()
        .copied()
        .filter(|&t| kinds[t as usize] == kind)
        .collect();
    // The edges of every triangle at a vertex of those (a flip must not make an edge that
    // is already there).
    let mut at_free = vec![false; positions.len()];
    for &t in &free {
        for v in triangles[t as usize] {
            at_free[v as usize] = true;
        }
    }
    let mut owner: HashMap<(u32, u32), u32> = HashMap::new();
    for (t, tri) in triangles.iter().enumerate() {
        if tri.iter().any(|&v| at_free[v as usize]) {
            for k in 0..3 {
                owner.insert((tri[k], tri[(k + 1) % 3]), t as u32);
            }
        }
    }
    let smallest = |tri: [u32; 3]| cell_min_angle_deg(positions, tri);
    let normal = |tri: [u32; 3]| cell_normal(positions, tri);
    let max_bend = FLIP_MAX_BEND_DEG.to_radians().cos();
    let mut order: Vec<u32> = free.iter().copied().collect();
    order.sort_unstable();
    for _pass in 0..8 {
        let mut flipped = false;
        for &t in &order {
            for k in 0..3 {
                let tri = triangles[t as usize];
                let (a, b, c) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
                let Some(&u) = owner.get(&(b, a)) else {
                    continue;
                };
                if u == t || !free.contains(&u) || kept(a, b) {
                    continue;
                }
                let other = triangles[u as usize];
                let Some(&d) = other.iter().find(|&&v| v != a && v != b) else {
                    continue;
                };
                if d == c || owner.contains_key(&(c, d)) || owner.contains_key(&(d, c)) {
                    continue;
                }
                let (Some(n_t), Some(n_u)) = (normal(tri), normal(other)) else {
                    continue;
                };
                if n_t.dot(&n_u) < max_bend {
                    continue;
                }
                let (new_t, new_u) = ([c, a, d], [d, b, c]);
                let mean = (n_t + n_u).normalize();
                let folds = [new_t, new_u]
                    .iter()
                    .any(|&n| normal(n).is_none_or(|n| n.dot(&mean) < max_bend));
                if folds
                    || smallest(new_t).min(smallest(new_u))
                        <= smallest(tri).min(smallest(other)) + 0.5
                {
                    continue;
                }
                for tri in [tri, other] {
                    for e in 0..3 {
                        owner.remove(&(tri[e], tri[(e + 1) % 3]));
                    }
                }
                triangles[t as usize] = new_t;
                triangles[u as usize] = new_u;
                for (id, tri) in [(t, new_t), (u, new_u)] {
                    for e in 0..3 {
                        owner.insert((tri[e], tri[(e + 1) % 3]), id);
                    }
                }
                flipped = true;
            }
        }
        if !flipped {
            break;
        }
    }
}
