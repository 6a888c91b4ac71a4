//! PLY through the `ply-rs-bw` crate. The header is read first and its element counts are
//! checked against the caps and against the bytes present before the payload is parsed.

use std::io::Cursor;

use ply_rs_bw::parser::{ParseError, Parser, Reader};
use ply_rs_bw::ply::{DefaultElement, Encoding, Header, Property, PropertyType, ScalarType};

use super::{ImportContext, push_fan};
use crate::geometry::TriMesh;
use crate::geometry::import::MeshImportError;
use crate::math::Vec3;

pub(super) fn read(bytes: &[u8], ctx: &ImportContext<'_>) -> Result<TriMesh, MeshImportError> {
    let parser = Parser::<DefaultElement>::new();
    let mut reader = Reader::new(Cursor::new(bytes));
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| ply_error(ctx, &e))?;
    check_counts(bytes, &header, ctx)?;
    let payload = parser
        .read_payload(&mut reader, &header)
        .map_err(|e| ply_error(ctx, &e))?;

    let vertices = payload.get("vertex").ok_or_else(|| {
        ctx.parse(
            None,
            "no 'vertex' element; is this a point cloud or mesh PLY?",
        )
    })?;
    let mut positions = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let coord = |name: &str| {
            v.get(name).and_then(scalar).ok_or_else(|| {
                ctx.parse(None, format!("vertex {i} has no numeric '{name}' property"))
            })
        };
        positions.push(Vec3::new(coord("x")?, coord("y")?, coord("z")?));
    }
    let mut triangles = Vec::new();
    if let Some(faces) = payload.get("face") {
        let mut polygon = Vec::new();
        for (f, face) in faces.iter().enumerate() {
            let list = face
                .get("vertex_indices")
                .or_else(|| face.get("vertex_index"))
                .ok_or_else(|| ctx.parse(None, format!("face {f} has no 'vertex_indices' list")))?;
            polygon.clear();
            for index in list_values(list).ok_or_else(|| {
                ctx.parse(
                    None,
                    format!("face {f}: 'vertex_indices' is not an integer list"),
                )
            })? {
                if index < 0 || index as usize >= positions.len() {
                    return Err(ctx.bad_index(None, f, index, positions.len()));
                }
                polygon.push(index as u32);
            }
            push_fan(&polygon, &mut triangles);
        }
    }
    Ok(TriMesh::new(positions, triangles))
}

fn ply_error(ctx: &ImportContext<'_>, e: &ParseError) -> MeshImportError {
    let text = e.to_string();
    // The crate prefixes "Line N: " when it knows the line; we report the line separately.
    let message = match e.line() {
        Some(l) => text
            .strip_prefix(&format!("Line {l}: "))
            .unwrap_or(&text)
            .to_string(),
        None => text,
    };
    ctx.parse(e.line(), message)
}

fn scalar_size(t: &ScalarType) -> u64 {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// Rejects counts over the caps, and counts that cannot fit in the bytes after the header.
fn check_counts(
    bytes: &[u8],
    header: &Header,
    ctx: &ImportContext<'_>,
) -> Result<(), MeshImportError> {
    let body = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .map(|p| bytes.len() - p - 10)
        .unwrap_or(0) as u64;
    let mut needed: u64 = 0;
    for (name, element) in &header.elements {
        let count = element.count as u64;
        match name.as_str() {
            "vertex" => ctx.check_vertex_count(count)?,
            "face" => ctx.check_face_count(count)?,
            _ => {}
        }
        // Smallest possible encoding of one element: binary scalars at their size (a list at
        // least its length field), ASCII at least one digit and one separator per value.
        let per_element: u64 = element
            .properties
            .values()
            .map(|p| match (&header.encoding, &p.data_type) {
                (Encoding::Ascii, _) => 2,
                (_, PropertyType::Scalar(t)) => scalar_size(t),
                (_, PropertyType::List(len, _)) => scalar_size(len),
            })
            .sum();
        needed = needed.saturating_add(count.saturating_mul(per_element));
    }
    if needed > body {
        return Err(ctx.truncated(needed, body));
    }
    Ok(())
}

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => v as f64,
        Property::UChar(v) => v as f64,
        Property::Short(v) => v as f64,
        Property::UShort(v) => v as f64,
        Property::Int(v) => v as f64,
        Property::UInt(v) => v as f64,
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        _ => return None,
    })
}

fn list_values(p: &Property) -> Option<Vec<i64>> {
    Some(match p {
        Property::ListChar(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUChar(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListShort(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUShort(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListInt(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUInt(v) => v.iter().map(|&x| x as i64).collect(),
        _ => return None,
    })
}
