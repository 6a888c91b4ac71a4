//! STL through the `stl_io` crate, with the binary size checked first: a binary STL is
//! exactly 84 + 50·n bytes, which catches truncation and absurd counts before parsing.

use std::io::Cursor;

use super::ImportContext;
use crate::geometry::TriMesh;
use crate::geometry::import::MeshImportError;
use crate::math::Vec3;

const HEADER: usize = 84;
const RECORD: u64 = 50;

pub(super) fn read(bytes: &[u8], ctx: &ImportContext<'_>) -> Result<TriMesh, MeshImportError> {
    let announced = (bytes.len() >= HEADER)
        .then(|| u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64);
    let binary_size = announced.map(|n| HEADER as u64 + RECORD * n);
    let looks_ascii = bytes
        .iter()
        .skip_while(|b| b.is_ascii_whitespace())
        .take(5)
        .eq(b"solid".iter());
    // Some exporters write binary files whose 80-byte header starts with "solid"; the exact
    // size identifies those.
    let is_binary = binary_size == Some(bytes.len() as u64) || !looks_ascii;
    if is_binary {
        let Some(n) = announced else {
            return Err(ctx.truncated(HEADER as u64, bytes.len() as u64));
        };
        ctx.check_face_count(n)?;
        let expected = HEADER as u64 + RECORD * n;
        if expected != bytes.len() as u64 {
            return Err(ctx.truncated(expected, bytes.len() as u64));
        }
    }
    let indexed = stl_io::read_stl(&mut Cursor::new(bytes)).map_err(|e| {
        let what = if is_binary { "binary" } else { "ASCII" };
        ctx.parse(None, format!("cannot read as {what} STL: {e}"))
    })?;
    ctx.check_vertex_count(indexed.vertices.len() as u64)?;
    ctx.check_face_count(indexed.faces.len() as u64)?;
    let positions = indexed
        .vertices
        .iter()
        .map(|v| Vec3::new(v.0[0] as f64, v.0[1] as f64, v.0[2] as f64))
        .collect();
    let triangles = indexed
        .faces
        .iter()
        .map(|f| {
            [
                f.vertices[0] as u32,
                f.vertices[1] as u32,
                f.vertices[2] as u32,
            ]
        })
        .collect();
    Ok(TriMesh::new(positions, triangles))
}
