//! Mesh import from bytes: OBJ, STL (ASCII and binary), PLY (ASCII and binary) and legacy
//! VTK (POLYDATA, and UNSTRUCTURED_GRID volume cells reduced to their boundary surface).
//!
//! Sans-IO: callers read the file and hand over its bytes with a name for messages.
//! Every count in a header is checked against [`ImportLimits`] and against the number of
//! bytes actually present before anything is allocated for it.

mod obj;
mod ply;
mod stl;
mod vtk;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::geometry::TriMesh;
use crate::math::Vec3;

/// Supported mesh file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// Wavefront OBJ (polygons are triangulated).
    Obj,
    /// STL, ASCII or binary.
    Stl,
    /// Stanford PLY, ASCII or binary.
    Ply,
    /// Legacy VTK (`.vtk`), POLYDATA or UNSTRUCTURED_GRID.
    Vtk,
}

impl MeshFormat {
    /// File extensions accepted, lower case.
    pub const EXTENSIONS: [&'static str; 4] = ["obj", "stl", "ply", "vtk"];

    /// The format for a file name, from its extension (case-insensitive).
    pub fn from_file_name(name: &str) -> Result<Self, MeshImportError> {
        let ext = std::path::Path::new(name)
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        match ext.as_str() {
            "obj" => Ok(Self::Obj),
            "stl" => Ok(Self::Stl),
            "ply" => Ok(Self::Ply),
            "vtk" => Ok(Self::Vtk),
            _ => Err(MeshImportError::UnsupportedExtension {
                file: name.to_string(),
                extension: ext,
            }),
        }
    }

    /// Short upper-case name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Self::Obj => "OBJ",
            Self::Stl => "STL",
            Self::Ply => "PLY",
            Self::Vtk => "VTK",
        }
    }
}

/// Length unit of the coordinates in a mesh file. Import converts to metres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LengthUnit {
    /// Metres.
    #[default]
    M,
    /// Centimetres.
    Cm,
    /// Millimetres.
    Mm,
}

impl LengthUnit {
    /// Metres per unit.
    pub fn to_metres(self) -> f64 {
        match self {
            Self::M => 1.0,
            Self::Cm => 0.01,
            Self::Mm => 0.001,
        }
    }
}

/// Size caps applied before parsing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ImportLimits {
    /// Largest accepted file (bytes).
    pub max_file_bytes: u64,
    /// Largest accepted triangle count (after triangulating polygons or extracting a boundary).
    pub max_triangles: usize,
}

impl ImportLimits {
    /// Vertex cap implied by the triangle cap. A closed mesh has about half as many vertices
    /// as triangles; unshared STL-style vertices need three per triangle.
    pub fn max_vertices(&self) -> usize {
        self.max_triangles.saturating_mul(3).saturating_add(16)
    }
}

impl Default for ImportLimits {
    fn default() -> Self {
        Self {
            max_file_bytes: 256 << 20,
            max_triangles: 2_000_000,
        }
    }
}

/// Why a file could not be read as a mesh.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum MeshImportError {
    /// The extension is not one of the supported formats.
    #[error(
        "{file}: unsupported mesh format '.{extension}'; use .obj, .stl, .ply or .vtk (legacy), or convert the file (e.g. with MeshLab)"
    )]
    UnsupportedExtension {
        /// File name.
        file: String,
        /// The extension found (may be empty).
        extension: String,
    },
    /// The file is bigger than the configured cap.
    #[error(
        "{file}: file is {bytes} bytes, over the limit of {limit}; decimate the mesh or raise mesh.max_file_mb"
    )]
    FileTooLarge {
        /// File name.
        file: String,
        /// Its size.
        bytes: u64,
        /// The cap.
        limit: u64,
    },
    /// The file has no content.
    #[error("{file}: the file is empty")]
    EmptyFile {
        /// File name.
        file: String,
    },
    /// The content does not follow the format.
    #[error("{file}{}: {format}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Parse {
        /// File name.
        file: String,
        /// Format being read.
        format: &'static str,
        /// 1-based line, when known.
        line: Option<usize>,
        /// What was wrong.
        message: String,
    },
    /// A binary file ends before the data its header announces.
    #[error(
        "{file}: {format} file is truncated: its header announces {expected} bytes of data but the file has {actual}; the download or export was cut short"
    )]
    Truncated {
        /// File name.
        file: String,
        /// Format being read.
        format: &'static str,
        /// Bytes the header implies.
        expected: u64,
        /// Bytes present.
        actual: u64,
    },
    /// A header announces more elements than the caps allow.
    #[error(
        "{file}: {format} header announces {count} {what}, over the limit of {limit}; decimate the mesh or raise mesh.max_triangles"
    )]
    TooManyElements {
        /// File name.
        file: String,
        /// Format being read.
        format: &'static str,
        /// Which element ("vertices", "triangles", ...).
        what: &'static str,
        /// Count announced.
        count: u64,
        /// The cap.
        limit: u64,
    },
    /// A face refers to a vertex that does not exist.
    #[error(
        "{file}{}: face {face} refers to vertex {index}, but the file defines {vertices} vertices",
        line.map(|l| format!(":{l}")).unwrap_or_default()
    )]
    IndexOutOfRange {
        /// File name.
        file: String,
        /// 1-based line, when known.
        line: Option<usize>,
        /// Face number (0-based).
        face: usize,
        /// The index as written in the file.
        index: i64,
        /// Vertices defined.
        vertices: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error(
        "{file}{}: vertex {vertex} has a non-finite coordinate; fix the exporter or remove the vertex",
        line.map(|l| format!(":{l}")).unwrap_or_default()
    )]
    NonFiniteCoordinate {
        /// File name.
        file: String,
        /// 1-based line, when known.
        line: Option<usize>,
        /// Vertex number (0-based, file order).
        vertex: usize,
    },
    /// Valid file, but nothing in it this importer can turn into a surface.
    #[error("{file}: {message}")]
    Unsupported {
        /// File name.
        file: String,
        /// What is missing or unsupported, and what to do.
        message: String,
    },
}

/// Reads a mesh of `format` from `bytes`, converting coordinates from `unit` to metres.
/// `source` names the file in error messages.
pub fn import_mesh(
    bytes: &[u8],
    format: MeshFormat,
    source: &str,
    unit: LengthUnit,
    limits: &ImportLimits,
) -> Result<TriMesh, MeshImportError> {
    if bytes.len() as u64 > limits.max_file_bytes {
        return Err(MeshImportError::FileTooLarge {
            file: source.to_string(),
            bytes: bytes.len() as u64,
            limit: limits.max_file_bytes,
        });
    }
    if bytes.iter().all(u8::is_ascii_whitespace) {
        return Err(MeshImportError::EmptyFile {
            file: source.to_string(),
        });
    }
    let ctx = ImportContext {
        source,
        format: format.name(),
        limits,
    };
    let mut mesh = match format {
        MeshFormat::Obj => obj::read(bytes, &ctx)?,
        MeshFormat::Stl => stl::read(bytes, &ctx)?,
        MeshFormat::Ply => ply::read(bytes, &ctx)?,
        MeshFormat::Vtk => vtk::read(bytes, &ctx)?,
    };
    if mesh.triangles.len() > limits.max_triangles {
        return Err(ctx.too_many(
            "triangles",
            mesh.triangles.len() as u64,
            limits.max_triangles,
        ));
    }
    if mesh.triangles.is_empty() {
        return Err(MeshImportError::Unsupported {
            file: source.to_string(),
            message: format!(
                "the {} file contains no surface faces (only points or lines?); export the organ's surface",
                format.name()
            ),
        });
    }
    if let Some(v) = mesh
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(MeshImportError::NonFiniteCoordinate {
            file: source.to_string(),
            line: None,
            vertex: v,
        });
    }
    let k = unit.to_metres();
    if k != 1.0 {
        mesh.map_positions(|p| p * k);
    }
    Ok(mesh)
}

/// What every reader needs to report errors and apply caps.
struct ImportContext<'a> {
    source: &'a str,
    format: &'static str,
    limits: &'a ImportLimits,
}

impl ImportContext<'_> {
    fn parse(&self, line: Option<usize>, message: impl Into<String>) -> MeshImportError {
        MeshImportError::Parse {
            file: self.source.to_string(),
            format: self.format,
            line,
            message: message.into(),
        }
    }

    fn too_many(&self, what: &'static str, count: u64, limit: usize) -> MeshImportError {
        MeshImportError::TooManyElements {
            file: self.source.to_string(),
            format: self.format,
            what,
            count,
            limit: limit as u64,
        }
    }

    fn truncated(&self, expected: u64, actual: u64) -> MeshImportError {
        MeshImportError::Truncated {
            file: self.source.to_string(),
            format: self.format,
            expected,
            actual,
        }
    }

    fn bad_index(
        &self,
        line: Option<usize>,
        face: usize,
        index: i64,
        vertices: usize,
    ) -> MeshImportError {
        MeshImportError::IndexOutOfRange {
            file: self.source.to_string(),
            line,
            face,
            index,
            vertices,
        }
    }

    fn check_vertex_count(&self, count: u64) -> Result<(), MeshImportError> {
        if count > self.limits.max_vertices() as u64 {
            return Err(self.too_many("vertices", count, self.limits.max_vertices()));
        }
        Ok(())
    }

    fn check_face_count(&self, count: u64) -> Result<(), MeshImportError> {
        if count > self.limits.max_triangles as u64 {
            return Err(self.too_many("faces", count, self.limits.max_triangles));
        }
        Ok(())
    }
}

/// Triangulates a polygon as a fan from its first vertex, appending to `out`.
/// Fans are exact for the convex quads and polygons that mesh exporters write.
fn push_fan(polygon: &[u32], out: &mut Vec<[u32; 3]>) {
    for k in 1..polygon.len().saturating_sub(1) {
        out.push([polygon[0], polygon[k], polygon[k + 1]]);
    }
}

/// Positions from a flat `[x, y, z, x, y, z, ...]` buffer.
fn positions_from_flat(flat: impl IntoIterator<Item = f64>) -> Vec<Vec3> {
    let flat: Vec<f64> = flat.into_iter().collect();
    flat.chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extension_is_case_insensitive_and_checked() {
        assert_eq!(
            MeshFormat::from_file_name("a/B.STL").unwrap(),
            MeshFormat::Stl
        );
        assert!(matches!(
            MeshFormat::from_file_name("mesh.txt"),
            Err(MeshImportError::UnsupportedExtension { .. })
        ));
        assert!(matches!(
            MeshFormat::from_file_name("mesh"),
            Err(MeshImportError::UnsupportedExtension { .. })
        ));
    }

    #[test]
    fn fan_triangulates_quads_and_pentagons() {
        let mut out = Vec::new();
        push_fan(&[0, 1, 2, 3], &mut out);
        assert_eq!(out, vec![[0, 1, 2], [0, 2, 3]]);
        out.clear();
        push_fan(&[0, 1, 2, 3, 4], &mut out);
        assert_eq!(out.len(), 3);
    }
}
