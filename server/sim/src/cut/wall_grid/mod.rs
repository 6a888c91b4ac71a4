//! Wound walls as grids: two strips, one from each lip down to the shared bottom curve,
//! gridded column by column, each column with as many rows as its depth needs — so a wound
//! that is shallow in one place and deep in another keeps well-shaped cells in both — with
//! their ends chosen, their bottoms spread and their floor eased, and a thin part's far side
//! kept clear.

use crate::geometry::TriMesh;
use crate::geometry::predicates::{line_triangle, nearest_on_segment};
use crate::math::{Aabb, Vec3};

use super::blade::PathSample;
use super::cells::{FaceKind, flip_to_surface_quality};
use super::wound::{Assembly, WallColumn, Wound};
use zip::{Columns, OneWall, end_column};

mod zip;

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
    // The end columns, rows 1 ..= rows, shared.
    let end0 = end_column(a_id, rows[0], &cols[0], out);
    let end1 = end_column(b_id, rows[n - 1], &cols[n - 1], out);
    let mut bottoms = vec![end0[end0.len() - 1]];
    for c in cols.iter().take(n - 1).skip(1) {
        bottoms.push(out.vertex(c.bottom()));
    }
    bottoms.push(end1[end1.len() - 1]);
    let columns = Columns {
        cols,
        rows,
        ends: [end0, end1],
        bottoms,
    };
    for (lip, side) in [(&wound.upper, 1.0), (&wound.lower, -1.0)] {
        let wall = OneWall::new(lip, side, &columns, out);
        let in_step = wall.strip(false, out);
        let lenient = wall.strip(true, out);
        differs |= lenient != in_step;
        let cells = if out_of_turn { lenient } else { in_step };
        for tri in cells {
            wall.emit(tri, true, out);
        }
        wall.zip_columns(out);
    }
    let [end0, end1] = &columns.ends;
    let mut shared: Vec<u32> = end0
        .iter()
        .chain(end1)
        .chain(&columns.bottoms)
        .copied()
        .collect();
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
pub(crate) fn path_cut_near(
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

#[cfg(test)]
mod tests;
