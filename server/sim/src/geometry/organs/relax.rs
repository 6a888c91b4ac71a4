//! Meshing an implicit organ with an exact vertex count and good, evenly sized triangles.
//!
//! A Fibonacci point set on the unit sphere is triangulated by its convex hull (genus 0, so
//! T = 2V − 4 exactly) and mapped onto the organ along rays from its star centre. That map
//! crowds points where the organ is near the centre and starves its far ends, so an isotropic
//! remesher follows (Botsch & Kobbelt 2004): split long edges, collapse short ones, flip edges
//! toward Delaunay, smooth tangentially and project back onto the implicit surface. A final
//! round of splits or collapses sets the vertex count exactly, and a last relaxation polishes.

use std::collections::HashSet;

use crate::geometry::TriMesh;
use crate::geometry::organs::implicit::OrganShape;
use crate::geometry::parry_adapter::convex_hull_of;
use crate::geometry::topology::EdgeTable;
use crate::math::Vec3;

/// Unit directions spread evenly over the sphere (golden-angle spiral).
pub fn fibonacci_sphere(n: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            Vec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Meshes `shape` with exactly `vertices` vertices (2·vertices − 4 triangles).
pub fn mesh_organ(shape: &OrganShape, vertices: usize, iterations: usize) -> TriMesh {
    let dirs = fibonacci_sphere(vertices);
    let mut triangles = convex_hull_of(&dirs).expect("a Fibonacci sphere is in convex position");
    // Wind outward: on the unit sphere the normal must point away from the centre.
    for t in &mut triangles {
        let [a, b, c] = [
            dirs[t[0] as usize],
            dirs[t[1] as usize],
            dirs[t[2] as usize],
        ];
        if (b - a).cross(&(c - a)).dot(&(a + b + c)) < 0.0 {
            t.swap(1, 2);
        }
    }
    let positions = dirs
        .iter()
        .map(|d| shape.to_world(&shape.ray_to_surface(d)))
        .collect();
    let mut mesh = TriMesh::new(positions, triangles);
    let h = mesh.mean_edge_length() * 1e-3;
    // Edge length of an equilateral triangulation of the same area with the target count.
    let target_triangles = (2 * vertices - 4) as f64;
    let length = (4.0 * mesh.area() / (3f64.sqrt() * target_triangles)).sqrt();
    let remesher = Remesher { shape, h };
    for _ in 0..8 {
        remesher.split_long_edges(&mut mesh, 4.0 / 3.0 * length, usize::MAX);
        remesher.collapse_short_edges(&mut mesh, 0.8 * length, usize::MAX, 4.0 / 3.0 * length);
        delaunay_flips(&mut mesh, shape, h);
        for _ in 0..3 {
            smooth_tangentially(&mut mesh, shape, h, 0.6);
        }
    }
    // Land exactly on the requested count: split the longest or collapse the shortest edges.
    for round in 0..64 {
        let have = mesh.positions.len();
        // Collapses near the target are picky about the edges they create; relax that
        // gradually if the count is not reached.
        let longest_after = (4.0 / 3.0 + round as f64 * 0.1) * length;
        if have == vertices {
            break;
        }
        if have < vertices {
            remesher.split_long_edges(&mut mesh, 0.0, vertices - have);
        } else {
            remesher.collapse_short_edges(&mut mesh, f64::INFINITY, have - vertices, longest_after);
        }
        delaunay_flips(&mut mesh, shape, h);
    }
    assert_eq!(
        mesh.positions.len(),
        vertices,
        "remesher must reach the vertex count"
    );
    for _ in 0..iterations {
        delaunay_flips(&mut mesh, shape, h);
        smooth_tangentially(&mut mesh, shape, h, 0.6);
    }
    delaunay_flips(&mut mesh, shape, h);
    for p in &mut mesh.positions {
        *p = project(shape, *p, h);
    }
    mesh
}

/// Edge splits and collapses on an implicit surface.
struct Remesher<'a> {
    shape: &'a OrganShape,
    h: f64,
}

impl Remesher<'_> {
    /// Splits up to `budget` edges longer than `min_len`, longest first, at their midpoints
    /// projected onto the surface. Each triangle takes part in at most one split per call.
    fn split_long_edges(&self, mesh: &mut TriMesh, min_len: f64, budget: usize) {
        let table = EdgeTable::build(&mesh.triangles);
        let mut order: Vec<(f64, usize)> = (0..table.len())
            .map(|e| {
                let [a, b] = table.edges[e];
                (
                    (mesh.positions[a as usize] - mesh.positions[b as usize]).norm(),
                    e,
                )
            })
            .filter(|(len, _)| *len > min_len)
            .collect();
        order.sort_by(|x, y| y.0.total_cmp(&x.0));
        let mut touched = vec![false; mesh.triangles.len()];
        let mut done = 0;
        for (_, e) in order {
            if done == budget {
                break;
            }
            let &[u, w] = table.uses_of(e) else { continue };
            let (t0, t1) = (u.triangle as usize, w.triangle as usize);
            if touched[t0] || touched[t1] {
                continue;
            }
            let [p, q] = table.edges[e];
            let mid = 0.5 * (mesh.positions[p as usize] + mesh.positions[q as usize]);
            let m = mesh.positions.len() as u32;
            mesh.positions.push(project(self.shape, mid, self.h));
            // Replace each triangle (x, y, o) holding the edge by (x, m, o) and (m, y, o).
            for t in [t0, t1] {
                let tri = mesh.triangles[t];
                let k = (0..3)
                    .find(|&k| {
                        let (x, y) = (tri[k], tri[(k + 1) % 3]);
                        (x == p && y == q) || (x == q && y == p)
                    })
                    .expect("the edge belongs to its triangle");
                let (x, y, o) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
                mesh.triangles[t] = [x, m, o];
                mesh.triangles.push([m, y, o]);
                touched[t] = true;
                touched.push(true);
            }
            done += 1;
        }
    }

    /// Collapses up to `budget` edges shorter than `max_len`, shortest first, into their
    /// projected midpoints, when the collapse keeps the surface a manifold with no flipped or
    /// triangles with an edge of `longest_after` or more. Vertices next to a collapse sit out the rest of the call.
    fn collapse_short_edges(
        &self,
        mesh: &mut TriMesh,
        max_len: f64,
        budget: usize,
        longest_after: f64,
    ) {
        let table = EdgeTable::build(&mesh.triangles);
        let n = mesh.positions.len();
        let mut incident: Vec<Vec<usize>> = vec![Vec::new(); n];
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for &v in tri {
                incident[v as usize].push(t);
            }
        }
        let ring = |v: u32, tris: &[[u32; 3]]| -> HashSet<u32> {
            incident[v as usize]
                .iter()
                .flat_map(|&t| tris[t])
                .filter(|&x| x != v)
                .collect()
        };
        let mut order: Vec<(f64, usize)> = (0..table.len())
            .map(|e| {
                let [a, b] = table.edges[e];
                (
                    (mesh.positions[a as usize] - mesh.positions[b as usize]).norm(),
                    e,
                )
            })
            .filter(|(len, _)| *len < max_len)
            .collect();
        order.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut frozen = vec![false; n];
        let mut dead_vertex = vec![false; n];
        let mut dead_triangle = vec![false; mesh.triangles.len()];
        let mut done = 0;
        for (_, e) in order {
            if done == budget {
                break;
            }
            let [a, b] = table.edges[e];
            if frozen[a as usize] || frozen[b as usize] {
                continue;
            }
            let &[u, w] = table.uses_of(e) else { continue };
            let (t0, t1) = (u.triangle as usize, w.triangle as usize);
            let ring_a = ring(a, &mesh.triangles);
            let ring_b = ring(b, &mesh.triangles);
            // Link condition: a and b may share only the two vertices opposite the edge.
            if ring_a.intersection(&ring_b).count() != 2 || ring_a.len() + ring_b.len() < 7 {
                continue;
            }
            let opposite: Vec<u32> = [t0, t1]
                .iter()
                .map(|&t| {
                    mesh.triangles[t]
                        .iter()
                        .copied()
                        .find(|&v| v != a && v != b)
                        .unwrap_or(a)
                })
                .collect();
            if opposite
                .iter()
                .any(|&o| ring(o, &mesh.triangles).len() <= 3)
            {
                continue;
            }
            let m = project(
                self.shape,
                0.5 * (mesh.positions[a as usize] + mesh.positions[b as usize]),
                self.h,
            );
            let ok = incident[a as usize]
                .iter()
                .chain(&incident[b as usize])
                .filter(|&&t| t != t0 && t != t1)
                .all(|&t| {
                    let old = mesh.corners(t);
                    let new: Vec<Vec3> = mesh.triangles[t]
                        .iter()
                        .map(|&v| {
                            if v == a || v == b {
                                m
                            } else {
                                mesh.positions[v as usize]
                            }
                        })
                        .collect();
                    let n_old = (old[1] - old[0]).cross(&(old[2] - old[0]));
                    let n_new = (new[1] - new[0]).cross(&(new[2] - new[0]));
                    let longest = (new[1] - new[0])
                        .norm()
                        .max((new[2] - new[1]).norm())
                        .max((new[0] - new[2]).norm());
                    n_new.dot(&n_old) > 0.3 * n_old.norm() * n_new.norm() && longest < longest_after
                });
            if !ok {
                continue;
            }
            mesh.positions[a as usize] = m;
            for &t in &incident[b as usize] {
                for v in mesh.triangles[t].iter_mut() {
                    if *v == b {
                        *v = a;
                    }
                }
            }
            dead_triangle[t0] = true;
            dead_triangle[t1] = true;
            dead_vertex[b as usize] = true;
            for v in ring_a.iter().chain(&ring_b).chain([&a, &b]) {
                frozen[*v as usize] = true;
            }
            done += 1;
        }
        // Compact: drop dead triangles and vertices, renumber.
        let mut remap = vec![u32::MAX; n];
        let mut positions = Vec::with_capacity(n - done);
        for v in 0..n {
            if !dead_vertex[v] {
                remap[v] = positions.len() as u32;
                positions.push(mesh.positions[v]);
            }
        }
        mesh.triangles = mesh
            .triangles
            .iter()
            .enumerate()
            .filter(|(t, _)| !dead_triangle[*t])
            .map(|(_, tri)| tri.map(|v| remap[v as usize]))
            .collect();
        mesh.positions = positions;
    }
}

/// Moves each vertex toward the area-weighted centroid of its triangles, in the tangent
/// plane, then back toward the surface with one Newton step that reuses the gradient.
fn smooth_tangentially(mesh: &mut TriMesh, shape: &OrganShape, h: f64, step: f64) {
    let n = mesh.positions.len();
    let mut weighted = vec![Vec3::zeros(); n];
    let mut weight = vec![0.0; n];
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.corners(t);
        let area = 0.5 * (b - a).cross(&(c - a)).norm();
        let centroid = (a + b + c) / 3.0;
        for &v in &mesh.triangles[t] {
            weighted[v as usize] += centroid * area;
            weight[v as usize] += area;
        }
    }
    for v in 0..n {
        if weight[v] <= 0.0 {
            continue;
        }
        let p = mesh.positions[v];
        let g = shape.gradient(&p, h);
        let gg = g.norm_squared();
        if gg <= 0.0 {
            continue;
        }
        let mut delta = weighted[v] / weight[v] - p;
        delta -= g * (g.dot(&delta) / gg);
        let moved = p + delta * step;
        mesh.positions[v] = moved - g * (shape.value(&moved) / gg);
    }
}

/// Newton steps along the gradient onto the zero set.
fn project(shape: &OrganShape, mut p: Vec3, h: f64) -> Vec3 {
    for _ in 0..3 {
        let f = shape.value(&p);
        let g = shape.gradient(&p, h);
        let gg = g.norm_squared();
        if gg <= 0.0 {
            break;
        }
        p -= g * (f / gg);
    }
    p
}

/// Flips every edge whose opposite angles sum to more than π (the Delaunay criterion), as
/// long as the flip keeps valences ≥ 3 and both new triangles facing outward.
fn delaunay_flips(mesh: &mut TriMesh, shape: &OrganShape, h: f64) {
    for _pass in 0..10 {
        let table = EdgeTable::build(&mesh.triangles);
        let mut valence = vec![0u32; mesh.positions.len()];
        for e in &table.edges {
            valence[e[0] as usize] += 1;
            valence[e[1] as usize] += 1;
        }
        let mut touched = vec![false; mesh.triangles.len()];
        let mut created: Vec<[u32; 2]> = Vec::new();
        let mut flips = 0;
        for e in 0..table.len() {
            let &[u, w] = table.uses_of(e) else { continue };
            let (t0, t1) = (u.triangle as usize, w.triangle as usize);
            if touched[t0] || touched[t1] {
                continue;
            }
            let [p, q] = table.edges[e];
            let opposite = |t: usize| {
                mesh.triangles[t]
                    .iter()
                    .copied()
                    .find(|&v| v != p && v != q)
                    .expect("a triangle has a vertex off each of its edges")
            };
            let (r, s) = (opposite(t0), opposite(t1));
            let pos = |v: u32| mesh.positions[v as usize];
            let angle = |apex: u32| {
                let (a, b) = (pos(p) - pos(apex), pos(q) - pos(apex));
                a.cross(&b).norm().atan2(a.dot(&b))
            };
            if angle(r) + angle(s) <= std::f64::consts::PI + 1e-9 {
                continue;
            }
            let key = [r.min(s), r.max(s)];
            if valence[p as usize] <= 3
                || valence[q as usize] <= 3
                || table.find(r, s).is_some()
                || created.contains(&key)
            {
                continue;
            }
            // Keep the winding of t0: find the direction in which t0 traverses p→q.
            let tri0 = mesh.triangles[t0];
            let k = (0..3).find(|&k| tri0[k] == p).expect("p is a corner of t0");
            let (a, b) = if tri0[(k + 1) % 3] == q {
                (p, q)
            } else {
                (q, p)
            };
            // t0 = (a, b, r), t1 = (b, a, s)  →  (r, a, s), (s, b, r).
            let new0 = [r, a, s];
            let new1 = [s, b, r];
            let faces_out = |tri: [u32; 3]| {
                let [x, y, z] = [pos(tri[0]), pos(tri[1]), pos(tri[2])];
                let n = (y - x).cross(&(z - x));
                n.dot(&shape.gradient(&((x + y + z) / 3.0), h)) > 0.0
            };
            if !faces_out(new0) || !faces_out(new1) {
                continue;
            }
            mesh.triangles[t0] = new0;
            mesh.triangles[t1] = new1;
            touched[t0] = true;
            touched[t1] = true;
            created.push(key);
            valence[p as usize] -= 1;
            valence[q as usize] -= 1;
            valence[r as usize] += 1;
            valence[s as usize] += 1;
            flips += 1;
        }
        if flips == 0 {
            return;
        }
    }
}
