//! OBJ through the `tobj` crate. tobj's errors carry no position, so when it fails a short
//! scan of the text finds the offending line for the message.

use std::io::Cursor;

use super::{ImportContext, positions_from_flat};
use crate::geometry::TriMesh;
use crate::geometry::import::MeshImportError;

pub(super) fn read(bytes: &[u8], ctx: &ImportContext<'_>) -> Result<TriMesh, MeshImportError> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let line = bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1;
        ctx.parse(
            Some(line),
            "not a text file (invalid UTF-8); is this really an OBJ file?",
        )
    })?;
    // Cap the element counts before tobj allocates for them.
    let (vertex_lines, face_lines) = text.lines().fold((0u64, 0u64), |(v, f), l| {
        let l = l.trim_start();
        (
            v + u64::from(l.starts_with("v ") || l.starts_with("v\t")),
            f + u64::from(l.starts_with("f ") || l.starts_with("f\t")),
        )
    });
    ctx.check_vertex_count(vertex_lines)?;
    ctx.check_face_count(face_lines)?;
    if let Some((line, vertex)) = first_non_finite_vertex(text) {
        return Err(MeshImportError::NonFiniteCoordinate {
            file: ctx.source.to_string(),
            line: Some(line),
            vertex,
        });
    }

    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, _materials) = tobj::load_obj_buf(&mut Cursor::new(bytes), &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| locate_error(text, e, ctx))?;

    // tobj renumbers vertices per object; concatenate the objects into one mesh.
    let mut mesh = TriMesh::default();
    for model in &models {
        let base = mesh.positions.len() as u32;
        mesh.positions
            .extend(positions_from_flat(model.mesh.positions.iter().copied()));
        mesh.triangles.extend(
            model
                .mesh
                .indices
                .chunks_exact(3)
                .map(|t| [base + t[0], base + t[1], base + t[2]]),
        );
    }
    Ok(mesh)
}

fn first_non_finite_vertex(text: &str) -> Option<(usize, usize)> {
    let mut vertex = 0;
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        let bad = words
            .take(3)
            .any(|w| w.parse::<f64>().is_ok_and(|x| !x.is_finite()));
        if bad {
            return Some((i + 1, vertex));
        }
        vertex += 1;
    }
    None
}

/// Turns a tobj error into one that names the line it most likely came from.
fn locate_error(text: &str, err: tobj::LoadError, ctx: &ImportContext<'_>) -> MeshImportError {
    use tobj::LoadError as E;
    let mut vertices = 0usize;
    let mut face = 0usize;
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let line_no = Some(i + 1);
        match words.next() {
            Some("v") => {
                let coords: Vec<&str> = words.collect();
                if matches!(err, E::PositionParseError)
                    && (coords.len() < 3
                        || coords.iter().take(3).any(|w| w.parse::<f64>().is_err()))
                {
                    return ctx.parse(
                        line_no,
                        format!(
                            "vertex {vertices}: expected three numbers, found {:?}",
                            line.trim()
                        ),
                    );
                }
                vertices += 1;
            }
            Some("f") => {
                let corners: Vec<&str> = words.collect();
                if corners.len() < 3 && matches!(err, E::FaceParseError | E::InvalidPolygon) {
                    return ctx.parse(
                        line_no,
                        format!("face {face} has fewer than three vertices"),
                    );
                }
                for c in &corners {
                    let first = c.split('/').next().unwrap_or("");
                    match first.parse::<i64>() {
                        Err(_) if matches!(err, E::FaceParseError | E::InvalidPolygon) => {
                            return ctx.parse(
                                line_no,
                                format!("face {face}: '{c}' is not a vertex index"),
                            );
                        }
                        Ok(index) => {
                            // OBJ indices are 1-based; negative ones count back from the last vertex.
                            let resolved = if index < 0 {
                                vertices as i64 + index
                            } else {
                                index - 1
                            };
                            if (resolved < 0 || resolved >= vertices as i64)
                                && matches!(err, E::FaceVertexOutOfBounds | E::FaceParseError)
                            {
                                return ctx.bad_index(line_no, face, index, vertices);
                            }
                        }
                        Err(_) => {}
                    }
                }
                face += 1;
            }
            _ => {}
        }
    }
    ctx.parse(None, format!("{err}"))
}
