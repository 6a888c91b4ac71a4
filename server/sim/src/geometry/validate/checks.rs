//! The checks and repairs [`validate`](super::validate) runs, in its order: indices and
//! coordinates, duplicate and unused vertices, closed and edge-manifold, orientation,
//! vertex-manifold, zero-area triangles, outward components, self-intersections.

use std::collections::HashMap;

use super::{MeshValidationError, MeshWarning, Position};
use crate::geometry::TriMesh;
use crate::geometry::parry_adapter::TriangleBvh;
use crate::geometry::predicates::{disjoint_triangles_intersect, segment_crosses_triangle};
use crate::geometry::topology::{EdgeTable, triangle_neighbours};
use crate::math::Vec3;

pub(super) fn check_indices_and_coordinates(
    mesh: &TriMesh,
    source: &str,
) -> Result<(), MeshValidationError> {
    let n = mesh.positions.len();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if let Some(&bad) = tri.iter().find(|&&i| i as usize >= n) {
            return Err(MeshValidationError::IndexOutOfRange {
                file: source.to_string(),
                triangle: t,
                index: bad,
                vertices: n,
            });
        }
    }
    if let Some((v, p)) = mesh
        .positions
        .iter()
        .enumerate()
        .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
    {
        return Err(MeshValidationError::NonFiniteVertex {
            file: source.to_string(),
            vertex: v,
            position: format!("({}, {}, {})", p.x, p.y, p.z),
        });
    }
    Ok(())
}

/// Merges vertices closer than 1e-9 of the bounding-box diagonal; returns how many were merged.
pub(super) fn merge_duplicate_vertices(mesh: &mut TriMesh) -> usize {
    let tol = (mesh.bbox().diagonal() * 1e-9).max(f64::MIN_POSITIVE);
    let cell = |p: &Vec3| {
        [
            (p.x / tol).floor() as i64,
            (p.y / tol).floor() as i64,
            (p.z / tol).floor() as i64,
        ]
    };
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    let mut remap = vec![0u32; mesh.positions.len()];
    let mut kept: Vec<Vec3> = Vec::with_capacity(mesh.positions.len());
    for (i, p) in mesh.positions.iter().enumerate() {
        let c = cell(p);
        let mut found = None;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = grid.get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                        && let Some(&k) =
                            list.iter().find(|&&k| (kept[k as usize] - p).norm() <= tol)
                    {
                        found = Some(k);
                        break 'search;
                    }
                }
            }
        }
        remap[i] = match found {
            Some(k) => k,
            None => {
                let k = kept.len() as u32;
                kept.push(*p);
                grid.entry(c).or_default().push(k);
                k
            }
        };
    }
    let merged = mesh.positions.len() - kept.len();
    for t in &mut mesh.triangles {
        for v in t.iter_mut() {
            *v = remap[*v as usize];
        }
    }
    mesh.positions = kept;
    merged
}

pub(super) fn drop_unused_vertices(mesh: &mut TriMesh) -> usize {
    let mut used = vec![false; mesh.positions.len()];
    for t in &mesh.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let unused = used.iter().filter(|u| !**u).count();
    if unused == 0 {
        return 0;
    }
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    let mut kept = Vec::with_capacity(mesh.positions.len() - unused);
    for (i, p) in mesh.positions.iter().enumerate() {
        if used[i] {
            remap[i] = kept.len() as u32;
            kept.push(*p);
        }
    }
    for t in &mut mesh.triangles {
        for v in t.iter_mut() {
            *v = remap[*v as usize];
        }
    }
    mesh.positions = kept;
    unused
}

pub(super) fn check_closed_and_edge_manifold(
    mesh: &TriMesh,
    source: &str,
) -> Result<(), MeshValidationError> {
    let table = EdgeTable::build(&mesh.triangles);
    let mut boundary = 0;
    let mut first_boundary = None;
    for e in 0..table.len() {
        let uses = table.uses_of(e);
        let [a, b] = table.edges[e];
        let pos = |v: u32| Position(mesh.positions[v as usize]);
        if uses.len() > 2 {
            return Err(MeshValidationError::NonManifoldEdge {
                file: source.to_string(),
                a: pos(a),
                b: pos(b),
                triangles: uses.len(),
                first: uses[0].triangle as usize,
            });
        }
        if uses.len() == 1 {
            boundary += 1;
            first_boundary.get_or_insert((a, b, uses[0].triangle));
        }
    }
    if let Some((a, b, t)) = first_boundary {
        return Err(MeshValidationError::OpenBoundary {
            file: source.to_string(),
            count: boundary,
            a: Position(mesh.positions[a as usize]),
            b: Position(mesh.positions[b as usize]),
            triangle: t as usize,
        });
    }
    Ok(())
}

/// Makes every pair of neighbouring triangles traverse their shared edge in opposite
/// directions, flipping the smaller part of each component. Returns each triangle's
/// component number and how many triangles were flipped.
pub(super) fn orient_consistently(
    mesh: &mut TriMesh,
    source: &str,
) -> Result<(Vec<u32>, usize), MeshValidationError> {
    let table = EdgeTable::build(&mesh.triangles);
    let nb = triangle_neighbours(&mesh.triangles, &table);
    let n = mesh.triangles.len();
    let mut component = vec![u32::MAX; n];
    let mut flip = vec![false; n];
    let mut flipped_total = 0;
    let mut stack = Vec::new();
    let mut members = Vec::new();
    let mut next_component = 0;
    // Whether triangles t and u traverse their shared edge in the same direction.
    let same_direction = |t: usize, u: usize, tris: &[[u32; 3]]| {
        let a = tris[t];
        let b = tris[u];
        (0..3).any(|i| {
            let (x, y) = (a[i], a[(i + 1) % 3]);
            (0..3).any(|j| b[j] == x && b[(j + 1) % 3] == y)
        })
    };
    for seed in 0..n {
        if component[seed] != u32::MAX {
            continue;
        }
        members.clear();
        component[seed] = next_component;
        stack.push(seed);
        while let Some(t) = stack.pop() {
            members.push(t);
            for &u in &nb[t] {
                let u = u as usize;
                let want = flip[t] ^ same_direction(t, u, &mesh.triangles);
                if component[u] == u32::MAX {
                    component[u] = next_component;
                    flip[u] = want;
                    stack.push(u);
                } else if flip[u] != want {
                    return Err(MeshValidationError::NonOrientable {
                        file: source.to_string(),
                        triangle: u,
                    });
                }
            }
        }
        let flipped = members.iter().filter(|&&t| flip[t]).count();
        // Keep the majority's winding: repairs should touch as few triangles as possible.
        if 2 * flipped > members.len() {
            for &t in &members {
                flip[t] = !flip[t];
            }
        }
        flipped_total += members.iter().filter(|&&t| flip[t]).count();
        next_component += 1;
    }
    for (t, tri) in mesh.triangles.iter_mut().enumerate() {
        if flip[t] {
            tri.swap(1, 2);
        }
    }
    Ok((component, flipped_total))
}

pub(super) fn check_vertex_manifold(
    mesh: &TriMesh,
    source: &str,
) -> Result<(), MeshValidationError> {
    // Around a manifold vertex v, the triangles (v, a, b) chain a → b into a single cycle.
    let mut fans: Vec<Vec<(u32, u32)>> = vec![Vec::new(); mesh.positions.len()];
    for tri in &mesh.triangles {
        for k in 0..3 {
            fans[tri[k] as usize].push((tri[(k + 1) % 3], tri[(k + 2) % 3]));
        }
    }
    for (v, fan) in fans.iter().enumerate() {
        let Some(&(start, _)) = fan.first() else {
            continue;
        };
        let mut steps = 0;
        let mut at = start;
        while let Some(&(_, next)) = fan.iter().find(|(a, _)| *a == at) {
            steps += 1;
            at = next;
            if at == start || steps > fan.len() {
                break;
            }
        }
        if steps != fan.len() {
            return Err(MeshValidationError::NonManifoldVertex {
                file: source.to_string(),
                vertex: v,
                position: Position(mesh.positions[v]),
            });
        }
    }
    Ok(())
}

/// Relative height below which a triangle counts as zero-area: 2·area / longest² < this.
pub(super) const ZERO_AREA_RATIO: f64 = 1e-10;

pub(super) fn is_zero_area(mesh: &TriMesh, t: usize) -> bool {
    let [a, b, c] = mesh.corners(t);
    let longest = (b - a)
        .norm_squared()
        .max((c - b).norm_squared())
        .max((a - c).norm_squared());
    mesh.doubled_area_normal(t).norm() <= ZERO_AREA_RATIO * longest
}

/// Removes zero-area triangles whose vertices are collinear by flipping the longest edge:
/// the middle vertex then splits the neighbour across that edge into two proper triangles.
pub(super) fn repair_zero_area_triangles(
    mesh: &mut TriMesh,
    source: &str,
) -> Result<usize, MeshValidationError> {
    let mut repaired = 0;
    for _pass in 0..8 {
        let bad: Vec<usize> = (0..mesh.triangles.len())
            .filter(|&t| is_zero_area(mesh, t))
            .collect();
        if bad.is_empty() {
            return Ok(repaired);
        }
        let table = EdgeTable::build(&mesh.triangles);
        let mut touched = vec![false; mesh.triangles.len()];
        let mut created: Vec<[u32; 2]> = Vec::new();
        let mut progress = false;
        for t in bad {
            if touched[t] {
                continue;
            }
            let tri = mesh.triangles[t];
            let [pa, pb, pc] = mesh.corners(t);
            let lens = [(pb - pa).norm(), (pc - pb).norm(), (pa - pc).norm()];
            let k = (0..3)
                .max_by(|&i, &j| lens[i].total_cmp(&lens[j]))
                .unwrap_or(0);
            // Edge p→q is the longest; r is the vertex lying on it.
            let (p, q, r) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
            let Some(e) = table.find(p, q) else { continue };
            let Some(other) = table
                .uses_of(e)
                .iter()
                .map(|u| u.triangle as usize)
                .find(|&u| u != t)
            else {
                continue;
            };
            if touched[other] {
                continue;
            }
            let o = mesh.triangles[other];
            let Some(s) = o.iter().copied().find(|&v| v != p && v != q) else {
                continue;
            };
            let new_edge = [r.min(s), r.max(s)];
            if table.find(r, s).is_some() || created.contains(&new_edge) {
                continue;
            }
            created.push(new_edge);
            mesh.triangles[t] = [r, p, s];
            mesh.triangles[other] = [s, q, r];
            touched[t] = true;
            touched[other] = true;
            repaired += 1;
            progress = true;
        }
        if !progress {
            break;
        }
    }
    if let Some(t) = (0..mesh.triangles.len()).find(|&t| is_zero_area(mesh, t)) {
        let [a, b, c] = mesh.corners(t);
        return Err(MeshValidationError::DegenerateTriangle {
            file: source.to_string(),
            triangle: t,
            position: Position((a + b + c) / 3.0),
        });
    }
    Ok(repaired)
}

pub(super) fn orient_components_outward(
    mesh: &mut TriMesh,
    component: &[u32],
    source: &str,
    warnings: &mut Vec<MeshWarning>,
) -> Result<usize, MeshValidationError> {
    let count = component.iter().map(|&c| c as usize + 1).max().unwrap_or(0);
    let mut volume = vec![0.0; count];
    let mut triangles = vec![0usize; count];
    let mut scale = vec![0.0f64; count];
    for (t, &c) in component.iter().enumerate() {
        let [a, b, cc] = mesh.corners(t);
        volume[c as usize] += a.dot(&b.cross(&cc)) / 6.0;
        triangles[c as usize] += 1;
        scale[c as usize] = scale[c as usize].max(a.norm()).max(b.norm()).max(cc.norm());
    }
    for c in 0..count {
        // A volume that is tiny against the component's extent means a flat or doubled sheet.
        if volume[c].abs() <= 1e-9 * scale[c].powi(3) {
            return Err(MeshValidationError::NoVolume {
                file: source.to_string(),
                component: c,
            });
        }
        if volume[c] < 0.0 {
            for (t, tri) in mesh.triangles.iter_mut().enumerate() {
                if component[t] as usize == c {
                    tri.swap(1, 2);
                }
            }
            warnings.push(MeshWarning::FlippedInvertedComponent {
                component: c,
                triangles: triangles[c],
            });
        }
    }
    Ok(count)
}

pub(super) fn check_self_intersections(
    mesh: &TriMesh,
    source: &str,
) -> Result<(), MeshValidationError> {
    let bvh = TriangleBvh::build(mesh);
    let mut count = 0;
    let mut first = None;
    for t in 0..mesh.triangles.len() {
        let tc = mesh.corners(t);
        let lo = tc[0].inf(&tc[1]).inf(&tc[2]);
        let hi = tc[0].sup(&tc[1]).sup(&tc[2]);
        let ti = mesh.triangles[t];
        bvh.for_each_overlapping(&lo, &hi, |u| {
            if u <= t {
                return;
            }
            let ui = mesh.triangles[u];
            let shared: Vec<u32> = ti.iter().copied().filter(|v| ui.contains(v)).collect();
            let uc = mesh.corners(u);
            let hit = match shared.len() {
                0 => disjoint_triangles_intersect(&tc, &uc),
                1 => {
                    // Sharing one vertex, they can only cross through an edge opposite it.
                    let opposite = |tri: [u32; 3], c: &[Vec3; 3]| {
                        let k = (0..3).find(|&k| tri[k] == shared[0]).unwrap_or(0);
                        (c[(k + 1) % 3], c[(k + 2) % 3])
                    };
                    let (a0, a1) = opposite(ti, &tc);
                    let (b0, b1) = opposite(ui, &uc);
                    segment_crosses_triangle(&a0, &a1, &uc)
                        || segment_crosses_triangle(&b0, &b1, &tc)
                }
                _ => false,
            };
            if hit {
                count += 1;
                first.get_or_insert((t, u));
            }
        });
    }
    if let Some((t, u)) = first {
        let c = mesh.corners(t);
        return Err(MeshValidationError::SelfIntersection {
            file: source.to_string(),
            count,
            first: t,
            second: u,
            position: Position((c[0] + c[1] + c[2]) / 3.0),
        });
    }
    Ok(())
}
