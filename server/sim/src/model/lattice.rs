//! Interior points on a regular lattice (the paper's "equidistant interpolation"), with
//! cell-clipped volumes (physics.md §1.3), and the spacing solve for a target point count.

use serde::Serialize;

use super::cell_volume::{Lattice, clipped_cell_fractions};
use crate::geometry::TriMesh;
use crate::math::{Aabb, Vec3};

/// Largest lattice (cells over the bounding box) a build may allocate.
pub const MAX_LATTICE_CELLS: usize = 64 << 20;

/// Places a lattice of spacing `spacing` over `bbox`: centred, so that a box whose sides are
/// multiples of the spacing gets points exactly on its faces, and with cells covering the box.
pub fn place_lattice(bbox: &Aabb, spacing: f64) -> Lattice {
    let size = bbox.size();
    let mut origin = Vec3::zeros();
    let mut dims = [0; 3];
    for a in 0..3 {
        // The small tolerance keeps exact multiples (a 40 mm beam at 2.5 mm) exact.
        let steps = (size[a] / spacing + 1e-9).floor();
        dims[a] = steps as usize + 1;
        origin[a] = bbox.min[a] + 0.5 * (size[a] - steps * spacing);
    }
    Lattice {
        origin,
        spacing,
        dims,
    }
}

/// Number of lattice cells the spacing would need over `bbox` (saturating).
pub fn lattice_cells(bbox: &Aabb, spacing: f64) -> usize {
    let size = bbox.size();
    (0..3)
        .map(|a| (size[a] / spacing + 1e-9).floor() + 1.0)
        .fold(1.0, |acc, n| acc * n)
        .min(usize::MAX as f64) as usize
}

/// The interior points chosen from a lattice, with their rest volumes.
#[derive(Debug, Clone)]
pub struct LatticeSampling {
    /// The lattice the points come from.
    pub lattice: Lattice,
    /// Rest positions (m).
    pub positions: Vec<Vec3>,
    /// Lattice coordinates of each point.
    pub coords: Vec<[u32; 3]>,
    /// Rest volume of each point (m³): its cell clipped to the organ, plus the volume of
    /// dropped neighbouring slivers.
    pub volumes: Vec<f64>,
    /// Cells that overlapped the organ by less than the minimum fraction and gave their
    /// volume to a neighbour.
    pub merged_slivers: usize,
}

/// Counts of a sampling attempt, for the spacing solve.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SamplingCount {
    /// Spacing tried (m).
    pub spacing_m: f64,
    /// Points kept.
    pub points: usize,
}

/// Samples the organ with a lattice of `spacing`: every cell whose clipped fraction is at
/// least `min_fraction` becomes a point; smaller slivers hand their volume to the nearest
/// kept point so that the total volume stays exact.
pub fn sample(mesh: &TriMesh, spacing: f64, min_fraction: f64) -> LatticeSampling {
    let lattice = place_lattice(&mesh.bbox(), spacing);
    let fractions = clipped_cell_fractions(mesh, &lattice);
    build_sampling(lattice, &fractions, min_fraction)
}

/// Points a lattice of `spacing` would keep, without building the point set.
pub fn count_points(mesh: &TriMesh, spacing: f64, min_fraction: f64) -> usize {
    let lattice = place_lattice(&mesh.bbox(), spacing);
    clipped_cell_fractions(mesh, &lattice)
        .iter()
        .filter(|&&f| f >= min_fraction)
        .count()
}

fn build_sampling(lattice: Lattice, fractions: &[f64], min_fraction: f64) -> LatticeSampling {
    let cell_volume = lattice.spacing.powi(3);
    let mut point_of_cell = vec![u32::MAX; fractions.len()];
    let mut positions = Vec::new();
    let mut coords = Vec::new();
    let mut volumes = Vec::new();
    for (c, &f) in fractions.iter().enumerate() {
        if f >= min_fraction {
            point_of_cell[c] = positions.len() as u32;
            let g = lattice.coords(c);
            positions.push(lattice.point(g));
            coords.push(g.map(|x| x as u32));
            volumes.push(f * cell_volume);
        }
    }
    let mut merged_slivers = 0;
    for (c, &f) in fractions.iter().enumerate() {
        if f <= 0.0 || f >= min_fraction {
            continue;
        }
        let g = lattice.coords(c);
        match nearest_kept(&lattice, &point_of_cell, fractions, g) {
            Some(p) => {
                volumes[p as usize] += f * cell_volume;
                merged_slivers += 1;
            }
            None => {
                // An island smaller than the minimum with no neighbour: keep it, or its
                // volume would be lost.
                point_of_cell[c] = positions.len() as u32;
                positions.push(lattice.point(g));
                coords.push(g.map(|x| x as u32));
                volumes.push(f * cell_volume);
            }
        }
    }
    LatticeSampling {
        lattice,
        positions,
        coords,
        volumes,
        merged_slivers,
    }
}

/// The kept point closest to cell `g` within two lattice steps (ties: the fuller cell).
fn nearest_kept(
    lattice: &Lattice,
    point_of_cell: &[u32],
    fractions: &[f64],
    g: [usize; 3],
) -> Option<u32> {
    let mut best: Option<(i64, f64, u32)> = None;
    for dz in -2i64..=2 {
        for dy in -2i64..=2 {
            for dx in -2i64..=2 {
                let n = [g[0] as i64 + dx, g[1] as i64 + dy, g[2] as i64 + dz];
                if (0..3).any(|a| n[a] < 0 || n[a] >= lattice.dims[a] as i64) {
                    continue;
                }
                let c = lattice.index(n[0] as usize, n[1] as usize, n[2] as usize);
                let p = point_of_cell[c];
                if p == u32::MAX {
                    continue;
                }
                let d2 = dx * dx + dy * dy + dz * dz;
                let better = match best {
                    None => true,
                    Some((bd, bf, _)) => d2 < bd || (d2 == bd && fractions[c] > bf),
                };
                if better {
                    best = Some((d2, fractions[c], p));
                }
            }
        }
    }
    best.map(|(_, _, p)| p)
}

/// Finds a spacing whose lattice keeps close to `target` points. A fixed-point iteration on
/// count ∝ s⁻³ brackets the target; bisection then narrows it down. The count is a step
/// function of the spacing (rows of points appear and vanish), so the best attempt is kept.
pub fn solve_spacing(
    mesh: &TriMesh,
    target: usize,
    min_fraction: f64,
) -> (f64, Vec<SamplingCount>) {
    let volume = mesh.signed_volume().abs();
    let bbox = mesh.bbox();
    let tolerance = (target / 1000).max(1);
    let mut tries: Vec<SamplingCount> = Vec::new();
    let attempt = |spacing: f64, tries: &mut Vec<SamplingCount>| {
        let points = if lattice_cells(&bbox, spacing) > MAX_LATTICE_CELLS {
            usize::MAX
        } else {
            count_points(mesh, spacing, min_fraction)
        };
        tries.push(SamplingCount {
            spacing_m: spacing,
            points,
        });
        points
    };
    // Smaller spacing ⇒ more points. `dense` keeps ≥ target points, `sparse` fewer.
    let mut dense: Option<f64> = None;
    let mut sparse: Option<f64> = None;
    let mut spacing = (volume / target as f64).cbrt();
    for _ in 0..24 {
        let points = attempt(spacing, &mut tries);
        if points.abs_diff(target) <= tolerance {
            break;
        }
        if points >= target {
            dense = Some(dense.map_or(spacing, |d: f64| d.max(spacing)));
        } else {
            sparse = Some(sparse.map_or(spacing, |s: f64| s.min(spacing)));
        }
        spacing = match (dense, sparse) {
            (Some(d), Some(s)) => {
                if (s - d) / d < 1e-6 {
                    break;
                }
                0.5 * (d + s)
            }
            _ if points == 0 || points == usize::MAX => {
                spacing * if points == 0 { 0.5 } else { 2.0 }
            }
            _ => spacing * (points as f64 / target as f64).cbrt(),
        };
    }
    let best = tries
        .iter()
        .min_by_key(|t| t.points.abs_diff(target))
        .map_or(spacing, |t| t.spacing_m);
    (best, tries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::organs::box_mesh;

    #[test]
    fn beam_lattice_puts_points_on_faces() {
        let mesh = box_mesh(Vec3::new(0.04, 0.01, 0.01), [16, 4, 4]);
        let s = sample(&mesh, 0.0025, 0.1);
        assert_eq!(s.lattice.dims, [17, 5, 5]);
        assert_eq!(s.positions.len(), 17 * 5 * 5);
        let total: f64 = s.volumes.iter().sum();
        assert!((total / 4e-6 - 1.0).abs() < 1e-7);
    }

    #[test]
    fn slivers_hand_their_volume_to_neighbours() {
        // A box 0.3 s beyond the lattice on each side: the outer cells are thin slivers.
        let mesh = box_mesh(Vec3::new(0.0106, 0.0106, 0.0106), [2, 2, 2]);
        let s = sample(&mesh, 0.005, 0.25);
        let total: f64 = s.volumes.iter().sum();
        assert!((total / mesh.signed_volume() - 1.0).abs() < 1e-7);
        assert!(s.merged_slivers > 0);
    }

    #[test]
    fn spacing_solve_reaches_the_target_on_a_smooth_organ() {
        let mesh = crate::geometry::organs::liver();
        let (spacing, tries) = solve_spacing(&mesh, 1526, 0.1);
        let points = count_points(&mesh, spacing, 0.1);
        assert!(points.abs_diff(1526) <= 15, "{points} after {tries:?}");
        assert!(tries.len() <= 24);
    }

    #[test]
    fn spacing_solve_gets_as_close_as_a_box_allows() {
        // A box's count is a product of whole rows; the solve must land on a neighbour of the target.
        let mesh = box_mesh(Vec3::new(0.05, 0.03, 0.02), [5, 3, 2]);
        let (spacing, _) = solve_spacing(&mesh, 1500, 0.1);
        let points = count_points(&mesh, spacing, 0.1);
        assert!(
            [1386, 1584, 1496].contains(&points) || points.abs_diff(1500) < 80,
            "{points}"
        );
    }
}
