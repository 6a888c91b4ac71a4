//! One wall's grid zipped into triangles: the lip to row 1 by parameter along the cut, then
//! neighbouring columns together by depth fraction, wound to face the gap.

use crate::geometry::triangle_min_angle_deg;
use crate::math::Vec3;

use super::WALL_MIN_ANGLE_DEG;
use crate::cut::cells::FaceKind;
use crate::cut::wound::{Assembly, WallColumn};

/// The columns' rows and their shared vertices, the same for both walls.
pub(super) struct Columns<'a> {
    pub cols: &'a [WallColumn],
    /// Rows of each column (0: an end column that ends at the surface).
    pub rows: Vec<usize>,
    /// The end columns' vertices, rows 0 ..= rows (an end at the surface: the end vertex
    /// twice, its row 1 and bottom).
    pub ends: [Vec<u32>; 2],
    /// Each column's bottom vertex.
    pub bottoms: Vec<u32>,
}

impl Columns<'_> {
    fn n(&self) -> usize {
        self.cols.len()
    }

    /// Rows the zips step through (an end column at the surface: its one pseudo-row).
    fn zip_rows(&self, c: usize) -> usize {
        self.rows[c].max(1)
    }

    fn is_end(&self, c: usize) -> bool {
        c == 0 || c == self.n() - 1
    }
}

/// The end column `c` on the lip's end vertex `id`: rows 1 ..= rows down to its bottom.
/// One that ends at the surface is the end vertex alone (its row 1 and bottom): the walls
/// fan from it.
pub(super) fn end_column(
    id: u32,
    rows: usize,
    column: &WallColumn,
    out: &mut Assembly,
) -> Vec<u32> {
    if rows == 0 {
        return vec![id, id];
    }
    let top = out.positions[id as usize];
    let mut ids = vec![id];
    for j in 1..=rows {
        let f = j as f64 / rows as f64;
        ids.push(out.vertex(top * (1.0 - f) + column.bottom() * f));
    }
    ids
}

/// The lip's position at parameter `tp` (on its polyline).
fn lip_at(lip: &[(f64, u32)], tp: f64, positions: &[Vec3]) -> Vec3 {
    let i = lip
        .partition_point(|&(t, _)| t <= tp)
        .clamp(1, lip.len() - 1)
        - 1;
    let (t0, v0) = lip[i];
    let (t1, v1) = lip[i + 1];
    let f = if t1 > t0 {
        ((tp - t0) / (t1 - t0)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    positions[v0 as usize] * (1.0 - f) + positions[v1 as usize] * f
}

fn shape(t: [u32; 3], out: &Assembly) -> f64 {
    triangle_min_angle_deg(t.map(|v| out.positions[v as usize]))
}

/// One lip's wall: `grid[c][j]` is column c's row j ≥ 1 (row 0 is the lip, not on the
/// columns).
pub(super) struct OneWall<'a> {
    lip: &'a [(f64, u32)],
    columns: &'a Columns<'a>,
    grid: Vec<Vec<u32>>,
    /// +1 for the upper lip's wall, −1 for the lower's.
    side: f64,
}

impl<'a> OneWall<'a> {
    /// The wall's grid: the inner columns' vertices made from the lip down.
    pub(super) fn new(
        lip: &'a [(f64, u32)],
        side: f64,
        columns: &'a Columns<'a>,
        out: &mut Assembly,
    ) -> Self {
        let n = columns.n();
        let mut grid: Vec<Vec<u32>> = Vec::with_capacity(n);
        for (c, col) in columns.cols.iter().enumerate() {
            let ids = if c == 0 {
                columns.ends[0].clone()
            } else if c == n - 1 {
                columns.ends[1].clone()
            } else {
                let rows = columns.rows[c];
                let top = lip_at(lip, col.param, &out.positions);
                let mut ids = vec![u32::MAX];
                for j in 1..rows {
                    let f = j as f64 / rows as f64;
                    ids.push(out.vertex(top * (1.0 - f) + col.bottom() * f));
                }
                ids.push(columns.bottoms[c]);
                ids
            };
            grid.push(ids);
        }
        Self {
            lip,
            columns,
            grid,
            side,
        }
    }

    /// Adds a wall triangle. The wall faces the gap: its outward normal points away from
    /// its own side. The winding follows from the grid (the lips and columns run from A to
    /// B, the rows down, the upper lip on the path's left seen from outside), not from each
    /// triangle's own normal, which a sliver of a narrow, deep wound can have pointing
    /// either way. Listed as the zips list them, a triangle between a lip and row 1 faces
    /// the lower side, and one between two columns the upper side.
    pub(super) fn emit(&self, tri: [u32; 3], faces_lower: bool, out: &mut Assembly) {
        // Stepping off or onto an end column at the surface (the end vertex twice).
        if tri[0] == tri[1] || tri[1] == tri[2] || tri[2] == tri[0] {
            return;
        }
        let tri = if faces_lower == (self.side > 0.0) {
            tri
        } else {
            [tri[0], tri[2], tri[1]]
        };
        out.created.push(out.triangles.len() as u32);
        out.triangles.push(tri);
        out.kinds.push(FaceKind::Wall);
    }

    /// Between the lip and row 1: the two polylines zipped together by parameter, keeping
    /// the two fronts in step along the cut — and, when `lenient`, letting a step out of
    /// turn where in turn it lays a sliver the other order avoids: at a shallow end column,
    /// rows a fraction of a gap apart beside a lip leaving sideways make the in-turn step's
    /// fan from the end vertex a 14.5° cell (the cerebroma's session), the other order
    /// 22.6°. Which is used is `out_of_turn`'s (see [`super::build_walls`]).
    pub(super) fn strip(&self, lenient: bool, out: &Assembly) -> Vec<[u32; 3]> {
        let (lip, grid, n) = (self.lip, &self.grid, self.columns.n());
        let mut cells = Vec::with_capacity(lip.len() + n);
        let (mut i, mut k) = (0, 0);
        while i + 1 < lip.len() || k + 1 < n {
            // (u32::MAX where that polyline has ended: the step is then never taken.)
            let lip_step = [
                lip[i].1,
                grid[k][1],
                lip.get(i + 1).map_or(u32::MAX, |l| l.1),
            ];
            let column_step = [
                lip[i].1,
                grid[k][1],
                grid.get(k + 1).map_or(u32::MAX, |g| g[1]),
            ];
            if self.lip_advances(i, k, lenient, [lip_step, column_step], out) {
                cells.push(lip_step);
                i += 1;
            } else {
                cells.push(column_step);
                k += 1;
            }
        }
        cells
    }

    /// Whether the strip's next step is along the lip (from lip vertex `i` and column `k`)
    /// rather than along the columns.
    fn lip_advances(
        &self,
        i: usize,
        k: usize,
        lenient: bool,
        [lip_step, column_step]: [[u32; 3]; 2],
        out: &Assembly,
    ) -> bool {
        let (lip, grid, n) = (self.lip, &self.grid, self.columns.n());
        let (rows, cols) = (&self.columns.rows, self.columns.cols);
        if i + 1 == lip.len() {
            false
        } else if k + 1 == n {
            true
        } else if k == 0 && rows[0] == 0 {
            // An end column at the surface is left first and reached last: a lip
            // step there would lay a cell along the lip from the end vertex.
            false
        } else if k + 2 == n && rows[n - 1] == 0 {
            true
        } else if k == 1 && i == 0 && rows[0] == 0 && i + 2 < lip.len() {
            // And the lip leaves that end vertex next (reaches it after the
            // columns): a column step from it would join it to two rows of a wall
            // rising to it, nearly on a line (exactly, on a straight cut with
            // columns graded near the end beside a lip that is not).
            true
        } else if i + 2 == lip.len() && k + 2 < n && rows[n - 1] == 0 {
            false
        } else if (lip[i + 1].0 - cols[k + 1].param).abs()
            > 0.5 * (cols[k + 1].param - cols[k].param)
        {
            let in_turn = lip[i + 1].0 < cols[k + 1].param;
            if lenient {
                // Each order weighed with the step that follows it.
                let lip_first = shape(lip_step, out)
                    .min(shape([lip[i + 1].1, grid[k][1], grid[k + 1][1]], out));
                let column_first = shape(column_step, out)
                    .min(shape([lip[i].1, grid[k + 1][1], lip[i + 1].1], out));
                let (in_order, out_of_order) = if in_turn {
                    (lip_first, column_first)
                } else {
                    (column_first, lip_first)
                };
                if in_order < WALL_MIN_ANGLE_DEG && out_of_order > in_order {
                    !in_turn
                } else {
                    in_turn
                }
            } else {
                in_turn
            }
        } else {
            shape(lip_step, out) >= shape(column_step, out)
        }
    }

    /// Between neighbouring columns, row 1 down to the bottom: the two columns zipped
    /// together by depth fraction (they may have different numbers of rows).
    pub(super) fn zip_columns(&self, out: &mut Assembly) {
        let (grid, columns) = (&self.grid, self.columns);
        for a in 0..columns.n() - 1 {
            let b = a + 1;
            let (ra, rb) = (columns.zip_rows(a), columns.zip_rows(b));
            let (mut j, mut k) = (1, 1);
            while j < ra || k < rb {
                // A column may reach its bottom only after an end column beside it has:
                // a triangle of three shared vertices would be emitted by both walls.
                let may_reach = |x_next: usize, rx: usize, y: usize, y_at: usize, ry: usize| {
                    x_next < rx || !columns.is_end(y) || y_at == ry
                };
                let can_a = j < ra && may_reach(j + 1, ra, b, k, rb);
                let can_b = k < rb && may_reach(k + 1, rb, a, j, ra);
                let tri_a = |j: usize| [grid[a][j], grid[b][k], grid[a][j + 1]];
                let tri_b = |k: usize| [grid[a][j], grid[b][k], grid[b][k + 1]];
                let advance_a = match (can_a, can_b) {
                    (true, false) => true,
                    (false, _) => false,
                    (true, true) => {
                        let (fa, fb) = ((j + 1) as f64 / ra as f64, (k + 1) as f64 / rb as f64);
                        if (fa - fb).abs() > 0.5 / ra.max(rb) as f64 {
                            // Keep the two fronts in step down the wall.
                            fa < fb
                        } else {
                            // The cell's better diagonal: each choice is followed by the
                            // other column's step, so weigh both triangles (the first
                            // alone picked a fine triangle and left a sliver beside it
                            // where the floor falls steeply).
                            let then_b = [grid[a][j + 1], grid[b][k], grid[b][k + 1]];
                            let then_a = [grid[a][j], grid[b][k + 1], grid[a][j + 1]];
                            shape(tri_a(j), out).min(shape(then_b, out))
                                >= shape(tri_b(k), out).min(shape(then_a, out))
                        }
                    }
                };
                if advance_a {
                    self.emit(tri_a(j), false, out);
                    j += 1;
                } else {
                    self.emit(tri_b(k), false, out);
                    k += 1;
                }
            }
        }
    }
}
