//! Mesh validation: everything built on a surface mesh assumes it is a closed, edge-manifold,
//! consistently outward-oriented surface with finite coordinates and no degenerate or
//! intersecting triangles. This module checks that, repairs what is safe to repair (with a
//! warning), and otherwise rejects the mesh with an error that names the element and what to do.

use serde::Serialize;

use crate::geometry::TriMesh;
use crate::math::Aabb;

mod checks;
mod diagnostics;

use checks::{
    check_closed_and_edge_manifold, check_indices_and_coordinates, check_self_intersections,
    check_vertex_manifold, drop_unused_vertices, merge_duplicate_vertices,
    orient_components_outward, orient_consistently, repair_zero_area_triangles,
};
pub use diagnostics::{MeshValidationError, MeshWarning, Position};

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
