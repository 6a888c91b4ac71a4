//! Wound walls: what an incision leaves below its lips, and a deeper pass along it.
//!
//! An incision records its wound: the two lips (vertices of the surface) and the columns
//! its walls hang from (a point on the path, the direction into the tissue, the depth).
//! The walls are two strips, one from each lip down to the shared bottom curve, gridded
//! column by column, each column with as many rows as its depth needs — so a wound that
//! is shallow in one place and deep in another keeps well-shaped cells in both.
//!
//! A later stroke that runs along the wound deeper than its walls (a surgeon deepening an
//! incision, or a deeper cut across it) cuts below the old floor; [`deepen`] takes the
//! walls of every such column down to the new depth. A wound deepened along at least half
//! its columns is then opened again as one incision at the new depths (its lid back to
//! skin), so its lips part as a first pass that deep would have opened them; if that
//! incision is refused, or less than half the wound was deepened, only the walls change.

use std::collections::{HashMap, HashSet};

use crate::geometry::TriMesh;
use crate::geometry::predicates::{line_triangle, nearest_on_segment};
use crate::geometry::triangle_min_angle_deg;
use crate::math::{Aabb, Vec3};

use super::incision::{
    FaceKind, Incised, IncisionParams, PathSample, flip_to_surface_quality, incise, source_through,
    tracks_across,
};

/// One column of a wound's walls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallColumn {
    /// Where it is along the path, in [0, 1].
    pub param: f64,
    /// Its top, on the path (rest space, m).
    pub top: Vec3,
    /// Unit direction into the tissue.
    pub inward: Vec3,
    /// Depth of the walls here (m).
    pub depth: f64,
}

impl WallColumn {
    fn bottom(&self) -> Vec3 {
        self.top + self.inward * self.depth
    }
}

/// An opened incision: what a later, deeper pass needs to take its walls further down.
#[derive(Debug, Clone, PartialEq)]
pub struct Wound {
    /// The upper lip from end A to end B: (parameter along the path in [0, 1], vertex).
    pub upper: Vec<(f64, u32)>,
    /// The lower lip, A to B (the same end vertices).
    pub lower: Vec<(f64, u32)>,
    /// The wall columns, evenly spaced from A (parameter 0) to B (parameter 1).
    pub columns: Vec<WallColumn>,
    /// Largest half-opening (m).
    pub opening_m: f64,
    /// Path length (m).
    pub length_m: f64,
    /// The spacing the incision was meshed at (m).
    pub spacing_m: f64,
}

impl Wound {
    /// Deepest column (m).
    pub fn depth_m(&self) -> f64 {
        self.columns.iter().map(|c| c.depth).fold(0.0, f64::max)
    }

    /// The same wound in another numbering of the vertices, with the vertices `splits` put
    /// on its lip edges; `None` if a lip vertex is gone.
    fn renumbered(&self, new_id: &[Option<u32>], splits: &EdgeSplits) -> Option<Wound> {
        let map = |lip: &[(f64, u32)]| -> Option<Vec<(f64, u32)>> {
            let mut out = Vec::with_capacity(lip.len());
            for (i, &(t, v)) in lip.iter().enumerate() {
                out.push((t, new_id.get(v as usize).copied().flatten()?));
                let Some(&(t1, v1)) = lip.get(i + 1) else {
                    continue;
                };
                let inserted: Vec<(f64, u32)> = match (splits.get(&(v, v1)), splits.get(&(v1, v))) {
                    (Some(along), _) => along.clone(),
                    (None, Some(against)) => {
                        against.iter().rev().map(|&(f, id)| (1.0 - f, id)).collect()
                    }
                    (None, None) => Vec::new(),
                };
                out.extend(inserted.iter().map(|&(f, id)| (t + f * (t1 - t), id)));
            }
            Some(out)
        };
        Some(Wound {
            upper: map(&self.upper)?,
            lower: map(&self.lower)?,
            ..self.clone()
        })
    }

    /// Distance between neighbouring columns (m).
    pub(crate) fn column_gap_m(&self) -> f64 {
        self.length_m / (self.columns.len() - 1).max(1) as f64
    }

    /// Its lip edges (unordered vertex pairs).
    fn lip_edges(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        [&self.upper, &self.lower]
            .into_iter()
            .flat_map(|lip| lip.windows(2).map(|e| edge_key(e[0].1, e[1].1)))
    }
}

/// Vertices a re-mesh put on edges of its input: input edge (a, b) → (fraction from a,
/// output vertex), in order from a.
pub(crate) type EdgeSplits = HashMap<(u32, u32), Vec<(f64, u32)>>;

fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// The wounds of `wounds` after a re-mesh whose vertex `v` came from input vertex
/// `source[v]` and which split the input edges in `splits` (a later incision's region can
/// reach an earlier wound's lip and split it); wounds that lost a lip vertex are dropped.
pub(crate) fn carry_wounds(
    wounds: &[Wound],
    source: &[Option<u32>],
    inputs: usize,
    splits: &EdgeSplits,
) -> Vec<Wound> {
    let mut new_id = vec![None; inputs];
    for (v, s) in source.iter().enumerate() {
        if let Some(s) = s {
            new_id[*s as usize] = Some(v as u32);
        }
    }
    wounds
        .iter()
        .filter_map(|w| w.renumbered(&new_id, splits))
        .collect()
}

/// A surface being assembled: vertices with the input vertex each one is, triangles with
/// their kind, and which triangles are new.
pub(crate) struct Assembly {
    pub positions: Vec<Vec3>,
    pub source: Vec<Option<u32>>,
    pub triangles: Vec<[u32; 3]>,
    pub kinds: Vec<FaceKind>,
    pub created: Vec<u32>,
}

impl Assembly {
    fn vertex(&mut self, p: Vec3) -> u32 {
        self.positions.push(p);
        self.source.push(None);
        (self.positions.len() - 1) as u32
    }

    /// Where the surface is now, to measure or undo what is added after it.
    fn mark(&self) -> AssemblyMark {
        AssemblyMark {
            positions: self.positions.len(),
            triangles: self.triangles.len(),
            created: self.created.len(),
        }
    }

    /// Smallest angle of the drawn triangles created since `mark` (degrees).
    fn min_angle_since_deg(&self, mark: &AssemblyMark) -> f64 {
        self.created[mark.created..]
            .iter()
            .filter(|&&t| self.kinds[t as usize] != FaceKind::Lid)
            .map(|&t| {
                triangle_min_angle_deg(
                    self.triangles[t as usize].map(|v| self.positions[v as usize]),
                )
            })
            .fold(180.0, f64::min)
    }

    /// Back to what it was at `mark`.
    fn truncate(&mut self, mark: AssemblyMark) {
        self.positions.truncate(mark.positions);
        self.source.truncate(mark.positions);
        self.triangles.truncate(mark.triangles);
        self.kinds.truncate(mark.triangles);
        self.created.truncate(mark.created);
    }

    /// Smallest angle of the created triangles that are drawn (degrees).
    pub fn min_created_angle_deg(&self) -> f64 {
        self.min_angle_since_deg(&AssemblyMark::default())
    }
}

/// A point in the assembly of a surface ([`Assembly::mark`]; the default: its start).
#[derive(Default)]
struct AssemblyMark {
    positions: usize,
    triangles: usize,
    created: usize,
}

/// Largest turn of a column toward its spread-out bottom ([`even_out_bottoms`]): the
/// columns lean with the cut's own direction, and a small turn keeps the wall near Σ and
/// within the walls' largest lean (plus this).
const SPREAD_MAX_TURN_DEG: f64 = 15.0;

/// Spreads the columns' bottoms where they bunch up: columns lean with the cut's own
/// direction (a raked blade's walls lie in Σ), and where that turns quickly two
/// neighbouring bottoms nearly meet (the tumour's default cut: 0.06 mm apart under tops
/// 0.39 mm apart, 9.6° wall cells). A gap is bunched when it is under half its share of
/// the bottom curve from the column before it to the one after the next; over each such
/// stretch (overlapping ones merged) the inner columns' bottoms are put on that curve as
/// their tops are spread along the path, each column turning at most
/// [`SPREAD_MAX_TURN_DEG`] toward its place (short of it if need be). Tops, the end
/// columns and the columns outside the stretches stay. The columns that moved.
pub(crate) fn even_out_bottoms(columns: &mut [WallColumn]) -> Vec<usize> {
    let n = columns.len();
    let mut moved = Vec::new();
    if n < 3 {
        return moved;
    }
    let bottoms: Vec<Vec3> = columns.iter().map(WallColumn::bottom).collect();
    let tops: Vec<Vec3> = columns.iter().map(|c| c.top).collect();
    let top_gap = |k: usize| (tops[k + 1] - tops[k]).norm();
    let bottom_gap = |k: usize| (bottoms[k + 1] - bottoms[k]).norm();
    // The stretches [a, b] of columns around bunched gaps.
    let mut stretches: Vec<(usize, usize)> = Vec::new();
    for k in 0..n - 1 {
        let (a, b) = (k.saturating_sub(1), (k + 2).min(n - 1));
        let (over_tops, over_bottoms) = (
            (a..b).map(top_gap).sum::<f64>(),
            (a..b).map(bottom_gap).sum::<f64>(),
        );
        // (Or under half its own top's: where the bottoms come together over several
        // gaps — a deeper pass under columns that lean toward each other over a hump,
        // 0.40 mm under tops 1.6 mm apart on the deltoid, rows 1.8 mm tall — the share
        // alone misses it, and the floor's cells are 12° slivers.)
        let share = top_gap(k) * over_bottoms / over_tops.max(1e-300);
        if over_tops <= 0.0 || bottom_gap(k) >= 0.5 * share.max(top_gap(k)) {
            continue;
        }
        match stretches.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => stretches.push((a, b)),
        }
    }
    let max_turn_cos = SPREAD_MAX_TURN_DEG.to_radians().cos();
    for (a, b) in stretches {
        let mut arc = vec![0.0];
        for k in a..b {
            arc.push(arc[arc.len() - 1] + bottom_gap(k));
        }
        let scale = arc[arc.len() - 1] / (a..b).map(top_gap).sum::<f64>();
        let mut along_top = 0.0;
        for c in a + 1..b {
            along_top += top_gap(c - 1);
            let target = along_top * scale;
            let i = arc
                .partition_point(|&x| x <= target)
                .clamp(1, arc.len() - 1)
                - 1;
            let f = ((target - arc[i]) / (arc[i + 1] - arc[i]).max(1e-300)).clamp(0.0, 1.0);
            let place = bottoms[a + i] * (1.0 - f) + bottoms[a + i + 1] * f;
            let (top, old, inward) = (tops[c], bottoms[c], columns[c].inward);
            let turned_ok = |t: f64| {
                (old + (place - old) * t - top)
                    .try_normalize(1e-12)
                    .is_some_and(|d| d.dot(&inward) >= max_turn_cos)
            };
            // As far toward its place as the turn allows (bisection: the turn grows with
            // the way gone, for a place not behind the top).
            let t = if turned_ok(1.0) {
                1.0
            } else {
                let (mut lo, mut hi) = (0.0, 1.0);
                for _ in 0..30 {
                    let mid = 0.5 * (lo + hi);
                    if turned_ok(mid) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                lo
            };
            let down = old + (place - old) * t - top;
            if t > 0.0
                && let Some(dir) = down.try_normalize(1e-12)
            {
                columns[c].inward = dir;
                columns[c].depth = down.norm();
                moved.push(c);
            }
        }
    }
    moved
}

/// The smallest angle a wall's cell should keep (degrees): the surface's bound.
const WALL_MIN_ANGLE_DEG: f64 = 15.0;

/// Rows of a column `depth` deep, for cells about `cell` tall; none for an end column that
/// ends at the surface ([`build_walls_choosing_ends`]).
fn rows_for(depth: f64, cell: f64) -> usize {
    if depth <= 0.0 {
        return 0;
    }
    // At least two rows: with one, the row under the lips would be the shared bottom row,
    // and both walls would fan the same triangles from the shared end vertices.
    ((depth / cell).round() as usize).clamp(2, 64)
}

/// Adds the wound's walls: from each lip down to the bottom curve, meeting at the bottom
/// and at both ends (the end columns and the bottom vertices are shared by the two walls).
/// Where a lip's strip would lay a sliver its fronts kept in step avoid, the walls are
/// built both ways and the ones whose smallest angle is larger kept (in step on a tie):
/// a step out of turn shifts every step after it (beside a spike's flank, an 8.9° cell
/// further on), and the flips after it may mend either.
pub(crate) fn build_walls(wound: &Wound, out: &mut Assembly) {
    let mark = out.mark();
    let columns = graded_columns(wound, &out.positions);
    if !build_and_flip(wound, &columns, false, out) {
        return;
    }
    let in_step = out.min_angle_since_deg(&mark);
    out.truncate(mark);
    let mark = out.mark();
    build_and_flip(wound, &columns, true, out);
    if out.min_angle_since_deg(&mark) <= in_step {
        out.truncate(mark);
        build_and_flip(wound, &columns, false, out);
    }
}

/// The walls on `columns` ([`build_wall_grids`]), their edges flipped to better cells;
/// whether a step out of turn would change a lip's strip.
fn build_and_flip(
    wound: &Wound,
    columns: &[WallColumn],
    out_of_turn: bool,
    out: &mut Assembly,
) -> bool {
    let mark = out.mark();
    let (shared, differs) = build_wall_grids(wound, columns, out_of_turn, out);
    // Where the two walls meet (the floor, the end columns) they face each other: an
    // edge there is never flipped, however flat a shallow, wide wound's V is.
    let meet = |v: u32| shared.binary_search(&v).is_ok();
    flip_to_surface_quality(
        &out.positions,
        &mut out.triangles,
        &out.kinds,
        &out.created[mark.created..],
        FaceKind::Wall,
        |a, b| meet(a) && meet(b),
    );
    differs
}

/// The wound's columns with columns added between each end column and the next where
/// the lips start with segments shorter than half a gap (an incision grades its lips to
/// quarter-spacing segments at the ends): at one, two, four… times the shorter first
/// segment from the end while within 0.6 of a gap, their tops, directions and depths
/// interpolated. Zipped to a row a gap away, those short lip segments would make
/// slivers (11.6° at best after flips, 3.5° as gridded, on 0.24 mm segments beside
/// columns 1.2 mm apart).
fn graded_columns(wound: &Wound, positions: &[Vec3]) -> Vec<WallColumn> {
    let cols = &wound.columns;
    let n = cols.len();
    // (Three columns at least: the two ends' added columns then lie in different gaps.)
    if n < 3 || wound.length_m <= 0.0 {
        return cols.clone();
    }
    let gap = wound.column_gap_m();
    // Between end column `end` and its neighbour `next`, at distances from the end.
    let added = |end: usize, next: usize, first: f64| -> Vec<WallColumn> {
        let mut out = Vec::new();
        // (A lip segment of no length would never double.)
        if !(first > 1e-9 && first < 0.5 * gap) {
            return out;
        }
        let mut at = first;
        while at <= 0.6 * gap {
            let f = at / gap;
            let (e, x) = (&cols[end], &cols[next]);
            let inward = (e.inward * (1.0 - f) + x.inward * f)
                .try_normalize(1e-12)
                .unwrap_or(x.inward);
            out.push(WallColumn {
                param: e.param + (x.param - e.param) * f,
                top: e.top * (1.0 - f) + x.top * f,
                inward,
                depth: e.depth * (1.0 - f) + x.depth * f,
            });
            at *= 2.0;
        }
        out
    };
    let segment = |lip: &[(f64, u32)], k: usize| {
        (positions[lip[k].1 as usize] - positions[lip[k + 1].1 as usize]).norm()
    };
    let (upper, lower) = (&wound.upper, &wound.lower);
    let first = segment(upper, 0).min(segment(lower, 0));
    let last = segment(upper, upper.len() - 2).min(segment(lower, lower.len() - 2));
    let mut graded = vec![cols[0]];
    graded.extend(added(0, 1, first));
    graded.extend_from_slice(&cols[1..n - 1]);
    let mut tail = added(n - 1, n - 2, last);
    tail.reverse();
    graded.extend(tail);
    graded.push(cols[n - 1]);
    graded
}

/// The walls as their grids on `cols` give them (see [`build_walls`]), the lips' strips
/// with steps out of turn where `out_of_turn`; the vertices both walls share (the end
/// columns' and the bottom's), sorted, and whether a step out of turn changes a strip.
fn build_wall_grids(
    wound: &Wound,
    cols: &[WallColumn],
    out_of_turn: bool,
    out: &mut Assembly,
) -> (Vec<u32>, bool) {
    let n = cols.len();
    let mut differs = false;
    let cell = wound.column_gap_m().max(wound.spacing_m / 4.0);
    let rows: Vec<usize> = cols.iter().map(|c| rows_for(c.depth, cell)).collect();
    let a_id = wound.upper[0].1;
    let b_id = wound.upper[wound.upper.len() - 1].1;
    // The end columns, rows 1 ..= rows, shared. One that ends at the surface is the end
    // vertex alone (its row 1 and bottom): the walls fan from it.
    let end_column = |id: u32, c: usize, out: &mut Assembly| {
        if rows[c] == 0 {
            return vec![id, id];
        }
        let top = out.positions[id as usize];
        let mut ids = vec![id];
        for j in 1..=rows[c] {
            let f = j as f64 / rows[c] as f64;
            ids.push(out.vertex(top * (1.0 - f) + cols[c].bottom() * f));
        }
        ids
    };
    let end0 = end_column(a_id, 0, out);
    let end1 = end_column(b_id, n - 1, out);
    let mut bottoms = vec![end0[end0.len() - 1]];
    for c in cols.iter().take(n - 1).skip(1) {
        bottoms.push(out.vertex(c.bottom()));
    }
    bottoms.push(end1[end1.len() - 1]);
    // Rows the zips below step through (an end column at the surface: its one pseudo-row).
    let zip_rows = |c: usize| rows[c].max(1);
    let end = |c: usize| c == 0 || c == n - 1;

    for (lip, side) in [(&wound.upper, 1.0), (&wound.lower, -1.0)] {
        // The lip's position at any parameter (on its polyline).
        let lip_at = |tp: f64, positions: &[Vec3]| -> Vec3 {
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
        };
        // grid[c][j]: column c, row j ≥ 1 (row 0 is the lip, not on the columns).
        let mut grid: Vec<Vec<u32>> = Vec::with_capacity(n);
        for (c, col) in cols.iter().enumerate() {
            let ids = if c == 0 {
                end0.clone()
            } else if c == n - 1 {
                end1.clone()
            } else {
                let top = lip_at(col.param, &out.positions);
                let mut ids = vec![u32::MAX];
                for j in 1..rows[c] {
                    let f = j as f64 / rows[c] as f64;
                    ids.push(out.vertex(top * (1.0 - f) + col.bottom() * f));
                }
                ids.push(bottoms[c]);
                ids
            };
            grid.push(ids);
        }
        // The wall faces the gap: its outward normal points away from its own side. The
        // winding follows from the grid (the lips and columns run from A to B, the rows
        // down, the upper lip on the path's left seen from outside), not from each
        // triangle's own normal, which a sliver of a narrow, deep wound can have pointing
        // either way.
        // Listed as the zips list them, a triangle between a lip and row 1 faces the lower
        // side, and one between two columns the upper side.
        let emit = |tri: [u32; 3], faces_lower: bool, out: &mut Assembly| {
            // Stepping off or onto an end column at the surface (the end vertex twice).
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[2] == tri[0] {
                return;
            }
            let tri = if faces_lower == (side > 0.0) {
                tri
            } else {
                [tri[0], tri[2], tri[1]]
            };
            out.created.push(out.triangles.len() as u32);
            out.triangles.push(tri);
            out.kinds.push(FaceKind::Wall);
        };
        let shape = |t: [u32; 3], out: &Assembly| {
            triangle_min_angle_deg(t.map(|v| out.positions[v as usize]))
        };
        // Between the lip and row 1: zip the two polylines together by parameter, keeping
        // the two fronts in step along the cut — and again letting a step out of turn
        // where in turn it lays a sliver the other order avoids: at a shallow end column,
        // rows a fraction of a gap apart beside a lip leaving sideways make the in-turn
        // step's fan from the end vertex a 14.5° cell (the cerebroma's session), the other
        // order 22.6°. Which is used is `out_of_turn`'s (see [`build_walls`]).
        let strip = |lenient: bool, out: &Assembly| -> Vec<[u32; 3]> {
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
                let advance_lip = if i + 1 == lip.len() {
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
                };
                if advance_lip {
                    cells.push(lip_step);
                    i += 1;
                } else {
                    cells.push(column_step);
                    k += 1;
                }
            }
            cells
        };
        let in_step = strip(false, out);
        let lenient = strip(true, out);
        differs |= lenient != in_step;
        let cells = if out_of_turn { lenient } else { in_step };
        for tri in cells {
            emit(tri, true, out);
        }
        // Between neighbouring columns, row 1 down to the bottom: zip the two columns
        // together by depth fraction (they may have different numbers of rows).
        for a in 0..n - 1 {
            let b = a + 1;
            let (ra, rb) = (zip_rows(a), zip_rows(b));
            let (mut j, mut k) = (1, 1);
            while j < ra || k < rb {
                // A column may reach its bottom only after an end column beside it has:
                // a triangle of three shared vertices would be emitted by both walls.
                let may_reach = |x_next: usize, rx: usize, y: usize, y_at: usize, ry: usize| {
                    x_next < rx || !end(y) || y_at == ry
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
                    emit(tri_a(j), false, out);
                    j += 1;
                } else {
                    emit(tri_b(k), false, out);
                    k += 1;
                }
            }
        }
    }
    let mut shared: Vec<u32> = end0.iter().chain(&end1).chain(&bottoms).copied().collect();
    shared.sort_unstable();
    shared.dedup();
    (shared, differs)
}

/// A wall column's `depth` from `top` along `inward`, held short of a thin part's far
/// side: at most 0.7 of the way to the first of `skin`'s triangles within one `spacing`
/// past it (the incision's rule, a deeper pass's and a spread column's).
pub(crate) fn held_short(
    mesh: &TriMesh,
    skin: &[usize],
    top: &Vec3,
    inward: &Vec3,
    depth: f64,
    spacing: f64,
) -> f64 {
    match first_hit(mesh, skin, top, inward, depth + spacing) {
        Some(hit) => depth.min(0.7 * hit),
        None => depth,
    }
}

/// Distance along the ray from `origin` in unit direction `dir` to the first of
/// `triangles` of `mesh` it hits within `reach`.
pub(crate) fn first_hit(
    mesh: &TriMesh,
    triangles: &[usize],
    origin: &Vec3,
    dir: &Vec3,
    reach: f64,
) -> Option<f64> {
    let ray = Aabb::around([origin, &(origin + dir * reach)]);
    triangles
        .iter()
        .filter_map(|&t| {
            let c = mesh.corners(t);
            if !ray.overlaps(&Aabb::around(&c)) {
                return None;
            }
            line_triangle(origin, dir, &c)
                .map(|(s, _)| s)
                .filter(|&s| s > 1e-9 && s <= reach)
        })
        .min_by(f64::total_cmp)
}

/// The cut `path` made (m: from the surface down to its floor, square to the path; `cuts`
/// from [`tracks_across`]) at its point nearest `x`, if that point is within `across` of
/// `x` — or within `along` where it is an end of the path (beside it, not ahead of it).
fn path_cut_near(
    path: &[PathSample],
    cuts: &[Vec3],
    x: &Vec3,
    across: f64,
    along: f64,
) -> Option<Vec3> {
    if let [only] = path {
        return ((x - only.surface).norm() <= along).then_some(cuts[0]);
    }
    let (distance, at_end, cut) = path
        .windows(2)
        .enumerate()
        .map(|(i, w)| {
            let (a, b) = (w[0].surface, w[1].surface);
            let f = nearest_on_segment(x, &a, &b);
            let at_end = (i == 0 && f == 0.0) || (i + 2 == path.len() && f == 1.0);
            let distance = (x - (a + (b - a) * f)).norm();
            (distance, at_end, cuts[i] * (1.0 - f) + cuts[i + 1] * f)
        })
        .min_by(|p, q| p.0.total_cmp(&q.0))?;
    (distance <= if at_end { along } else { across }).then_some(cut)
}

/// Where a deeper pass ends or crosses a wound, the new floor meets the old one in a step;
/// the walls' cells across a step taller than the columns are apart would be slivers. The
/// new floor is eased down to the old at 45° or less (never above the old floor: the walls
/// show a little less of the new cut at its ends, never uncut tissue). An end column may
/// be at most half a gap deeper than its neighbour: the end column and the floor are shared
/// by both walls, so the neighbour's last cell must fan from the end column's bottom up to
/// the neighbour's last row (a crossing pass at a wound's end made 13.5° cells at 45°).
/// A first incision's walls (`old` none) are eased the same way where a thin part stops a
/// column at a fraction of a millimetre beside one several deep (the deltoid sheet).
pub(crate) fn limit_slope(columns: &mut [WallColumn], old: Option<&[WallColumn]>, gap: f64) {
    let last = columns.len().saturating_sub(1);
    let step = |c: usize| if c == 0 || c == last { 0.5 * gap } else { gap };
    let floor = |c: usize| old.map_or(0.0, |old| old[c].depth);
    for c in 1..columns.len() {
        let limit = columns[c - 1].depth + step(c);
        columns[c].depth = columns[c].depth.min(limit).max(floor(c));
    }
    for c in (0..last).rev() {
        let limit = columns[c + 1].depth + step(c);
        columns[c].depth = columns[c].depth.min(limit).max(floor(c));
    }
}

/// Depth, in column gaps, under which an end column may end at the surface
/// ([`build_walls_choosing_ends`]).
const SHALLOW_END: f64 = 0.75;

/// Adds the wound's walls as [`build_walls`] does, after choosing for each end column
/// shallower than [`SHALLOW_END`] gaps (a thin part, or a blade that barely reached below
/// the surface there) whether it ends at the surface instead, the floor rising to the end
/// vertex at 45° ([`limit_slope`]) and the walls fanning from it: an end column's rows
/// (at least two) that short make slivers with the next column (4–14° on the deltoid),
/// but a lip that starts with a short segment needs them. Of the ways, the one whose
/// walls have the largest smallest angle, the wound's columns as they are on a tie. A
/// column is never raised above `old`'s floor. The wound keeps the columns chosen.
pub(crate) fn build_walls_choosing_ends(
    wound: &mut Wound,
    old: Option<&[WallColumn]>,
    out: &mut Assembly,
) {
    let last = wound.columns.len().saturating_sub(1);
    let gap = wound.column_gap_m();
    // (Three columns at least: the walls need one below the surface between the ends.)
    let shallow = |end: usize| {
        last >= 2
            && wound.columns[end].depth > 0.0
            && wound.columns[end].depth < SHALLOW_END * gap
            && old.is_none_or(|old| old[end].depth <= 0.0)
    };
    let ends: Vec<usize> = [0, last].into_iter().filter(|&e| shallow(e)).collect();
    if ends.is_empty() {
        build_walls(wound, out);
        return;
    }
    let original = wound.columns.clone();
    let ways = 1usize << ends.len();
    let mut best: Option<(f64, Vec<WallColumn>)> = None;
    for way in 0..ways {
        let mut columns = original.clone();
        for (k, &end) in ends.iter().enumerate() {
            if way & (1 << k) != 0 {
                columns[end].depth = 0.0;
            }
        }
        if way != 0 {
            limit_slope(&mut columns, old, gap);
        }
        wound.columns = columns;
        let mark = out.mark();
        build_walls(wound, out);
        let angle = out.min_angle_since_deg(&mark);
        let better = best.as_ref().is_none_or(|(b, _)| angle > *b);
        if better && way + 1 == ways {
            // The last way tried is the best: its walls stay.
            return;
        }
        out.truncate(mark);
        if better {
            best = Some((angle, wound.columns.clone()));
        }
    }
    if let Some((_, columns)) = best {
        wound.columns = columns;
    }
    build_walls(wound, out);
}

/// Takes the walls of `wounds` down where `path` cut deeper than them, and opens again
/// the wounds deepened along at least half their columns (see the module docs). `None`
/// when no wound is deepened by more than a quarter of its spacing.
pub fn deepen(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    wounds: &[Wound],
    path: &[PathSample],
    params: &IncisionParams,
) -> Option<Incised> {
    // Wall faces by edge: to find each wound's walls, and to check that its lips are
    // still wall edges.
    let walls_by_edge = faces_by_edge(mesh, kinds, FaceKind::Wall);
    // The new depth of every column the path ran over, for the wounds it deepens.
    let skin: Vec<usize> = (0..mesh.triangles.len())
        .filter(|&t| kinds[t] == FaceKind::Skin)
        .collect();
    let cuts = tracks_across(path);
    let mut deeper: Vec<(usize, Wound)> = Vec::new();
    for (w, wound) in wounds.iter().enumerate() {
        // Across the wound, anywhere over the lid (with a quarter spacing for the entry's
        // wander); along it, the walls go down as far as the blade has come (to the
        // nearest column), not ahead.
        let across = wound.opening_m + 0.25 * wound.spacing_m;
        let along = 0.5 * wound.column_gap_m();
        let mut changed = false;
        let mut new = wound.clone();
        for col in &mut new.columns {
            // As far down this column as the pass cut (a pass leaning against the wound's
            // walls reaches less far along them than its edge is long).
            let Some(cut) = path_cut_near(path, &cuts, &col.top, across, along) else {
                continue;
            };
            let depth = cut.dot(&col.inward).max(0.0);
            if depth <= col.depth + 0.25 * wound.spacing_m {
                continue;
            }
            // A thin part: stop the wall short of the far side of the organ, as the
            // incision does.
            let depth = held_short(mesh, &skin, &col.top, &col.inward, depth, wound.spacing_m);
            if depth > col.depth + 0.25 * wound.spacing_m {
                col.depth = depth;
                changed = true;
            }
        }
        if changed {
            limit_slope(&mut new.columns, Some(&wound.columns), wound.column_gap_m());
            // Deeper, columns that lean toward each other bunch their bottoms further:
            // spread as a first incision's (and held short of a thin part's far side
            // along their new directions).
            for c in even_out_bottoms(&mut new.columns) {
                let col = &mut new.columns[c];
                col.depth = held_short(
                    mesh,
                    &skin,
                    &col.top,
                    &col.inward,
                    col.depth,
                    wound.spacing_m,
                );
            }
        }
        // A wound whose record no longer matches its walls (it cannot happen as the
        // incisions keep their records, but a torn surface would be worse than a shallow
        // wall) is left as it is.
        if changed && wound.lip_edges().all(|e| walls_by_edge.contains_key(&e)) {
            deeper.push((w, new));
        }
    }
    if deeper.is_empty() {
        return None;
    }
    // The old walls of those wounds go, with the vertices only they used (the lips stay:
    // skin and lids use them).
    let lip_edges: HashSet<(u32, u32)> = deeper
        .iter()
        .flat_map(|(w, _)| wounds[*w].lip_edges())
        .collect();
    let removed = faces_inside(mesh, &walls_by_edge, &lip_edges);
    let (mut out, new_id) = without(mesh, kinds, &removed);
    let no_splits = EdgeSplits::new();
    let mut carried: Vec<Wound> = wounds.to_vec();
    for (w, new) in &deeper {
        carried[*w] = new.clone();
    }
    let carried: Option<Vec<Wound>> = carried
        .iter()
        .map(|w| w.renumbered(&new_id, &no_splits))
        .collect();
    let mut carried = carried?;
    let (mut depth_m, mut opening_m, mut length_m): (f64, f64, f64) = (0.0, 0.0, 0.0);
    for (w, _) in &deeper {
        let wound = &mut carried[*w];
        build_walls_choosing_ends(wound, Some(&wounds[*w].columns), &mut out);
        depth_m = depth_m.max(wound.depth_m());
        opening_m = opening_m.max(wound.opening_m);
        length_m = length_m.max(wound.length_m);
    }
    let min_angle_deg = out.min_created_angle_deg();
    let mut result = Incised {
        mesh: TriMesh::new(out.positions, out.triangles),
        kinds: out.kinds,
        source: out.source,
        created: out.created,
        wounds: carried,
        lip_max_turn_deg: 0.0,
        min_angle_deg,
        opening_m,
        depth_m,
        length_m,
    };
    // A wound deepened along most of its length opens as wide as a first pass that deep
    // would have (the lips part with the depth); a notch under a crossing cut does not
    // widen the whole wound. Last wound first: reopening one keeps the others' places.
    for (w, _) in deeper.iter().rev() {
        // (As its walls were built: an end may have been brought to the surface.)
        let built = &result.wounds[*w].columns;
        let deepened = built
            .iter()
            .zip(&wounds[*w].columns)
            .filter(|(n, o)| n.depth > o.depth)
            .count();
        if 2 * deepened < built.len() {
            continue;
        }
        if let Some(mut wider) = reopen(&result, *w, params) {
            wider.source = source_through(&wider.source, &result.source);
            // The figures cover every deepened wound, not only the reopened one.
            if deeper.len() > 1 {
                wider.min_angle_deg = wider.min_angle_deg.min(result.min_angle_deg);
                wider.depth_m = wider.depth_m.max(result.depth_m);
                wider.opening_m = wider.opening_m.max(result.opening_m);
                wider.length_m = wider.length_m.max(result.length_m);
            }
            result = wider;
        }
    }
    Some(result)
}

/// Opens wound `w` of `surface` again as one incision along its columns at their depths —
/// its walls out, its lid back to skin (the lid lies on the surface as it was), and
/// [`incise`] on that — so the opening is the one a first pass that deep would have drawn.
/// `None` if the incision is refused (the caller keeps the walls it rebuilt).
fn reopen(surface: &Incised, w: usize, params: &IncisionParams) -> Option<Incised> {
    let wound = &surface.wounds[w];
    let lip_edges: HashSet<(u32, u32)> = wound.lip_edges().collect();
    let (mesh, kinds) = (&surface.mesh, &surface.kinds);
    let walls = faces_inside(
        mesh,
        &faces_by_edge(mesh, kinds, FaceKind::Wall),
        &lip_edges,
    );
    let lid = faces_inside(mesh, &faces_by_edge(mesh, kinds, FaceKind::Lid), &lip_edges);
    let mut kinds = surface.kinds.clone();
    for (k, &in_lid) in kinds.iter_mut().zip(&lid) {
        if in_lid {
            *k = FaceKind::Skin;
        }
    }
    let (closed, new_id) = without(&surface.mesh, &kinds, &walls);
    let no_splits = EdgeSplits::new();
    let others: Vec<Wound> = surface
        .wounds
        .iter()
        .enumerate()
        .filter(|&(i, _)| i != w)
        .map(|(_, o)| o.renumbered(&new_id, &no_splits))
        .collect::<Option<_>>()?;
    let path: Vec<PathSample> = wound
        .columns
        .iter()
        .map(|c| PathSample {
            surface: c.top,
            bottom: c.bottom(),
        })
        .collect();
    let mesh = TriMesh::new(closed.positions, closed.triangles);
    let mut out = incise(&mesh, &closed.kinds, &others, &path, params).ok()?;
    out.source = source_through(&out.source, &closed.source);
    // The reopened wound back in its place (unless another lost its record on the way).
    let reopened = out.wounds.pop()?;
    if out.wounds.len() != others.len() {
        return None;
    }
    out.wounds.insert(w, reopened);
    Some(out)
}

/// The faces of `kind` by their (unordered) edges.
type FacesByEdge = HashMap<(u32, u32), Vec<usize>>;

fn faces_by_edge(mesh: &TriMesh, kinds: &[FaceKind], kind: FaceKind) -> FacesByEdge {
    let mut by_edge = FacesByEdge::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if kinds[t] == kind {
            for e in 0..3 {
                by_edge
                    .entry(edge_key(tri[e], tri[(e + 1) % 3]))
                    .or_default()
                    .push(t);
            }
        }
    }
    by_edge
}

/// The faces of `by_edge` reached from `lip_edges` across edges between two of them, never
/// across a lip edge: a wound's walls (or its lid), which are joined to nothing else.
fn faces_inside(
    mesh: &TriMesh,
    by_edge: &FacesByEdge,
    lip_edges: &HashSet<(u32, u32)>,
) -> Vec<bool> {
    let mut inside = vec![false; mesh.triangles.len()];
    let mut stack: Vec<usize> = lip_edges
        .iter()
        .filter_map(|e| by_edge.get(e))
        .flatten()
        .copied()
        .collect();
    while let Some(t) = stack.pop() {
        if std::mem::replace(&mut inside[t], true) {
            continue;
        }
        let tri = mesh.triangles[t];
        for e in 0..3 {
            let edge = edge_key(tri[e], tri[(e + 1) % 3]);
            if lip_edges.contains(&edge) {
                continue;
            }
            if let Some(next) = by_edge.get(&edge) {
                stack.extend(next.iter().copied().filter(|&u| !inside[u]));
            }
        }
    }
    inside
}

/// `mesh` without the `removed` faces and the vertices only they used, as an assembly whose
/// `source` points back into `mesh`, and where each vertex of `mesh` went.
fn without(mesh: &TriMesh, kinds: &[FaceKind], removed: &[bool]) -> (Assembly, Vec<Option<u32>>) {
    let mut used = vec![false; mesh.positions.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if !removed[t] {
            tri.iter().for_each(|&v| used[v as usize] = true);
        }
    }
    let mut out = Assembly {
        positions: Vec::with_capacity(mesh.positions.len()),
        source: Vec::with_capacity(mesh.positions.len()),
        triangles: Vec::with_capacity(mesh.triangles.len()),
        kinds: Vec::with_capacity(mesh.triangles.len()),
        created: Vec::new(),
    };
    let mut new_id = vec![None; mesh.positions.len()];
    for (v, p) in mesh.positions.iter().enumerate() {
        if used[v] {
            new_id[v] = Some(out.positions.len() as u32);
            out.positions.push(*p);
            out.source.push(Some(v as u32));
        }
    }
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if !removed[t] {
            // Every corner of a kept face is a kept vertex.
            out.triangles
                .push(tri.map(|v| new_id[v as usize].unwrap_or(u32::MAX)));
            out.kinds.push(kinds[t]);
        }
    }
    (out, new_id)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cut::checks::{check, check_topology, top_path};
    use crate::cut::incision::corners_of_kind;
    use crate::cut::{IncisionParams, incise};
    use crate::geometry::predicates::distance_sq_to_segment;
    use crate::pipeline::script::vertical_extent;
    use crate::scene::BuiltinMesh;

    /// A first incision's floor where a thin part stopped the end column 0.52 mm down
    /// beside columns 3.7 mm deep, 1.84 mm apart (a deltoid stroke: 4.9° wall cells): eased
    /// to 45°, never deeper than it was; a smooth floor is left alone.
    #[test]
    fn a_first_incisions_floor_is_eased_beside_a_shallow_end() {
        let gap = 1.84e-3;
        let columns = |depths_mm: &[f64]| -> Vec<WallColumn> {
            depths_mm
                .iter()
                .enumerate()
                .map(|(c, &d)| WallColumn {
                    param: c as f64 / (depths_mm.len() - 1) as f64,
                    top: Vec3::new(c as f64 * gap, 0.0, 0.0),
                    inward: -Vec3::z(),
                    depth: d * 1e-3,
                })
                .collect()
        };
        let depths = |c: &[WallColumn]| -> Vec<f64> {
            c.iter().map(|c| (c.depth * 1e5).round() / 100.0).collect()
        };
        let mut cut = columns(&[2.81, 3.12, 3.26, 3.25, 3.29, 3.51, 3.65, 3.68, 3.69, 0.52]);
        limit_slope(&mut cut, None, gap);
        assert_eq!(
            depths(&cut),
            vec![2.81, 3.12, 3.26, 3.25, 3.29, 3.51, 3.65, 3.68, 2.36, 0.52]
        );
        let smooth = columns(&[1.0, 2.0, 3.0, 3.5, 3.5, 3.0, 2.0, 1.2]);
        let mut eased = smooth.clone();
        limit_slope(&mut eased, None, gap);
        assert_eq!(eased, smooth);
    }

    /// A straight wound 12 mm long along x with columns 1.2 mm apart straight down, `depths`
    /// deep (mm), and lips 1 mm apart at most, with vertices at `params` along it: the
    /// surface with the lips alone (no triangles yet).
    fn straight_wound(depths_mm: &[f64], params: &[f64]) -> (Wound, Assembly) {
        straight_wound_with(depths_mm, params, params)
    }

    /// The same with the upper and lower lips' vertices at `upper` and `lower`.
    fn straight_wound_with(depths_mm: &[f64], upper: &[f64], lower: &[f64]) -> (Wound, Assembly) {
        let (length, opening) = (0.012, 0.0005);
        let mut out = Assembly {
            positions: Vec::new(),
            source: Vec::new(),
            triangles: Vec::new(),
            kinds: Vec::new(),
            created: Vec::new(),
        };
        let a = out.vertex(Vec3::zeros());
        let b = out.vertex(Vec3::new(length, 0.0, 0.0));
        let lip = |params: &[f64], side: f64, out: &mut Assembly| -> Vec<(f64, u32)> {
            params
                .iter()
                .map(|&t| match t {
                    0.0 => (t, a),
                    1.0 => (t, b),
                    _ => {
                        let half_opening = opening * 4.0 * t * (1.0 - t);
                        (
                            t,
                            out.vertex(Vec3::new(t * length, side * half_opening, 0.0)),
                        )
                    }
                })
                .collect()
        };
        let upper = lip(upper, 1.0, &mut out);
        let lower = lip(lower, -1.0, &mut out);
        let n = depths_mm.len();
        let columns = depths_mm
            .iter()
            .enumerate()
            .map(|(c, &d)| {
                let param = c as f64 / (n - 1) as f64;
                WallColumn {
                    param,
                    top: Vec3::new(param * length, 0.0, 0.0),
                    inward: -Vec3::z(),
                    depth: d * 1e-3,
                }
            })
            .collect();
        let wound = Wound {
            upper,
            lower,
            columns,
            opening_m: opening,
            length_m: length,
            spacing_m: 0.0012,
        };
        (wound, out)
    }

    /// Lip vertices graded to 0.24 mm segments at the ends, as an incision grades them.
    const GRADED_LIPS: [f64; 15] = [
        0.0, 0.02, 0.04, 0.06, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 0.94, 0.96, 0.98, 1.0,
    ];

    /// Lip vertices at the columns.
    const EVEN_LIPS: [f64; 11] = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0];

    /// End columns 0.18 mm deep beside columns 1.2 mm apart (the deltoid's shallow ends).
    const SHALLOW_ENDS: [f64; 11] = [0.18, 1.38, 2.5, 3.0, 3.0, 3.0, 3.0, 3.0, 2.5, 1.38, 0.18];

    /// The walls of `wound` in `out` are two sheets hanging from its lips: every edge of
    /// theirs is used once each way (a lip edge once), and every lip edge is used.
    fn assert_sound_walls(wound: &Wound, out: &Assembly) {
        let mut uses: HashMap<(u32, u32), usize> = HashMap::new();
        for &t in &out.created {
            let tri = out.triangles[t as usize];
            assert!(
                tri[0] != tri[1] && tri[1] != tri[2] && tri[2] != tri[0],
                "{tri:?}"
            );
            for k in 0..3 {
                *uses.entry((tri[k], tri[(k + 1) % 3])).or_default() += 1;
            }
        }
        let lips: HashSet<(u32, u32)> = wound.lip_edges().collect();
        for (&(u, v), &n) in &uses {
            assert_eq!(n, 1, "edge {u}-{v} used {n} times one way");
            let back = uses.contains_key(&(v, u));
            assert_eq!(back, !lips.contains(&edge_key(u, v)), "edge {u}-{v}");
        }
        for (u, v) in lips {
            assert!(uses.contains_key(&(u, v)) || uses.contains_key(&(v, u)));
        }
    }

    /// The smallest angle of the walls `build` gives the straight wound with its columns as
    /// they are (checked sound).
    fn walls_built_by(
        depths_mm: &[f64],
        lips: &[f64],
        build: impl Fn(&Wound, &mut Assembly),
    ) -> f64 {
        let (wound, mut out) = straight_wound(depths_mm, lips);
        build(&wound, &mut out);
        assert_sound_walls(&wound, &out);
        out.min_created_angle_deg()
    }

    /// The straight wound as [`build_walls_choosing_ends`] leaves it, and its walls'
    /// smallest angle (checked sound).
    fn walls_chosen(depths_mm: &[f64], lips: &[f64], old: Option<&[WallColumn]>) -> (Wound, f64) {
        let (mut wound, mut out) = straight_wound(depths_mm, lips);
        build_walls_choosing_ends(&mut wound, old, &mut out);
        assert_sound_walls(&wound, &out);
        let angle = out.min_created_angle_deg();
        (wound, angle)
    }

    /// The wound's column depths (mm, to a hundredth).
    fn depths_mm(wound: &Wound) -> Vec<f64> {
        wound
            .columns
            .iter()
            .map(|c| (c.depth * 1e5).round() / 100.0)
            .collect()
    }

    /// Shallow end columns under lips graded at the ends: as gridded on the wound's
    /// columns the walls' end cells are slivers (3.5°: the end columns' two rows 0.09 mm
    /// tall, and the short lip segments zipped to a row a gap away). With columns graded
    /// like the lips near the ends and the walls flipped to their better diagonals, none
    /// is under 19°, the walls are sound and the floor is kept.
    #[test]
    fn wall_columns_are_graded_like_the_lips_at_the_ends() {
        let before = walls_built_by(&SHALLOW_ENDS, &GRADED_LIPS, |wound, out| {
            build_wall_grids(wound, &wound.columns, false, out);
        });
        assert!(before < 5.0, "{before}");
        let (chosen, after) = walls_chosen(&SHALLOW_ENDS, &GRADED_LIPS, None);
        assert!(after >= 19.0, "{before}° → {after}°");
        assert_eq!(depths_mm(&chosen), SHALLOW_ENDS);
    }

    /// Shallow end columns under lips with no short segments: as gridded (and flipped) the
    /// end columns' rows make slivers; ended at the surface, the floor rising to the ends
    /// at 45°, the walls fan from the end vertices with no cell under 18°. Ends deeper than
    /// three quarters of a gap are kept (their rows make fine cells), as is a floor that
    /// was deeper there before (a deeper pass never raises a wall).
    #[test]
    fn shallow_wall_ends_rise_to_the_surface_where_that_shapes_the_cells_better() {
        let before = walls_built_by(&SHALLOW_ENDS, &EVEN_LIPS, build_walls);
        assert!(before < 10.0, "{before}");
        let (chosen, after) = walls_chosen(&SHALLOW_ENDS, &EVEN_LIPS, None);
        assert!(after >= 18.0, "{before}° → {after}°");
        assert_eq!(
            depths_mm(&chosen),
            [0.0, 1.2, 2.4, 3.0, 3.0, 3.0, 3.0, 3.0, 2.4, 1.2, 0.0]
        );

        let deeper = [0.95, 1.38, 2.5, 3.0, 3.0, 3.0, 3.0, 3.0, 2.5, 1.38, 0.95];
        let (kept, angle) = walls_chosen(&deeper, &EVEN_LIPS, None);
        assert_eq!(depths_mm(&kept), deeper);
        assert!(angle >= 18.0, "{angle}");

        let old = straight_wound(&[0.1; 11], &EVEN_LIPS).0.columns;
        let (held, _) = walls_chosen(&SHALLOW_ENDS, &EVEN_LIPS, Some(&old));
        for (new, old) in held.columns.iter().zip(&old) {
            assert!(new.depth >= old.depth, "{:?}", depths_mm(&held));
        }
    }

    /// An end at the surface beside columns graded like the lips, also under lips whose
    /// vertices differ (one graded at its ends, one not), each end and both: two sound
    /// sheets, no cell near a line (7.2° at worst here; the walls' choice of ends, which
    /// weighs the cells, is not asked). Before the lip zip left an end vertex along the lip
    /// first, a coarse lip beside columns graded to the other drew cells of three points
    /// on a line.
    #[test]
    fn walls_ending_at_the_surface_beside_graded_columns_are_sound() {
        let ends = [
            [0.0, 1.2, 2.4, 3.0, 3.0, 3.0, 3.0, 3.0, 2.4, 1.2, 0.0],
            [0.0, 1.2, 2.4, 3.0, 3.0, 3.0, 3.0, 3.0, 2.5, 1.38, 0.9],
            [0.9, 1.38, 2.5, 3.0, 3.0, 3.0, 3.0, 3.0, 2.4, 1.2, 0.0],
        ];
        for depths in ends {
            for (upper, lower) in [
                (&GRADED_LIPS[..], &GRADED_LIPS[..]),
                (&GRADED_LIPS[..], &EVEN_LIPS[..]),
                (&EVEN_LIPS[..], &GRADED_LIPS[..]),
            ] {
                let (wound, mut out) = straight_wound_with(&depths, upper, lower);
                build_walls(&wound, &mut out);
                assert_sound_walls(&wound, &out);
                let angle = out.min_created_angle_deg();
                assert!(angle > 5.0, "{depths:?}: {angle}");
            }
        }
    }

    /// Columns whose lean turns quickly bring two bottoms within 0.04 of a gap of each
    /// other — on a straight path, and on a curved one whose bottoms are spread more widely
    /// than its tops: spread out, the bunched gap is at least a third of the others, the
    /// bottoms stay in order along the path, on the old bottom curve where they reached
    /// their place, and every column turns by at most 15°; columns away from the bunch,
    /// the end columns and all tops are kept. Evenly spread bottoms are left alone. On a
    /// shallow wall the way to its place would turn a column by more: it goes as far as 15°.
    #[test]
    fn bunched_column_bottoms_are_spread_along_their_curve() {
        let column = |top: Vec3, lean: Vec3, depth: f64| WallColumn {
            param: 0.0,
            top,
            inward: (lean - Vec3::z()).normalize(),
            depth: depth * (1.0 + lean.norm_squared()).sqrt(),
        };
        let gap = |c: &[WallColumn], k: usize| (c[k + 1].bottom() - c[k].bottom()).norm();
        let turn = |a: &WallColumn, b: &WallColumn| a.inward.angle(&b.inward).to_degrees();
        // Tops 1 mm apart along x, or on a 10 mm arc; 3 mm deep, leaning outward on the
        // arc (bottoms further apart than tops); columns 4 and 5 lean toward each other.
        for curved in [false, true] {
            let original: Vec<WallColumn> = (0..11)
                .map(|k| {
                    let (top, out) = if curved {
                        let a = 0.1 * k as f64;
                        (
                            Vec3::new(0.01 * a.sin(), 0.01 * a.cos(), 0.0),
                            Vec3::new(a.sin(), a.cos(), 0.0),
                        )
                    } else {
                        (Vec3::new(0.001 * k as f64, 0.0, 0.0), Vec3::zeros())
                    };
                    let tangent = out
                        .cross(&Vec3::z())
                        .try_normalize(1e-12)
                        .unwrap_or(Vec3::x());
                    // (0.48 mm along the path either way, 0.51 on the arc, whose bottoms
                    // are 6 % further apart.)
                    let toward = if curved { 0.17 } else { 0.16 };
                    let lean = match k {
                        4 => tangent * toward,
                        5 => -tangent * toward,
                        _ => Vec3::zeros(),
                    } + out * 0.2;
                    column(top, lean, 0.003)
                })
                .collect();
            assert!(gap(&original, 4) < 0.0001, "curved {curved}");
            let mut columns = original.clone();
            assert_eq!(even_out_bottoms(&mut columns), [4, 5]);
            let others = (0..10).filter(|&k| k != 4).map(|k| gap(&original, k));
            let least_other = others.fold(f64::INFINITY, f64::min);
            assert!(gap(&columns, 4) >= least_other / 3.0, "curved {curved}");
            let old_bottoms: Vec<Vec3> = original.iter().map(WallColumn::bottom).collect();
            let mut along = f64::NEG_INFINITY;
            for (k, c) in columns.iter().enumerate() {
                assert_eq!(c.top, original[k].top);
                assert!(turn(c, &original[k]) <= 15.0 + 1e-9, "column {k}");
                // In order: each bottom further along the path than the one before.
                let a = if curved {
                    c.bottom().x.atan2(c.bottom().y)
                } else {
                    c.bottom().x
                };
                assert!(a > along, "column {k} out of order");
                along = a;
                if turn(c, &original[k]) < 15.0 - 1e-6 {
                    let on_curve = old_bottoms
                        .windows(2)
                        .map(|w| distance_sq_to_segment(&c.bottom(), &w[0], &w[1]).sqrt())
                        .fold(f64::INFINITY, f64::min);
                    assert!(on_curve < 1e-12, "column {k} off the curve by {on_curve}");
                }
            }
            for k in [0, 1, 2, 7, 8, 9, 10] {
                assert_eq!(columns[k], original[k], "column {k} moved");
            }
        }
        // Even bottoms: nothing to do.
        let even: Vec<WallColumn> = (0..11)
            .map(|k| column(Vec3::new(0.001 * k as f64, 0.0, 0.0), Vec3::zeros(), 0.003))
            .collect();
        let mut kept = even.clone();
        assert!(even_out_bottoms(&mut kept).is_empty());
        assert_eq!(kept, even);
        // A wall 0.5 mm deep whose two middle bottoms crossed 0.8 mm along the path: the way
        // back under their tops is a turn of about 60°; they turn 15° toward it.
        let mut shallow: Vec<WallColumn> = (0..11)
            .map(|k| {
                let lean = match k {
                    4 => Vec3::x() * 1.6,
                    5 => -Vec3::x() * 1.6,
                    _ => Vec3::zeros(),
                };
                column(Vec3::new(0.001 * k as f64, 0.0, 0.0), lean, 0.0005)
            })
            .collect();
        let before = shallow.clone();
        assert!(!even_out_bottoms(&mut shallow).is_empty());
        for k in [4, 5] {
            assert!(
                (turn(&shallow[k], &before[k]) - 15.0).abs() < 1e-6,
                "column {k}"
            );
        }
    }

    /// The liver with a 60 mm incision 4 mm deep along y = 0.
    fn first_pass() -> (TriMesh, Incised) {
        let liver = BuiltinMesh::Liver.generate();
        let kinds = vec![FaceKind::Skin; liver.triangles.len()];
        let path = top_path(&liver, [-0.03, 0.0], [0.03, 0.0], 0.004);
        let out = incise(&liver, &kinds, &[], &path, &IncisionParams::default()).expect("incision");
        (liver, out)
    }

    /// `deepen` on an incised surface with the default parameters.
    fn deepen_on(surface: &Incised, path: &[PathSample]) -> Option<Incised> {
        let params = IncisionParams::default();
        deepen(
            &surface.mesh,
            &surface.kinds,
            &surface.wounds,
            path,
            &params,
        )
    }

    /// How far the walls reach below the organ's top within 2 mm of x (m).
    fn wall_depth_at(liver: &TriMesh, out: &Incised, x: f64) -> f64 {
        let (top, _) = vertical_extent(liver, x, 0.0).expect("surface above");
        corners_of_kind(&out.mesh, &out.kinds, FaceKind::Wall)
            .filter(|p| (p.x - x).abs() < 2e-3)
            .map(|p| top - p.z)
            .fold(0.0, f64::max)
    }

    /// The skin and lid faces, as corner positions: what a deeper pass must not touch.
    fn outside(out: &Incised) -> Vec<[Vec3; 3]> {
        (0..out.mesh.triangles.len())
            .filter(|&t| out.kinds[t] != FaceKind::Wall)
            .map(|t| out.mesh.corners(t))
            .collect()
    }

    #[test]
    fn a_deeper_pass_along_the_wound_takes_its_walls_down_and_opens_it_wider() {
        let (liver, first) = first_pass();
        assert_eq!(first.wounds.len(), 1);
        assert!((wall_depth_at(&liver, &first, 0.0) - 0.004).abs() < 5e-4);
        let deeper = top_path(&liver, [-0.03, 0.0], [0.03, 0.0], 0.01);
        let out = deepen_on(&first, &deeper).expect("deeper walls");
        check(&out, "deepened");
        for x in [-0.02, 0.0, 0.02] {
            let d = wall_depth_at(&liver, &out, x);
            assert!((d - 0.01).abs() < 5e-4, "at {x}: {d}");
        }
        // The lips part as a first pass 10 mm deep would have opened them: k_open × 10 mm,
        // less the little the re-meshed region's margin takes (a first pass 1.2 mm).
        assert_eq!(out.wounds.len(), 1);
        assert!((first.wounds[0].opening_m - 0.0012).abs() < 1e-5);
        let opening = out.wounds[0].opening_m;
        assert!(opening > 0.0025 && opening <= 0.003 + 1e-9, "{opening}");
        assert!((out.wounds[0].depth_m() - 0.01).abs() < 1e-3);
        // Every vertex that stayed is where it was.
        for (v, s) in out.source.iter().enumerate() {
            if let Some(s) = s {
                assert_eq!(out.mesh.positions[v], first.mesh.positions[*s as usize]);
            }
        }
    }

    #[test]
    fn a_deeper_pass_along_part_of_the_wound_deepens_that_part() {
        let (liver, first) = first_pass();
        let deeper = top_path(&liver, [-0.01, 0.0], [0.01, 0.0], 0.01);
        let out = deepen_on(&first, &deeper).expect("deeper walls");
        check(&out, "partly deepened");
        let d = |x| wall_depth_at(&liver, &out, x);
        assert!((d(0.0) - 0.01).abs() < 5e-4, "{}", d(0.0));
        assert!((d(-0.02) - 0.004).abs() < 5e-4, "{}", d(-0.02));
        assert!((d(0.02) - 0.004).abs() < 5e-4, "{}", d(0.02));
        // A third of the wound deepened: the lips stay (the opening is the first pass's).
        assert_eq!(outside(&out), outside(&first));
        // And again, deeper still over the middle: the walls of a deepened wound deepen.
        let again = top_path(&liver, [-0.005, 0.0], [0.005, 0.0], 0.015);
        let out2 = deepen_on(&out, &again).expect("deeper again");
        check(&out2, "deepened twice");
        assert!((wall_depth_at(&liver, &out2, 0.0) - 0.015).abs() < 5e-4);
        assert!((wall_depth_at(&liver, &out2, -0.008) - 0.01).abs() < 5e-4);
    }

    #[test]
    fn a_deeper_cut_across_the_wound_notches_its_walls() {
        let (liver, first) = first_pass();
        // The part of a crossing cut over the wound (the rest opens incisions of its own).
        let across = top_path(&liver, [0.0, -0.004], [0.0, 0.004], 0.01);
        let out = deepen_on(&first, &across).expect("notch");
        check(&out, "notched");
        // The walls are gridded by columns a few millimetres apart: the crossing shows as a
        // V eased down from the old floor at 45° (7.1 mm deep here, where the blade went
        // 10 mm), the rest of the wound as it was.
        let notch = wall_depth_at(&liver, &out, 0.0);
        assert!(notch > 0.0065 && notch <= 0.0105, "{notch}");
        assert!((wall_depth_at(&liver, &out, 0.015) - 0.004).abs() < 5e-4);
    }

    #[test]
    fn a_wound_whose_lip_a_later_incision_split_still_deepens_soundly() {
        // Cuts that come up to the wound from the side and stop just short of its lip: their
        // re-meshed region reaches the lip, and the refinement puts vertices on it, which
        // the wound's record must take in (or the rebuilt walls would leave the lip edges
        // it split open).
        let (liver, first) = first_pass();
        let lip_vertices = |w: &Wound| w.upper.len() + w.lower.len();
        let mut split = 0;
        for x in [-0.02, -0.012, -0.004, 0.004, 0.012, 0.02] {
            let stop = -(first.opening_m + 0.0005);
            let beside = top_path(&liver, [x, -0.03], [x, stop], 0.004);
            let params = IncisionParams::default();
            let Ok(second) = incise(&first.mesh, &first.kinds, &first.wounds, &beside, &params)
            else {
                continue;
            };
            check_topology(&second, "beside");
            assert_eq!(second.wounds.len(), 2);
            if lip_vertices(&second.wounds[0]) > lip_vertices(&first.wounds[0]) {
                split += 1;
            }
            let deeper = top_path(&liver, [-0.03, 0.0], [0.03, 0.0], 0.01);
            let out = deepen_on(&second, &deeper).expect("deeper");
            // Sound, though not well shaped: a split a fraction of a column from a lip
            // vertex makes a short lip segment, and the wall cell under it a sliver.
            check_topology(&out, "deepened after a cut beside it");
            assert!((wall_depth_at(&liver, &out, 0.0) - 0.01).abs() < 5e-4);
        }
        assert!(
            split > 0,
            "no later incision split a lip: the case is not exercised"
        );
    }

    /// A wound whose columns lean toward each other over a few gaps, as a tilted blade's
    /// over a hump leave them (a deeper pass on the deltoid drew bottoms 0.40 mm apart
    /// under tops 1.6 mm apart there, 12.1° floor cells): a deeper pass over that part,
    /// 10 mm down, draws bottoms 1.0 and 0.72 mm apart under tops 2.86 mm apart — not
    /// bunched as a share of a bottom curve that is drawn together itself, and 12.0°
    /// floor cells as they were. Spread as a first incision's are, the walls keep the
    /// bound.
    #[test]
    fn a_deeper_pass_under_columns_leaning_together_spreads_their_bottoms() {
        let (liver, mut first) = first_pass();
        let gap = first.wounds[0].column_gap_m();
        let cols = &mut first.wounds[0].columns;
        let middle: Vec<usize> = (0..cols.len())
            .filter(|&c| cols[c].top.x.abs() < 0.008)
            .collect();
        // Leaning along the path, x per unit depth.
        let leans = [0.35, 0.35, 0.12, -0.11, -0.34, -0.34];
        assert_eq!(middle.len(), leans.len());
        for (&c, lean) in middle.iter().zip(leans) {
            cols[c].inward = (Vec3::x() * lean - Vec3::z()).normalize();
        }
        let pass = top_path(&liver, [-0.01, 0.0], [0.01, 0.0], 0.01);
        let out = deepen_on(&first, &pass).expect("deeper");
        check(&out, "deepened under leaning columns");
        let cols = &out.wounds[0].columns;
        let least = cols
            .windows(2)
            .map(|w| (w[1].bottom() - w[0].bottom()).norm())
            .fold(f64::INFINITY, f64::min);
        assert!(least > 0.4 * gap, "{least} under tops {gap} apart");
    }

    #[test]
    fn a_pass_no_deeper_than_the_walls_changes_nothing() {
        let (liver, first) = first_pass();
        let shallow = top_path(&liver, [-0.03, 0.0], [0.03, 0.0], 0.004);
        assert!(deepen_on(&first, &shallow).is_none());
        // Nor does a deeper pass beside the wound, clear of its lips.
        let beside = top_path(&liver, [-0.03, 0.012], [0.03, 0.012], 0.01);
        assert!(deepen_on(&first, &beside).is_none());
    }
}
