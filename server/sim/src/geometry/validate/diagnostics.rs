//! What validation says about a mesh: the repairs it made (warnings) and why it rejected
//! one (errors), each naming the source and the element.

use std::fmt;

use serde::Serialize;
use thiserror::Error;

use crate::geometry::remesh::RemeshReport;
use crate::math::Vec3;

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
