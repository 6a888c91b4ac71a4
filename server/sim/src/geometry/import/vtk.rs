//! Legacy VTK reader (ASCII and BINARY; POLYDATA and UNSTRUCTURED_GRID).
//!
//! Hand-written because the available crate (vtkio 0.6) aborts the process on an absurd
//! POINTS count and reports errors without a position. This reader checks every count
//! against the caps and the bytes left before allocating, and names the line of any error.
//! Volume cells (tetrahedra, hexahedra, wedges, pyramids, voxels) are reduced to their
//! boundary surface: the faces used by exactly one cell, wound away from that cell.

use std::collections::HashMap;

use super::{ImportContext, push_fan};
use crate::geometry::TriMesh;
use crate::geometry::import::MeshImportError;
use crate::math::Vec3;

pub(super) fn read(bytes: &[u8], ctx: &ImportContext<'_>) -> Result<TriMesh, MeshImportError> {
    let mut c = Cursor {
        bytes,
        pos: 0,
        line: 1,
    };
    let (first, _) = c.next_line().unwrap_or(("", 1));
    if !first
        .trim_start()
        .to_ascii_lowercase()
        .starts_with("# vtk datafile version")
    {
        return Err(ctx.parse(
            Some(1),
            "not a legacy VTK file (first line must be '# vtk DataFile Version x.y'); XML .vtu/.vtp files are not supported, convert them with ParaView",
        ));
    }
    let _title = c.next_line();
    let (encoding, line) = c.next_line().unwrap_or(("", 3));
    let binary = match encoding.trim().to_ascii_uppercase().as_str() {
        "ASCII" => false,
        "BINARY" => true,
        other => {
            return Err(ctx.parse(
                Some(line),
                format!("expected ASCII or BINARY, found '{other}'"),
            ));
        }
    };
    let (kw, line) = c
        .token()
        .ok_or_else(|| ctx.parse(Some(c.line), "missing DATASET line"))?;
    if !kw.eq_ignore_ascii_case("DATASET") {
        return Err(ctx.parse(Some(line), format!("expected DATASET, found '{kw}'")));
    }
    let (kind, line) = c
        .token()
        .ok_or_else(|| ctx.parse(Some(c.line), "missing dataset type"))?;
    let kind = kind.to_ascii_uppercase();
    if kind != "POLYDATA" && kind != "UNSTRUCTURED_GRID" {
        return Err(MeshImportError::Unsupported {
            file: ctx.source.to_string(),
            message: format!(
                "line {line}: dataset {kind} has no surface to import; use POLYDATA or UNSTRUCTURED_GRID"
            ),
        });
    }

    let mut reader = SectionReader { c, ctx, binary };
    let mut points: Option<Vec<Vec3>> = None;
    let mut polygons: Vec<Vec<u32>> = Vec::new();
    let mut cells: Vec<Vec<u32>> = Vec::new();
    let mut cell_types: Vec<i64> = Vec::new();
    while let Some((kw, line)) = reader.c.token() {
        match kw.to_ascii_uppercase().as_str() {
            "POINTS" => {
                let n = reader.count(line)?;
                ctx.check_vertex_count(n)?;
                let dtype = reader.dtype(line)?;
                let flat = reader.numbers(3 * n, dtype, line)?;
                points = Some(
                    flat.chunks_exact(3)
                        .map(|v| Vec3::new(v[0], v[1], v[2]))
                        .collect(),
                );
            }
            "POLYGONS" => polygons.extend(reader.cell_lists(line)?),
            "TRIANGLE_STRIPS" => {
                for strip in reader.cell_lists(line)? {
                    for k in 0..strip.len().saturating_sub(2) {
                        // Every other triangle of a strip is wound backwards.
                        let t = if k % 2 == 0 {
                            vec![strip[k], strip[k + 1], strip[k + 2]]
                        } else {
                            vec![strip[k + 1], strip[k], strip[k + 2]]
                        };
                        polygons.push(t);
                    }
                }
            }
            "VERTICES" | "LINES" => {
                reader.cell_lists(line)?;
            }
            "CELLS" => cells = reader.cell_lists(line)?,
            "CELL_TYPES" => {
                let n = reader.count(line)?;
                ctx.check_face_count(n)?;
                cell_types = reader
                    .numbers(n, DataType::Int32, line)?
                    .into_iter()
                    .map(|v| v as i64)
                    .collect();
            }
            "METADATA" => reader.c.skip_block(),
            // Attributes follow the geometry; nothing after them is needed.
            "POINT_DATA" | "CELL_DATA" | "FIELD" => break,
            other => {
                return Err(ctx.parse(Some(line), format!("unexpected keyword '{other}'")));
            }
        }
    }
    let positions = points.ok_or_else(|| ctx.parse(None, "no POINTS section"))?;
    if !cells.is_empty() {
        if cell_types.len() != cells.len() {
            return Err(ctx.parse(
                None,
                format!("{} CELLS but {} CELL_TYPES", cells.len(), cell_types.len()),
            ));
        }
        polygons.extend(surface_of_cells(&positions, &cells, &cell_types, ctx)?);
    }
    let mut triangles = Vec::new();
    for (f, poly) in polygons.iter().enumerate() {
        if let Some(&bad) = poly.iter().find(|&&i| i as usize >= positions.len()) {
            return Err(ctx.bad_index(None, f, bad as i64, positions.len()));
        }
        push_fan(poly, &mut triangles);
    }
    Ok(TriMesh::new(positions, triangles))
}

/// Boundary faces of volume cells, or the 2D cells themselves when there are no volume cells.
fn surface_of_cells(
    positions: &[Vec3],
    cells: &[Vec<u32>],
    types: &[i64],
    ctx: &ImportContext<'_>,
) -> Result<Vec<Vec<u32>>, MeshImportError> {
    let faces_of = |t: i64| -> Option<&'static [&'static [usize]]> {
        Some(match t {
            10 => &[&[0, 1, 2], &[0, 1, 3], &[1, 2, 3], &[0, 2, 3]],
            11 => &[
                &[0, 1, 3, 2],
                &[4, 5, 7, 6],
                &[0, 1, 5, 4],
                &[2, 3, 7, 6],
                &[0, 2, 6, 4],
                &[1, 3, 7, 5],
            ],
            12 => &[
                &[0, 1, 2, 3],
                &[4, 5, 6, 7],
                &[0, 1, 5, 4],
                &[1, 2, 6, 5],
                &[2, 3, 7, 6],
                &[3, 0, 4, 7],
            ],
            13 => &[
                &[0, 1, 2],
                &[3, 4, 5],
                &[0, 1, 4, 3],
                &[1, 2, 5, 4],
                &[2, 0, 3, 5],
            ],
            14 => &[
                &[0, 1, 2, 3],
                &[0, 1, 4],
                &[1, 2, 4],
                &[2, 3, 4],
                &[3, 0, 4],
            ],
            _ => return None,
        })
    };
    let corner_counts = |t: i64| match t {
        10 => 4,
        11 | 12 => 8,
        13 => 6,
        14 => 5,
        _ => 0,
    };
    let has_volume = types.iter().any(|&t| faces_of(t).is_some());
    let mut out = Vec::new();
    if !has_volume {
        for (cell, &t) in cells.iter().zip(types) {
            match t {
                5 | 7 | 9 => out.push(cell.clone()),
                8 if cell.len() == 4 => out.push(vec![cell[0], cell[1], cell[3], cell[2]]),
                _ => {}
            }
        }
        return Ok(out);
    }
    let n = positions.len();
    let mut seen: HashMap<Vec<u32>, (u32, usize)> = HashMap::new();
    let mut candidates: Vec<Vec<u32>> = Vec::new();
    for (i, (cell, &t)) in cells.iter().zip(types).enumerate() {
        let Some(faces) = faces_of(t) else { continue };
        if cell.len() != corner_counts(t) || cell.iter().any(|&v| v as usize >= n) {
            return Err(ctx.parse(
                None,
                format!(
                    "cell {i} (type {t}) has {} corners or an index beyond {n} points",
                    cell.len()
                ),
            ));
        }
        let centroid =
            cell.iter().map(|&v| positions[v as usize]).sum::<Vec3>() / cell.len() as f64;
        for local in faces {
            let mut face: Vec<u32> = local.iter().map(|&k| cell[k]).collect();
            let p: Vec<Vec3> = face.iter().map(|&v| positions[v as usize]).collect();
            let normal: Vec3 = (1..p.len() - 1)
                .map(|k| (p[k] - p[0]).cross(&(p[k + 1] - p[0])))
                .sum();
            let face_centre = p.iter().sum::<Vec3>() / p.len() as f64;
            if normal.dot(&(face_centre - centroid)) < 0.0 {
                face.reverse();
            }
            let mut key = face.clone();
            key.sort_unstable();
            let entry = seen.entry(key).or_insert((0, candidates.len()));
            if entry.0 == 0 {
                candidates.push(face);
            }
            entry.0 += 1;
        }
    }
    let mut boundary: Vec<(usize, Vec<u32>)> = seen
        .into_values()
        .filter(|(count, _)| *count == 1)
        .map(|(_, idx)| (idx, std::mem::take(&mut candidates[idx])))
        .collect();
    // Keep the file's cell order so that output is deterministic.
    boundary.sort_unstable_by_key(|(idx, _)| *idx);
    out.extend(boundary.into_iter().map(|(_, f)| f));
    Ok(out)
}

#[derive(Debug, Clone, Copy)]
enum DataType {
    Int8,
    UInt8,
    Int16,
    UInt16,
    Int32,
    UInt32,
    Int64,
    Float32,
    Float64,
}

impl DataType {
    fn parse(name: &str) -> Option<Self> {
        Some(match name.to_ascii_lowercase().as_str() {
            "char" => Self::Int8,
            "unsigned_char" | "bit" => Self::UInt8,
            "short" => Self::Int16,
            "unsigned_short" => Self::UInt16,
            "int" | "vtktypeint32" => Self::Int32,
            "unsigned_int" | "vtktypeuint32" => Self::UInt32,
            "long" | "unsigned_long" | "vtktypeint64" | "vtktypeuint64" | "vtkidtype" => {
                Self::Int64
            }
            "float" => Self::Float32,
            "double" => Self::Float64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::Int8 | Self::UInt8 => 1,
            Self::Int16 | Self::UInt16 => 2,
            Self::Int32 | Self::UInt32 | Self::Float32 => 4,
            Self::Int64 | Self::Float64 => 8,
        }
    }

    /// Decodes one big-endian value (legacy VTK binary is big-endian).
    fn decode(self, b: &[u8]) -> f64 {
        match self {
            Self::Int8 => b[0] as i8 as f64,
            Self::UInt8 => b[0] as f64,
            Self::Int16 => i16::from_be_bytes([b[0], b[1]]) as f64,
            Self::UInt16 => u16::from_be_bytes([b[0], b[1]]) as f64,
            Self::Int32 => i32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Self::UInt32 => u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Self::Int64 => {
                i64::from_be_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f64
            }
            Self::Float32 => f32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Self::Float64 => f64::from_be_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        }
    }
}

/// Byte cursor that tracks line numbers.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Cursor<'a> {
    fn next_line(&mut self) -> Option<(&'a str, usize)> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let start = self.pos;
        let end = self.bytes[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(self.bytes.len(), |p| start + p);
        self.pos = (end + 1).min(self.bytes.len());
        let line = self.line;
        self.line += 1;
        let text = std::str::from_utf8(&self.bytes[start..end]).unwrap_or("");
        Some((text.trim_end_matches('\r'), line))
    }

    fn token(&mut self) -> Option<(&'a str, usize)> {
        while self.pos < self.bytes.len() && self.bytes[self.pos].is_ascii_whitespace() {
            if self.bytes[self.pos] == b'\n' {
                self.line += 1;
            }
            self.pos += 1;
        }
        if self.pos >= self.bytes.len() {
            return None;
        }
        let start = self.pos;
        while self.pos < self.bytes.len() && !self.bytes[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        Some((
            std::str::from_utf8(&self.bytes[start..self.pos]).unwrap_or("\u{fffd}"),
            self.line,
        ))
    }

    /// Moves past the rest of the current line (binary data starts on the next byte).
    fn end_line(&mut self) {
        while self.pos < self.bytes.len() {
            let b = self.bytes[self.pos];
            self.pos += 1;
            if b == b'\n' {
                self.line += 1;
                return;
            }
        }
    }

    /// Skips a METADATA block, which ends at an empty line.
    fn skip_block(&mut self) {
        self.end_line();
        while let Some((l, _)) = self.next_line() {
            if l.trim().is_empty() {
                return;
            }
        }
    }

    fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }
}

struct SectionReader<'a, 'c> {
    c: Cursor<'a>,
    ctx: &'c ImportContext<'c>,
    binary: bool,
}

impl SectionReader<'_, '_> {
    fn count(&mut self, line: usize) -> Result<u64, MeshImportError> {
        let (t, l) = self
            .c
            .token()
            .ok_or_else(|| self.ctx.parse(Some(line), "missing count"))?;
        t.parse::<u64>()
            .map_err(|_| self.ctx.parse(Some(l), format!("'{t}' is not a count")))
    }

    fn dtype(&mut self, line: usize) -> Result<DataType, MeshImportError> {
        let (t, l) = self
            .c
            .token()
            .ok_or_else(|| self.ctx.parse(Some(line), "missing data type"))?;
        DataType::parse(t)
            .ok_or_else(|| self.ctx.parse(Some(l), format!("unknown data type '{t}'")))
    }

    /// Reads `n` numbers, checking first that they can fit in the bytes left.
    fn numbers(
        &mut self,
        n: u64,
        dtype: DataType,
        line: usize,
    ) -> Result<Vec<f64>, MeshImportError> {
        let min_bytes = if self.binary { dtype.size() as u64 } else { 2 };
        let needed = n.saturating_mul(min_bytes);
        if needed > self.c.remaining() as u64 {
            return Err(self.ctx.truncated(needed, self.c.remaining() as u64));
        }
        let n = n as usize;
        let mut out = Vec::with_capacity(n);
        if self.binary {
            self.c.end_line();
            let size = dtype.size();
            let data = &self.c.bytes[self.c.pos..self.c.pos + n * size];
            out.extend(data.chunks_exact(size).map(|b| dtype.decode(b)));
            self.c.pos += n * size;
        } else {
            for k in 0..n {
                let (t, l) = self.c.token().ok_or_else(|| {
                    self.ctx.parse(
                        Some(self.c.line),
                        format!("section at line {line} ends after {k} of {n} values"),
                    )
                })?;
                let v = t
                    .parse::<f64>()
                    .map_err(|_| self.ctx.parse(Some(l), format!("'{t}' is not a number")))?;
                out.push(v);
            }
        }
        Ok(out)
    }

    /// Reads a cell-list section (`POLYGONS n size`, `CELLS n size`, ...), in either the
    /// classic `k i1 .. ik` layout or the VTK 5 OFFSETS/CONNECTIVITY layout.
    fn cell_lists(&mut self, line: usize) -> Result<Vec<Vec<u32>>, MeshImportError> {
        let n = self.count(line)?;
        let size = self.count(line)?;
        self.ctx.check_face_count(n)?;
        let save = (self.c.pos, self.c.line);
        if let Some((t, l)) = self.c.token()
            && t.eq_ignore_ascii_case("OFFSETS")
        {
            let dtype = self.dtype(l)?;
            let offsets = self.numbers(n, dtype, l)?;
            let (kw, l2) = self
                .c
                .token()
                .ok_or_else(|| self.ctx.parse(Some(l), "missing CONNECTIVITY"))?;
            if !kw.eq_ignore_ascii_case("CONNECTIVITY") {
                return Err(self
                    .ctx
                    .parse(Some(l2), format!("expected CONNECTIVITY, found '{kw}'")));
            }
            let dtype = self.dtype(l2)?;
            let conn = self.numbers(size, dtype, l2)?;
            let mut out = Vec::with_capacity(offsets.len().saturating_sub(1));
            for w in offsets.windows(2) {
                let (a, b) = (w[0] as usize, w[1] as usize);
                if a > b || b > conn.len() {
                    return Err(self
                        .ctx
                        .parse(Some(l), "OFFSETS are not increasing within CONNECTIVITY"));
                }
                out.push(conn[a..b].iter().map(|&v| index(v)).collect());
            }
            return Ok(out);
        }
        (self.c.pos, self.c.line) = save;
        let flat = self.numbers(size, DataType::Int32, line)?;
        let mut out = Vec::with_capacity(n as usize);
        let mut k = 0;
        while out.len() < n as usize {
            let Some(&len) = flat.get(k) else {
                return Err(self.ctx.parse(
                    Some(line),
                    format!("section declares {n} cells but its data ends early"),
                ));
            };
            // A cell size is a count of the values after it: anything else (negative,
            // fractional, NaN, or so large that `k + 1 + len` would overflow — found by
            // fuzzing) is an error, not an index.
            let fits =
                len.is_finite() && len >= 0.0 && len.fract() == 0.0 && len <= flat.len() as f64;
            let len = len as usize;
            if !fits || k + 1 + len > flat.len() {
                return Err(self.ctx.parse(
                    Some(line),
                    format!("cell {} runs past the section's {size} values", out.len()),
                ));
            }
            out.push(flat[k + 1..k + 1 + len].iter().map(|&v| index(v)).collect());
            k += 1 + len;
        }
        Ok(out)
    }
}

/// A vertex index from a file value; negative or huge values map to an index that the
/// range check after reading rejects.
fn index(v: f64) -> u32 {
    if v >= 0.0 && v < u32::MAX as f64 {
        v as u32
    } else {
        u32::MAX
    }
}
