//! Surface geometry: the triangle mesh, import from files, validation, and the procedural
//! organs used by the built-in scenes.

pub mod halfedge;
pub mod import;
mod mesh;
pub mod organs;
pub mod parry_adapter;
pub mod predicates;
pub mod remesh;
pub mod topology;
pub mod validate;

pub use import::{ImportLimits, LengthUnit, MeshFormat, MeshImportError, import_mesh};
pub use mesh::{TriMesh, angle_deg, triangle_angles_deg, triangle_min_angle_deg};
pub use validate::{
    MeshStats, MeshValidationError, MeshWarning, ValidatedMesh, ValidationOptions, validate,
};
