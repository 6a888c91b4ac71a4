//! What the eye sees of a wound while a scripted cut runs: how far the drawn surface jumps
//! when an incision lands, how far from it new surface appears, and how wide the lips
//! stand apart (issue 41's `max_vertex_jump_mm`, `max_surface_growth_mm` and `opening_mm`).

use scalpel_sim::geometry::TriMesh;
use scalpel_sim::geometry::parry_adapter::TriangleBvh;
use scalpel_sim::geometry::predicates::closest_point_on_triangle;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::Simulation;

/// Farthest a jump is looked for (m): a vertex farther than this from the other surface
/// reads as this far.
const MOST_JUMP_M: f64 = 0.064;

/// Distance from `x` to `mesh` (m), at most [`MOST_JUMP_M`].
fn distance_to(x: &Vec3, mesh: &TriMesh, bvh: &TriangleBvh) -> f64 {
    let mut reach = 0.001;
    while reach <= MOST_JUMP_M {
        let r = Vec3::repeat(reach);
        let mut best = f64::INFINITY;
        bvh.for_each_overlapping(&(x - r), &(x + r), |t| {
            let d = (closest_point_on_triangle(x, &mesh.corners(t)) - x).norm();
            best = best.min(d);
        });
        // Only a hit within the box's inscribed sphere is surely the nearest.
        if best <= reach {
            return best;
        }
        reach *= 2.0;
    }
    MOST_JUMP_M
}

/// The largest distance from a vertex of `a` used by a triangle to the surface `b` (m).
fn one_way(a: &TriMesh, b: &TriMesh, bvh: &TriangleBvh) -> f64 {
    let mut used = vec![false; a.positions.len()];
    for t in &a.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    a.positions
        .iter()
        .zip(&used)
        .filter(|(_, u)| **u)
        .map(|(x, _)| distance_to(x, b, bvh))
        .fold(0.0, f64::max)
}

/// Watches the drawn surface for changes that are not the field's: a re-cut landing, a
/// wound deepened. The surface lives in rest space and the field carries it, so a change of
/// the rest surface is exactly what moves on screen without the tissue moving it.
pub struct SurfaceWatch {
    last: TriMesh,
    signature: (usize, usize, usize),
}

fn signature(sim: &Simulation) -> (usize, usize, usize) {
    let s = sim.current_surface();
    let runs = sim.incisions().map_or(0, |i| i.runs + i.incisions);
    (s.mesh.positions.len(), s.mesh.triangles.len(), runs)
}

impl SurfaceWatch {
    /// Starts from the simulation's surface now.
    pub fn new(sim: &Simulation) -> Self {
        Self {
            last: sim.current_surface().drawn_rest(),
            signature: signature(sim),
        }
    }

    /// If the surface changed since the last call, how far it jumped, in rest space.
    pub fn jump(&mut self, sim: &Simulation) -> Option<Jump> {
        let now = signature(sim);
        if now == self.signature {
            return None;
        }
        self.signature = now;
        let surface = sim.current_surface();
        let (next, skin) = (surface.drawn_rest(), surface.skin_rest());
        let old = TriangleBvh::build(&self.last);
        let jump = Jump {
            moved_m: one_way(&self.last, &next, &TriangleBvh::build(&next))
                .max(one_way(&skin, &self.last, &old)),
            grown_m: one_way(&next, &self.last, &old),
        };
        self.last = next;
        Some(jump)
    }
}

/// How the drawn surface changed without the field changing it (m, rest space).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jump {
    /// How far what was drawn moved: the farthest an old vertex is from the new surface,
    /// or a new skin vertex (a lip, the skin around it) from the old one.
    pub moved_m: f64,
    /// How far from the old surface new surface appeared: a wound's walls growing with
    /// the crack (the one-way Hausdorff distance, new to old).
    pub grown_m: f64,
}

/// The lips' current gap (m) across the wound nearest to `at` (rest): at the wall column
/// whose top is nearest, the distance between the upper and the lower lip at its place
/// along the path. `None` without a column within `within_m` of `at`.
pub fn lip_gap_m(sim: &Simulation, at: Vec3, within_m: f64) -> Option<f64> {
    let s = sim.current_surface();
    let (wound, column) = s
        .wounds
        .iter()
        .flat_map(|w| w.columns.iter().map(move |c| (w, c)))
        .min_by(|a, b| (a.1.top - at).norm().total_cmp(&(b.1.top - at).norm()))?;
    if (column.top - at).norm() > within_m {
        return None;
    }
    let p = &s.mesh.positions;
    let on = |lip: &[(f64, u32)]| -> Option<Vec3> {
        let k = lip.partition_point(|&(t, _)| t <= column.param);
        let (t1, v1) = *lip.get(k.min(lip.len() - 1))?;
        let (t0, v0) = *lip.get(k.saturating_sub(1))?;
        let f = if t1 > t0 {
            ((column.param - t0) / (t1 - t0)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        Some(p[v0 as usize] + (p[v1 as usize] - p[v0 as usize]) * f)
    };
    Some((on(&wound.upper)? - on(&wound.lower)?).norm())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(z: f64) -> TriMesh {
        TriMesh::new(
            vec![
                Vec3::new(0.0, 0.0, z),
                Vec3::new(0.01, 0.0, z),
                Vec3::new(0.01, 0.01, z),
                Vec3::new(0.0, 0.01, z),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    /// A surface moved 2 mm jumps 2 mm each way; a far one reads as the cap.
    #[test]
    fn the_jump_is_the_distance_between_the_surfaces() {
        let a = square(0.0);
        let b = square(0.002);
        let d = one_way(&a, &b, &TriangleBvh::build(&b));
        assert!((d - 0.002).abs() < 1e-12, "{d}");
        let far = square(1.0);
        assert_eq!(one_way(&a, &far, &TriangleBvh::build(&far)), MOST_JUMP_M);
        assert_eq!(one_way(&a, &a, &TriangleBvh::build(&a)), 0.0);
    }
}
