//! A flat map of an incision region that keeps its angles.
//!
//! The region around an incision is triangulated in 2D and lifted back onto the surface.
//! Projected onto one plane, a steep or curved part of it is squashed: the refinement's
//! good triangles come back as slivers on the surface, and where the region's boundary
//! runs along the rim of a thin part (the deltoid sheet) the triangles beyond face away
//! from the plane and cannot join the region at all, so the splits the refinement puts on
//! that boundary are fanned into needles. A least-squares conformal map (Lévy, Petitjean,
//! Ray and Maillot 2002, "Least squares conformal maps for automatic texture atlas
//! generation") flattens the region minimising, in the least-squares sense, how far each
//! triangle's map is from a similarity (angle-keeping), whatever way its triangles face: a
//! developable region (a cylinder's patch) is unrolled exactly, a flat one is its
//! projection.

use std::collections::HashMap;

use crate::geometry::TriMesh;
use crate::geometry::predicates::closest_point_on_triangle;
use crate::math::Vec3;
use crate::sparse_llt::SparseLlt;

/// A chart triangle's doubled signed area must be at least this share of its doubled
/// area on the surface: a triangle squashed further (or turned over) is no chart.
const MIN_AREA_SHARE: f64 = 1e-3;

/// 2D coordinates for the vertices of a set of mesh triangles.
pub(crate) struct Chart {
    coords: HashMap<u32, [f64; 2]>,
    triangles: Vec<usize>,
}

impl Chart {
    /// The orthogonal projection of `region`'s vertices by `project`.
    pub(crate) fn projected(
        mesh: &TriMesh,
        region: &[usize],
        project: impl Fn(&Vec3) -> [f64; 2],
    ) -> Self {
        let mut coords = HashMap::new();
        for &t in region {
            for v in mesh.triangles[t] {
                coords
                    .entry(v)
                    .or_insert_with(|| project(&mesh.positions[v as usize]));
            }
        }
        Chart {
            coords,
            triangles: region.to_vec(),
        }
    }

    /// The least-squares conformal map of `region` (a disk), turned and moved to lie as
    /// near `project`'s coordinates as it can and scaled to the region's area; `None` if a
    /// triangle comes out turned over or squashed, if the boundary crosses itself, or if
    /// the solve fails.
    pub(crate) fn conformal(
        mesh: &TriMesh,
        region: &[usize],
        project: impl Fn(&Vec3) -> [f64; 2],
    ) -> Option<Self> {
        let projected = Self::projected(mesh, region, &project);
        let mut vertices: Vec<u32> = projected.coords.keys().copied().collect();
        vertices.sort_unstable();
        let index: HashMap<u32, usize> =
            vertices.iter().enumerate().map(|(i, &v)| (v, i)).collect();
        if vertices.len() < 3 {
            return None;
        }
        let at: Vec<Vec3> = vertices
            .iter()
            .map(|&v| mesh.positions[v as usize])
            .collect();
        let triangles: Vec<[usize; 3]> = region
            .iter()
            .map(|&t| mesh.triangles[t].map(|v| index[&v]))
            .collect();
        let pins = Pins::far_apart(&at)?;
        let (entries, mut rhs) = pins.normal_equations(&triangles, &at)?;
        solve_lower(pins.unknowns(), entries, &mut rhs)?;
        let mut flat = pins.placed(&rhs)?;

        // Turned and moved onto the projection (least squares over the vertices), scaled
        // to the region's area on the surface.
        let target: Vec<[f64; 2]> = vertices.iter().map(|v| projected.coords[v]).collect();
        let area_3d: f64 = region
            .iter()
            .map(|&t| mesh.doubled_area_normal(t).norm())
            .sum();
        fit_onto(&mut flat, &target, &triangles, area_3d)?;
        // Every triangle the right way round and not squashed.
        for (&t, &tri) in region.iter().zip(&triangles) {
            if doubled_2d(&flat, tri) < MIN_AREA_SHARE * mesh.doubled_area_normal(t).norm() {
                return None;
            }
        }
        let coords: HashMap<u32, [f64; 2]> =
            vertices.iter().zip(&flat).map(|(&v, &p)| (v, p)).collect();
        let chart = Chart {
            coords,
            triangles: region.to_vec(),
        };
        chart.boundary_is_simple(mesh).then_some(chart)
    }

    /// Whether the region's boundary edges (those without a twin in the region) meet only
    /// at shared vertices in the chart: a map can keep every triangle the right way round
    /// and still lay one part of the region over another. Edges that touch or run along
    /// each other count as meeting (two boundary vertices on one chart point would be one
    /// vertex to the triangulation).
    fn boundary_is_simple(&self, mesh: &TriMesh) -> bool {
        let mut directed = std::collections::HashSet::new();
        for &t in &self.triangles {
            let tri = mesh.triangles[t];
            for k in 0..3 {
                directed.insert((tri[k], tri[(k + 1) % 3]));
            }
        }
        let edges: Vec<(u32, u32)> = directed
            .iter()
            .copied()
            .filter(|&(a, b)| !directed.contains(&(b, a)))
            .collect();
        let orient = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        };
        for (i, &(a, b)) in edges.iter().enumerate() {
            for &(c, d) in &edges[i + 1..] {
                if a == c || a == d || b == c || b == d {
                    continue;
                }
                let [pa, pb, pc, pd] = [a, b, c, d].map(|v| self.coords[&v]);
                if orient(pa, pb, pc) * orient(pa, pb, pd) <= 0.0
                    && orient(pc, pd, pa) * orient(pc, pd, pb) <= 0.0
                {
                    return false;
                }
            }
        }
        true
    }

    /// The chart position of a vertex of the region.
    pub(crate) fn vertex(&self, v: u32) -> [f64; 2] {
        self.coords[&v]
    }

    /// The chart corners of a triangle of the region.
    pub(crate) fn triangle(&self, mesh: &TriMesh, t: usize) -> [[f64; 2]; 3] {
        mesh.triangles[t].map(|v| self.vertex(v))
    }

    /// The chart position of a point on (or near) the region: through the region's
    /// triangle nearest to it, by the barycentric coordinates of its projection onto that
    /// triangle's plane (so a point beyond the region's edge maps beyond its edge).
    pub(crate) fn point(&self, mesh: &TriMesh, x: &Vec3) -> [f64; 2] {
        let nearest = self
            .triangles
            .iter()
            .map(|&t| {
                let d = (closest_point_on_triangle(x, &mesh.corners(t)) - x).norm_squared();
                (d, t)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map_or(0, |(_, t)| t);
        let [a, b, c] = mesh.corners(nearest);
        let (ab, ac, ax) = (b - a, c - a, x - a);
        let (d00, d01, d11) = (ab.dot(&ab), ab.dot(&ac), ac.dot(&ac));
        let (d20, d21) = (ax.dot(&ab), ax.dot(&ac));
        let det = d00 * d11 - d01 * d01;
        let (v, w) = if det > 0.0 {
            ((d11 * d20 - d01 * d21) / det, (d00 * d21 - d01 * d20) / det)
        } else {
            (1.0 / 3.0, 1.0 / 3.0)
        };
        let [qa, qb, qc] = self.triangle(mesh, nearest);
        let u = 1.0 - v - w;
        [
            u * qa[0] + v * qb[0] + w * qc[0],
            u * qa[1] + v * qb[1] + w * qc[1],
        ]
    }
}

/// A symmetric matrix's lower triangle by (column, row).
type Lower = HashMap<(usize, usize), f64>;

/// Two vertices far apart pinned (a conformal map is otherwise free to move, turn and
/// scale) and the numbering of the free ones' unknowns.
struct Pins {
    /// The pinned vertices and where they are pinned.
    at: [usize; 2],
    values: [[f64; 2]; 2],
    /// Each vertex's place among the free ones (`usize::MAX` for a pinned one).
    free_of: Vec<usize>,
    free: usize,
}

impl Pins {
    /// The vertex farthest from the first, and the one farthest from that, at their
    /// distance apart on the x axis.
    fn far_apart(at: &[Vec3]) -> Option<Self> {
        let n = at.len();
        let farthest = |from: usize| {
            (0..n)
                .max_by(|&a, &b| {
                    (at[a] - at[from])
                        .norm()
                        .total_cmp(&(at[b] - at[from]).norm())
                })
                .unwrap_or(0)
        };
        let pin_a = farthest(0);
        let pin_b = farthest(pin_a);
        let span = (at[pin_b] - at[pin_a]).norm();
        if pin_a == pin_b || span <= 0.0 {
            return None;
        }
        let mut pins = Pins {
            at: [pin_a, pin_b],
            values: [[0.0, 0.0], [span, 0.0]],
            free_of: vec![usize::MAX; n],
            free: 0,
        };
        for i in 0..n {
            if pins.of(i).is_none() {
                pins.free_of[i] = pins.free;
                pins.free += 1;
            }
        }
        Some(pins)
    }

    /// Which pin vertex `i` is, if any.
    fn of(&self, i: usize) -> Option<usize> {
        if i == self.at[0] {
            Some(0)
        } else if i == self.at[1] {
            Some(1)
        } else {
            None
        }
    }

    /// The number of unknowns: (u, v) of each free vertex.
    fn unknowns(&self) -> usize {
        2 * self.free
    }

    /// Unknown `k`'s row in the system (u of vertex k / 2 for even k, v for odd), or the
    /// pinned value it stands for.
    fn unknown(&self, k: usize) -> Result<usize, f64> {
        let (i, c) = (k / 2, k % 2);
        match self.of(i) {
            Some(p) => Err(self.values[p][c]),
            None => Ok(2 * self.free_of[i] + c),
        }
    }

    /// The normal equations of the conformality residuals (lower triangle, by (column,
    /// row)) and their right-hand side from the pins; `None` for a degenerate triangle.
    fn normal_equations(&self, triangles: &[[usize; 3]], at: &[Vec3]) -> Option<(Lower, Vec<f64>)> {
        let mut entries: Lower = HashMap::new();
        let mut rhs = vec![0.0; self.unknowns()];
        for &corners in triangles {
            let [p0, p1, p2] = corners.map(|i| at[i]);
            let ex = (p1 - p0).try_normalize(1e-300)?;
            let normal = (p1 - p0).cross(&(p2 - p0)).try_normalize(1e-300)?;
            let ey = normal.cross(&ex);
            let q = [p0, p1, p2].map(|p| [(p - p0).dot(&ex), (p - p0).dot(&ey)]);
            let doubled = q[1][0] * q[2][1] - q[1][1] * q[2][0];
            let w = 1.0 / doubled.sqrt();
            // The conformality residual Σ W_j U_j with W_j = z_{j+2} − z_{j+1}: its real
            // and imaginary rows over (u_j, v_j).
            let mut rows = [[(0usize, 0.0); 6], [(0usize, 0.0); 6]];
            for j in 0..3 {
                let (a, b) = (
                    w * (q[(j + 2) % 3][0] - q[(j + 1) % 3][0]),
                    w * (q[(j + 2) % 3][1] - q[(j + 1) % 3][1]),
                );
                let (iu, iv) = (2 * corners[j], 2 * corners[j] + 1);
                rows[0][2 * j] = (iu, a);
                rows[0][2 * j + 1] = (iv, -b);
                rows[1][2 * j] = (iu, b);
                rows[1][2 * j + 1] = (iv, a);
            }
            for row in &rows {
                for &(k, a) in row {
                    let Ok(r) = self.unknown(k) else { continue };
                    for &(l, b) in row {
                        match self.unknown(l) {
                            Ok(c) if c <= r => *entries.entry((c, r)).or_insert(0.0) += a * b,
                            Ok(_) => {}
                            Err(value) => rhs[r] -= a * b * value,
                        }
                    }
                }
            }
        }
        Some((entries, rhs))
    }

    /// Every vertex's map: the pins' values and the solved free ones; `None` if any is
    /// not finite.
    fn placed(&self, solved: &[f64]) -> Option<Vec<[f64; 2]>> {
        let flat: Vec<[f64; 2]> = (0..self.free_of.len())
            .map(|i| match self.of(i) {
                Some(p) => self.values[p],
                None => [solved[2 * self.free_of[i]], solved[2 * self.free_of[i] + 1]],
            })
            .collect();
        flat.iter()
            .all(|p| p[0].is_finite() && p[1].is_finite())
            .then_some(flat)
    }
}

/// Solves the `m` × `m` system whose lower triangle is `entries` (by (column, row)) in
/// place of `rhs`; `None` if it does not factor.
fn solve_lower(m: usize, entries: Lower, rhs: &mut [f64]) -> Option<()> {
    let mut sorted: Vec<((usize, usize), f64)> = entries.into_iter().collect();
    sorted.sort_unstable_by_key(|&(key, _)| key);
    let mut col_ptr = vec![0usize; m + 1];
    let mut row_idx = Vec::with_capacity(sorted.len());
    let mut values = Vec::with_capacity(sorted.len());
    for &((c, r), v) in &sorted {
        col_ptr[c + 1] += 1;
        row_idx.push(r);
        values.push(v);
    }
    for c in 0..m {
        col_ptr[c + 1] += col_ptr[c];
    }
    SparseLlt::factor(m, &col_ptr, &row_idx, &values, 1)
        .ok()?
        .solve_in_place(rhs, 1);
    Some(())
}

/// A chart triangle's doubled signed area.
fn doubled_2d(p: &[[f64; 2]], tri: [usize; 3]) -> f64 {
    let [a, b, c] = tri.map(|i| p[i]);
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Turns and moves `flat` onto `target` (least squares over the vertices) and scales it to
/// the doubled area `area_3d`; `None` if the map is turned over as a whole.
fn fit_onto(
    flat: &mut [[f64; 2]],
    target: &[[f64; 2]],
    triangles: &[[usize; 3]],
    area_3d: f64,
) -> Option<()> {
    let n = flat.len();
    let mean = |pts: &[[f64; 2]]| {
        let s = pts
            .iter()
            .fold([0.0, 0.0], |s, p| [s[0] + p[0], s[1] + p[1]]);
        [s[0] / n as f64, s[1] / n as f64]
    };
    let (cf, ct) = (mean(flat), mean(target));
    let (mut dot, mut cross) = (0.0, 0.0);
    for (f, t) in flat.iter().zip(target) {
        let (a, b) = ([f[0] - cf[0], f[1] - cf[1]], [t[0] - ct[0], t[1] - ct[1]]);
        dot += a[0] * b[0] + a[1] * b[1];
        cross += a[0] * b[1] - a[1] * b[0];
    }
    let angle = cross.atan2(dot);
    let area_2d: f64 = triangles.iter().map(|&tri| doubled_2d(flat, tri)).sum();
    if area_2d <= 0.0 {
        return None;
    }
    let scale = (area_3d / area_2d).sqrt();
    let (cos, sin) = (scale * angle.cos(), scale * angle.sin());
    for p in flat.iter_mut() {
        let (x, y) = (p[0] - cf[0], p[1] - cf[1]);
        *p = [ct[0] + cos * x - sin * y, ct[1] + sin * x + cos * y];
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::triangle_angles_deg;

    /// A grid of `nx` × `ny` squares, each split in two, mapped by `place` from (x, y).
    fn grid(nx: usize, ny: usize, place: impl Fn(f64, f64) -> Vec3) -> TriMesh {
        let mut positions = Vec::new();
        for j in 0..=ny {
            for i in 0..=nx {
                positions.push(place(i as f64, j as f64));
            }
        }
        let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
        let mut triangles = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        TriMesh::new(positions, triangles)
    }

    fn all(mesh: &TriMesh) -> Vec<usize> {
        (0..mesh.triangles.len()).collect()
    }

    /// A flat region square to the projection is its projection; a point beyond its edge
    /// maps beyond the edge, where the projection puts it.
    #[test]
    fn a_flat_region_maps_to_its_projection() {
        let mesh = grid(6, 4, |x, y| {
            Vec3::new(1e-3 * x + 0.3e-3 * y, 1e-3 * y, 0.02)
        });
        let project = |p: &Vec3| [p.x, p.y];
        let chart = Chart::conformal(&mesh, &all(&mesh), project).expect("a chart");
        let near = |q: [f64; 2], p: &Vec3| (q[0] - p.x).abs() < 1e-12 && (q[1] - p.y).abs() < 1e-12;
        for (v, p) in mesh.positions.iter().enumerate() {
            let q = chart.vertex(v as u32);
            assert!(near(q, p), "{v}: {q:?}");
        }
        let beyond = Vec3::new(-0.4e-3, 2.5e-3, 0.02);
        assert!(near(chart.point(&mesh, &beyond), &beyond));
    }

    /// A half cylinder (a sheet bent round a 5 mm radius, its sides facing away from the
    /// projection plane at up to 90° and beyond) is unrolled: every angle and length as on
    /// the surface, where the projection squashes the sides to slivers.
    #[test]
    fn a_bent_sheet_is_unrolled_with_its_angles() {
        let radius = 5e-3;
        let step = std::f64::consts::PI * 1.1 / 12.0;
        let mesh = grid(12, 5, |i, j| {
            let phi = -0.55 * std::f64::consts::PI + step * i;
            Vec3::new(radius * phi.sin(), 1e-3 * j, radius * phi.cos())
        });
        let project = |p: &Vec3| [p.x, p.y];
        let chart = Chart::conformal(&mesh, &all(&mesh), project).expect("a chart");
        let flat = |tri: [u32; 3]| {
            tri.map(|v| {
                let q = chart.vertex(v);
                Vec3::new(q[0], q[1], 0.0)
            })
        };
        let (mut worst_chart, mut worst_projection) = (0.0f64, 0.0f64);
        for tri in &mesh.triangles {
            let surface = triangle_angles_deg(tri.map(|v| mesh.positions[v as usize]));
            let mapped = triangle_angles_deg(flat(*tri));
            let projected = triangle_angles_deg(tri.map(|v| {
                let p = mesh.positions[v as usize];
                Vec3::new(p.x, p.y, 0.0)
            }));
            for k in 0..3 {
                worst_chart = worst_chart.max((mapped[k] - surface[k]).abs());
                worst_projection = worst_projection.max((projected[k] - surface[k]).abs());
            }
        }
        assert!(worst_chart < 1e-6, "chart off by {worst_chart}°");
        assert!(
            worst_projection > 30.0,
            "projection off by {worst_projection}°"
        );
        // Lengths too (the chart is scaled to the area).
        let (a, b) = (mesh.triangles[0][0], mesh.triangles[0][1]);
        let (qa, qb) = (chart.vertex(a), chart.vertex(b));
        let along = ((qb[0] - qa[0]).powi(2) + (qb[1] - qa[1]).powi(2)).sqrt();
        let surface = (mesh.positions[b as usize] - mesh.positions[a as usize]).norm();
        assert!((along / surface - 1.0).abs() < 1e-9, "{along} vs {surface}");
        // A point on a triangle maps to the same barycentric place in the chart.
        let t = 30;
        let [p, q, r] = mesh.corners(t);
        let x = p * 0.2 + q * 0.5 + r * 0.3;
        let [cp, cq, cr] = chart.triangle(&mesh, t);
        let mapped = chart.point(&mesh, &x);
        let wanted = [
            0.2 * cp[0] + 0.5 * cq[0] + 0.3 * cr[0],
            0.2 * cp[1] + 0.5 * cq[1] + 0.3 * cr[1],
        ];
        assert!((mapped[0] - wanted[0]).abs() < 1e-12 && (mapped[1] - wanted[1]).abs() < 1e-12);
    }

    /// A fan whose corners round its centre sum to 400° (a cone's tip opened out too
    /// far) cannot be laid flat without one triangle over another: no chart.
    #[test]
    fn a_region_that_would_overlap_itself_has_no_chart() {
        let spokes = 8;
        let mut positions = vec![Vec3::zeros()];
        for k in 0..=spokes {
            let phi = (50.0 * k as f64).to_radians();
            // Rising, so that the surface itself does not meet itself.
            let z = 1e-5 * k as f64 / spokes as f64;
            positions.push(Vec3::new(1e-3 * phi.cos(), 1e-3 * phi.sin(), z));
        }
        let triangles: Vec<[u32; 3]> = (1..=spokes as u32).map(|k| [0, k, k + 1]).collect();
        let fan = TriMesh::new(positions, triangles);
        let project = |p: &Vec3| [p.x, p.y];
        assert!(Chart::conformal(&fan, &all(&fan), project).is_none());
        // Six of them (300°) lie flat.
        let open: Vec<usize> = (0..6).collect();
        assert!(Chart::conformal(&fan, &open, project).is_some());
    }
}
