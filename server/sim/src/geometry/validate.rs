//! Mesh validation: everything built on a surface mesh assumes it is a closed, edge-manifold,
//! consistently outward-oriented surface with finite coordinates and no degenerate or
//! intersecting triangles. This module checks that, repairs what is safe to repair (with a
//! warning), and otherwise rejects the mesh with an error that names the element and what to do.

use std::collections::HashMap;
use std::fmt;

use serde::Serialize;
use thiserror::Error;

use crate::geometry::TriMesh;
use crate::geometry::parry_adapter::TriangleBvh;
use crate::geometry::predicates::{disjoint_triangles_intersect, segment_crosses_triangle};
use crate::geometry::remesh::RemeshReport;
use crate::geometry::topology::{EdgeTable, triangle_neighbours};
use crate::math::{Aabb, Vec3};

/// Limits and switches for [`validate`].
#[derive(Debug, Clone, PartialEq)]
pub struct ValidationOptions {
    /// Largest accepted triangle count.
    pub max_triangles: usize,
    /// Whether to search for intersecting triangle pairs (O(n log n)).
    pub check_self_intersections: bool,
}

impl Default for ValidationOptions {
    fn default() -> Self {
        Self {
            max_triangles: 2_000_000,
            check_self_intersections: true,
        }
    }
}

/// A repair or observation made while validating; the mesh was accepted.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[non_exhaustive]
pub enum MeshWarning {
    /// Vertices closer than the merge tolerance were merged into one.
    MergedDuplicateVertices {
        /// How many vertices were merged away.
        count: usize,
    },
    /// Vertices used by no triangle were dropped.
    DroppedUnusedVertices {
        /// How many.
        count: usize,
    },
    /// Triangles that repeated a vertex (after merging) were removed.
    RemovedCollapsedTriangles {
        /// How many.
        count: usize,
    },
    /// Zero-area triangles (three collinear vertices) were removed by flipping their longest edge.
    RepairedZeroAreaTriangles {
        /// How many.
        count: usize,
    },
    /// Triangles wound against their neighbours were flipped to agree with them.
    ReorientedTriangles {
        /// How many.
        count: usize,
    },
    /// A whole component was wound inward (negative volume) and was flipped to face outward.
    FlippedInvertedComponent {
        /// Component number.
        component: usize,
        /// Its triangle count.
        triangles: usize,
    },
    /// The mesh has several closed components.
    SeveralComponents {
        /// How many.
        count: usize,
    },
    /// The mesh is implausibly large or small for an organ; the units are probably wrong.
    SuspiciousSize {
        /// Bounding-box diagonal in metres.
        diagonal_m: f64,
    },
    /// The surface was remeshed to even triangles ([`crate::geometry::remesh`]).
    Remeshed(RemeshReport),
    /// Remeshing was due but not applied (too many triangles, or its surface failed
    /// validation or needed a repair); the mesh was kept.
    RemeshRefused {
        /// The edge length asked for (m).
        target_edge_m: f64,
        /// Why the remeshed surface was rejected.
        reason: String,
    },
}

impl MeshWarning {
    /// Whether the mesh was changed to mend it (rather than observed, or remeshed).
    pub fn is_repair(&self) -> bool {
        match self {
            Self::MergedDuplicateVertices { .. }
            | Self::DroppedUnusedVertices { .. }
            | Self::RemovedCollapsedTriangles { .. }
            | Self::RepairedZeroAreaTriangles { .. }
            | Self::ReorientedTriangles { .. }
            | Self::FlippedInvertedComponent { .. } => true,
            Self::SeveralComponents { .. }
            | Self::SuspiciousSize { .. }
            | Self::Remeshed(_)
            | Self::RemeshRefused { .. } => false,
        }
    }
}

impl fmt::Display for MeshWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::MergedDuplicateVertices { count } => {
                write!(f, "merged {count} duplicate vertices")
            }
            Self::DroppedUnusedVertices { count } => {
                write!(f, "dropped {count} vertices that no triangle uses")
            }
            Self::RemovedCollapsedTriangles { count } => write!(
                f,
                "removed {count} triangles with a repeated vertex (collapsed edges)"
            ),
            Self::RepairedZeroAreaTriangles { count } => write!(
                f,
                "repaired {count} zero-area triangles by flipping their longest edge"
            ),
            Self::ReorientedTriangles { count } => write!(
                f,
                "flipped {count} triangles whose winding disagreed with their neighbours"
            ),
            Self::FlippedInvertedComponent {
                component,
                triangles,
            } => write!(
                f,
                "component {component} ({triangles} triangles) was inside-out; flipped it to face outward"
            ),
            Self::SeveralComponents { count } => write!(
                f,
                "the mesh has {count} separate closed components; each is simulated as tissue"
            ),
            Self::SuspiciousSize { diagonal_m } => write!(
                f,
                "the mesh is {:.4} m across; if that is not the organ's size, set the units (m, cm, mm)",
                diagonal_m
            ),
            Self::Remeshed(r) => write!(
                f,
                "remeshed to {:.2} mm edges (mesh.remesh; \"off\" keeps the triangles as they \
                 are): {} → {} triangles, smallest angle {:.1}° → {:.1}°, {} → {} triangles under \
                 15°, the two surfaces within {:.2} mm of each other, volume {:+.2} %",
                r.target_edge_m * 1e3,
                r.triangles_before,
                r.triangles_after,
                r.min_angle_before_deg,
                r.min_angle_after_deg,
                r.under_15_before,
                r.under_15_after,
                r.max_deviation_m * 1e3,
                100.0 * r.volume_change
            ),
            Self::RemeshRefused {
                target_edge_m,
                reason,
            } => write!(
                f,
                "remeshing to {:.2} mm edges was not applied, the mesh is used as it is: {reason}",
                target_edge_m * 1e3
            ),
        }
    }
}

/// Why a mesh was rejected. Every variant names the source and the offending element.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum MeshValidationError {
    /// No triangles at all.
    #[error("{file}: the mesh has no triangles; export the organ's surface, not just its points")]
    Empty {
        /// File or scene name.
        file: String,
    },
    /// More triangles than the configured cap.
    #[error(
        "{file}: {count} triangles exceed the limit of {limit}; decimate the mesh (e.g. MeshLab 'Quadric Edge Collapse Decimation') or raise mesh.max_triangles"
    )]
    TooManyTriangles {
        /// File or scene name.
        file: String,
        /// Triangles found.
        count: usize,
        /// The cap.
        limit: usize,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error(
        "{file}: triangle {triangle} refers to vertex {index}, but there are only {vertices} vertices; the file is corrupt"
    )]
    IndexOutOfRange {
        /// File or scene name.
        file: String,
        /// Triangle index (0-based, file order).
        triangle: usize,
        /// The bad vertex index.
        index: u32,
        /// Number of vertices.
        vertices: usize,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{file}: vertex {vertex} has a non-finite coordinate {position}; fix or remove it")]
    NonFiniteVertex {
        /// File or scene name.
        file: String,
        /// Vertex index (0-based).
        vertex: usize,
        /// The coordinates as read.
        position: String,
    },
    /// An edge used by only one triangle: the surface has a hole.
    #[error(
        "{file}: the mesh is not closed: {count} edges have only one triangle, e.g. the edge {a}–{b} of triangle {triangle}; fill the holes (e.g. MeshLab 'Close Holes') and export again"
    )]
    OpenBoundary {
        /// File or scene name.
        file: String,
        /// Number of boundary edges.
        count: usize,
        /// First boundary edge, as positions.
        a: Position,
        /// Second end of that edge.
        b: Position,
        /// Triangle owning the edge (0-based).
        triangle: usize,
    },
    /// An edge shared by more than two triangles.
    #[error(
        "{file}: the mesh is not edge-manifold: the edge {a}–{b} is shared by {triangles} triangles (first: {first}); remove the extra or duplicate faces"
    )]
    NonManifoldEdge {
        /// File or scene name.
        file: String,
        /// First end of the edge.
        a: Position,
        /// Second end.
        b: Position,
        /// How many triangles share it.
        triangles: usize,
        /// One of them (0-based).
        first: usize,
    },
    /// Triangle fans touching at a single vertex (an "hourglass" vertex).
    #[error(
        "{file}: vertex {vertex} at {position} joins separate sheets of triangles (non-manifold vertex); split or weld the surface there"
    )]
    NonManifoldVertex {
        /// File or scene name.
        file: String,
        /// Vertex index after merging duplicates.
        vertex: usize,
        /// Its position.
        position: Position,
    },
    /// No consistent winding exists (a Möbius-like surface).
    #[error(
        "{file}: the surface cannot be oriented consistently (around triangle {triangle}); it is not the boundary of a solid"
    )]
    NonOrientable {
        /// File or scene name.
        file: String,
        /// Triangle where the conflict was found.
        triangle: usize,
    },
    /// A closed component that encloses no volume.
    #[error(
        "{file}: component {component} encloses no volume (a flat or doubled sheet); export a solid surface"
    )]
    NoVolume {
        /// File or scene name.
        file: String,
        /// Component number.
        component: usize,
    },
    /// A zero-area triangle that could not be repaired by an edge flip.
    #[error(
        "{file}: triangle {triangle} at {position} has zero area and cannot be repaired; clean the mesh (e.g. MeshLab 'Remove Zero Area Faces')"
    )]
    DegenerateTriangle {
        /// File or scene name.
        file: String,
        /// Triangle index after repairs.
        triangle: usize,
        /// Its centroid.
        position: Position,
    },
    /// Two triangles cross each other.
    #[error(
        "{file}: the surface intersects itself: {count} triangle pairs cross, e.g. triangles {first} and {second} near {position}; repair it (e.g. MeshLab 'Select Self Intersecting Faces', then remesh)"
    )]
    SelfIntersection {
        /// File or scene name.
        file: String,
        /// Number of crossing pairs.
        count: usize,
        /// One triangle of the first pair.
        first: usize,
        /// The other.
        second: usize,
        /// Near where.
        position: Position,
    },
}

/// A position for messages, printed in millimetres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Position(pub Vec3);

impl fmt::Display for Position {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let p = self.0 * 1000.0;
        write!(f, "({:.3}, {:.3}, {:.3}) mm", p.x, p.y, p.z)
    }
}

/// Measures of an accepted mesh.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MeshStats {
    /// Vertex count.
    pub vertices: usize,
    /// Triangle count.
    pub triangles: usize,
    /// Closed components.
    pub components: usize,
    /// Enclosed volume (m³).
    pub volume_m3: f64,
    /// Surface area (m²).
    pub area_m2: f64,
    /// Bounding box (m).
    pub bbox: Aabb,
    /// Smallest triangle angle (degrees).
    pub min_angle_deg: f64,
    /// Mean edge length (m).
    pub mean_edge_m: f64,
}

/// A mesh that passed validation, with the repairs made and its measures.
#[derive(Debug, Clone)]
pub struct ValidatedMesh {
    /// The closed, manifold, outward-oriented mesh.
    pub mesh: TriMesh,
    /// Repairs and observations.
    pub warnings: Vec<MeshWarning>,
    /// Measures.
    pub stats: MeshStats,
}

/// Validates `mesh` (named `source` in messages), repairing what is safe to repair.
pub fn validate(
    mut mesh: TriMesh,
    source: &str,
    options: &ValidationOptions,
) -> Result<ValidatedMesh, MeshValidationError> {
    let src = || source.to_string();
    let mut warnings = Vec::new();

    if mesh.triangles.is_empty() {
        return Err(MeshValidationError::Empty { file: src() });
    }
    if mesh.triangles.len() > options.max_triangles {
        return Err(MeshValidationError::TooManyTriangles {
            file: src(),
            count: mesh.triangles.len(),
            limit: options.max_triangles,
        });
    }
    check_indices_and_coordinates(&mesh, source)?;

    let merged = merge_duplicate_vertices(&mut mesh);
    if merged > 0 {
        warnings.push(MeshWarning::MergedDuplicateVertices { count: merged });
    }
    let before = mesh.triangles.len();
    mesh.triangles
        .retain(|t| t[0] != t[1] && t[1] != t[2] && t[2] != t[0]);
    if mesh.triangles.len() < before {
        warnings.push(MeshWarning::RemovedCollapsedTriangles {
            count: before - mesh.triangles.len(),
        });
    }
    if mesh.triangles.is_empty() {
        return Err(MeshValidationError::Empty { file: src() });
    }
    let unused = drop_unused_vertices(&mut mesh);
    if unused > 0 {
        warnings.push(MeshWarning::DroppedUnusedVertices { count: unused });
    }

    check_closed_and_edge_manifold(&mesh, source)?;
    let (component, reoriented) = orient_consistently(&mut mesh, source)?;
    if reoriented > 0 {
        warnings.push(MeshWarning::ReorientedTriangles { count: reoriented });
    }
    check_vertex_manifold(&mesh, source)?;

    let repaired = repair_zero_area_triangles(&mut mesh, source)?;
    if repaired > 0 {
        warnings.push(MeshWarning::RepairedZeroAreaTriangles { count: repaired });
    }

    let components = orient_components_outward(&mut mesh, &component, source, &mut warnings)?;
    if components > 1 {
        warnings.push(MeshWarning::SeveralComponents { count: components });
    }
    if options.check_self_intersections {
        check_self_intersections(&mesh, source)?;
    }

    let bbox = mesh.bbox();
    let diagonal_m = bbox.diagonal();
    if !(0.002..=2.0).contains(&diagonal_m) {
        warnings.push(MeshWarning::SuspiciousSize { diagonal_m });
    }
    let stats = MeshStats {
        vertices: mesh.positions.len(),
        triangles: mesh.triangles.len(),
        components,
        volume_m3: mesh.signed_volume(),
        area_m2: mesh.area(),
        bbox,
        min_angle_deg: mesh.min_angle_deg(),
        mean_edge_m: mesh.mean_edge_length(),
    };
    Ok(ValidatedMesh {
        mesh,
        warnings,
        stats,
    })
}

fn check_indices_and_coordinates(mesh: &TriMesh, source: &str) -> Result<(), MeshValidationError> {
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
fn merge_duplicate_vertices(mesh: &mut TriMesh) -> usize {
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

fn drop_unused_vertices(mesh: &mut TriMesh) -> usize {
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

fn check_closed_and_edge_manifold(mesh: &TriMesh, source: &str) -> Result<(), MeshValidationError> {
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
fn orient_consistently(
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

fn check_vertex_manifold(mesh: &TriMesh, source: &str) -> Result<(), MeshValidationError> {
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
const ZERO_AREA_RATIO: f64 = 1e-10;

fn is_zero_area(mesh: &TriMesh, t: usize) -> bool {
    let [a, b, c] = mesh.corners(t);
    let longest = (b - a)
        .norm_squared()
        .max((c - b).norm_squared())
        .max((a - c).norm_squared());
    mesh.doubled_area_normal(t).norm() <= ZERO_AREA_RATIO * longest
}

/// Removes zero-area triangles whose vertices are collinear by flipping the longest edge:
/// the middle vertex then splits the neighbour across that edge into two proper triangles.
fn repair_zero_area_triangles(
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

fn orient_components_outward(
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

fn check_self_intersections(mesh: &TriMesh, source: &str) -> Result<(), MeshValidationError> {
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
