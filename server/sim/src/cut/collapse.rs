//! Edge collapses that remove a new vertex where it spoils the cells around it on the
//! surface itself. physics.md §5.2 step 7 collapses tiny triangles away from the region's
//! boundary; here the measure is the smallest angle on the surface, and a split of the
//! boundary may slide along its edge (the triangle beyond is fanned afterwards).
//!
//! The incision region is triangulated to the angle limit in its chart (super::chart: a
//! conformal map, or where that fails the projection onto one plane); the refinement may
//! split an edge of its boundary a fraction of a millimetre from a corner, and the cells on
//! that short piece, lifted back onto a curved or steep face, lose much of their smallest
//! angle (the tumour's default cut, in the projection the region was once triangulated in:
//! 27.4° in the plane, 10.3° on the surface). Collapsing the
//! new vertex into its neighbour — along the boundary edge it lies on, so the triangles
//! outside the region keep their plane — removes the short piece.

use std::collections::{HashMap, HashSet};

use crate::math::Vec3;

use super::cells::{FaceKind, cell_min_angle_deg, cell_normal};
use super::fan::plan_fan;

/// Cells whose smallest angle is under this are worked on.
const COLLAPSE_BELOW_DEG: f64 = 20.0;
/// A collapse must raise the smallest angle around the vertex by this much.
const COLLAPSE_GAIN_DEG: f64 = 1.0;
/// Largest turn of a cell's normal that a collapse may cause (as for flips).
const COLLAPSE_MAX_TURN_DEG: f64 = 30.0;

/// Keeps the items of `items` whose index `keep` says.
fn retain_indexed<T>(items: &mut Vec<T>, keep: impl Fn(usize) -> bool) {
    let mut i = 0;
    items.retain(|_| {
        i += 1;
        keep(i - 1)
    });
}

/// The new index of every item `kept` says stays (`u32::MAX` for the others).
fn renumbering(kept: &[bool]) -> Vec<u32> {
    let mut next = 0;
    kept.iter()
        .map(|&k| {
            if k {
                next += 1;
                next - 1
            } else {
                u32::MAX
            }
        })
        .collect()
}

/// Drops the collapsed vertices `gone` from `positions` and `source`; the new id of every
/// vertex (`u32::MAX` for the dropped ones).
pub(crate) fn drop_vertices(
    gone: &HashSet<u32>,
    positions: &mut Vec<Vec3>,
    source: &mut Vec<Option<u32>>,
) -> Vec<u32> {
    let kept: Vec<bool> = (0..positions.len())
        .map(|v| !gone.contains(&(v as u32)))
        .collect();
    let new_id = renumbering(&kept);
    retain_indexed(positions, |v| new_id[v] != u32::MAX);
    retain_indexed(source, |v| new_id[v] != u32::MAX);
    new_id
}

/// Collapses vertices of `movable` (new vertices strictly inside the region, all of whose
/// cells are created skin) into a neighbour where that raises the smallest angle around
/// them, worst cells first. Removes the two cells on each collapsed edge from `triangles`,
/// `kinds` and `created` (indices kept consistent) and returns the collapsed vertices with
/// where they went; the caller drops them ([`drop_vertices`]).
pub(crate) fn collapse_to_quality(
    positions: &[Vec3],
    triangles: &mut Vec<[u32; 3]>,
    kinds: &mut Vec<FaceKind>,
    created: &mut Vec<u32>,
    movable: &HashSet<u32>,
) -> Vec<(u32, u32)> {
    let smallest = |tri: [u32; 3]| cell_min_angle_deg(positions, tri);
    let normal = |tri: [u32; 3]| cell_normal(positions, tri);
    // Cells around every vertex of a created cell (an old vertex's old cells included: the
    // link test needs its whole neighbourhood).
    let mut star: HashMap<u32, Vec<u32>> = HashMap::new();
    for &t in created.iter() {
        for v in triangles[t as usize] {
            star.entry(v).or_default();
        }
    }
    for (t, tri) in triangles.iter().enumerate() {
        for v in tri {
            if let Some(list) = star.get_mut(v) {
                list.push(t as u32);
            }
        }
    }
    let mut alive = vec![true; triangles.len()];
    let neighbours = |v: u32, star: &HashMap<u32, Vec<u32>>, triangles: &[[u32; 3]]| {
        let mut out: HashSet<u32> = HashSet::new();
        for &t in &star[&v] {
            out.extend(triangles[t as usize].iter().copied().filter(|&w| w != v));
        }
        out
    };
    let max_turn = COLLAPSE_MAX_TURN_DEG.to_radians().cos();
    // The smallest angle around v after collapsing it into u, if the collapse is allowed.
    let evaluate = |v: u32, u: u32, star: &HashMap<u32, Vec<u32>>, triangles: &[[u32; 3]]| {
        let cells = &star[&v];
        if cells.iter().any(|&t| kinds[t as usize] != FaceKind::Skin) {
            return None;
        }
        let on_edge: Vec<u32> = cells
            .iter()
            .copied()
            .filter(|&t| triangles[t as usize].contains(&u))
            .collect();
        if on_edge.len() != 2 {
            return None;
        }
        // Link condition: v and u share exactly the two far corners of the cells on their
        // edge, or the collapse would pinch the surface.
        let apexes: HashSet<u32> = on_edge
            .iter()
            .flat_map(|&t| triangles[t as usize])
            .filter(|&w| w != v && w != u)
            .collect();
        let common: HashSet<u32> = neighbours(v, star, triangles)
            .intersection(&neighbours(u, star, triangles))
            .copied()
            .collect();
        if common != apexes || apexes.len() != 2 {
            return None;
        }
        let mut after = f64::INFINITY;
        for &t in cells.iter().filter(|t| !on_edge.contains(t)) {
            let old = triangles[t as usize];
            let new = old.map(|w| if w == v { u } else { w });
            let (Some(n_old), Some(n_new)) = (normal(old), normal(new)) else {
                return None;
            };
            if n_old.dot(&n_new) < max_turn {
                return None;
            }
            after = after.min(smallest(new));
        }
        Some(after)
    };

    let mut collapsed = Vec::new();
    for _pass in 0..4 {
        let mut worst: Vec<(f64, u32)> = created
            .iter()
            .filter(|&&t| alive[t as usize] && kinds[t as usize] == FaceKind::Skin)
            .map(|&t| (smallest(triangles[t as usize]), t))
            .filter(|&(a, _)| a < COLLAPSE_BELOW_DEG)
            .collect();
        worst.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut changed = false;
        for (_, t) in worst {
            if !alive[t as usize] {
                continue;
            }
            let mut best: Option<(f64, u32, u32)> = None;
            for v in triangles[t as usize] {
                if !movable.contains(&v) {
                    continue;
                }
                let before = star[&v]
                    .iter()
                    .map(|&c| smallest(triangles[c as usize]))
                    .fold(f64::INFINITY, f64::min);
                let mut targets: Vec<u32> = neighbours(v, &star, triangles).into_iter().collect();
                targets.sort_unstable();
                for u in targets {
                    if let Some(after) = evaluate(v, u, &star, triangles)
                        && after > before + COLLAPSE_GAIN_DEG
                        && best.is_none_or(|b| after > b.0)
                    {
                        best = Some((after, v, u));
                    }
                }
            }
            let Some((_, v, u)) = best else {
                continue;
            };
            let cells = star.remove(&v).unwrap_or_default();
            collapse_cells(v, u, &cells, triangles, &mut alive, &mut star);
            collapsed.push((v, u));
            changed = true;
        }
        if !changed {
            break;
        }
    }
    drop_dead(triangles, kinds, created, &alive);
    collapsed
}

/// A triangle outside the region whose edges got new vertices (`splits[e]` on the edge
/// from corner e to e + 1, in order); covered by [`super::fan::plan_fan`] once the splits
/// are settled.
#[derive(Debug, Clone)]
pub(crate) struct SplitTriangle {
    pub corners: [u32; 3],
    pub splits: [Vec<u32>; 3],
    pub kind: FaceKind,
}

/// Collapses vertices the refinement put on the region's boundary into the next vertex
/// along the same original edge where that raises the smallest angle of the region's cells
/// around them together with the fan that will cover the skin triangle beyond (worst
/// first). Sliding along the edge keeps the triangle beyond in its plane; its split is
/// dropped from `outside`. Call before the triangles in `outside` are fanned: `triangles`
/// holds the region's cells and the unsplit rest. Returns the collapsed vertices with where
/// they went; the removed cells are dropped as in [`collapse_to_quality`].
pub(crate) fn collapse_boundary_splits(
    positions: &[Vec3],
    triangles: &mut Vec<[u32; 3]>,
    kinds: &mut Vec<FaceKind>,
    created: &mut Vec<u32>,
    outside: &mut [SplitTriangle],
) -> Vec<(u32, u32)> {
    let mut cells_at = cells_at_splits(outside, created, triangles);
    let mut owner = edge_owners(triangles, outside);
    let mut alive = vec![true; triangles.len()];
    let mut collapsed = Vec::new();
    for _pass in 0..8 {
        // (quality around the split, triangle beyond, edge, index on the edge)
        let mut worst: Vec<(Quality, usize, usize, usize)> = Vec::new();
        for (o, out) in outside.iter().enumerate() {
            if out.kind != FaceKind::Skin {
                continue;
            }
            for e in 0..3 {
                for (i, &v) in out.splits[e].iter().enumerate() {
                    let around =
                        quality_around(positions, out, &out.splits, &cells_at[&v], triangles);
                    if around.min < COLLAPSE_BELOW_DEG {
                        worst.push((around, o, e, i));
                    }
                }
            }
        }
        worst.sort_by(|a, b| a.0.min.total_cmp(&b.0.min));
        let mut changed = false;
        // One change per triangle beyond and pass: the indices of its splits move.
        let mut touched: HashSet<usize> = HashSet::new();
        for (_, o, e, i) in worst {
            if touched.contains(&o) {
                continue;
            }
            let out = &outside[o];
            let chain = &out.splits[e];
            let v = chain[i];
            let prev = if i == 0 { out.corners[e] } else { chain[i - 1] };
            let next = chain
                .get(i + 1)
                .copied()
                .unwrap_or(out.corners[(e + 1) % 3]);
            let cells = &cells_at[&v];
            // As things are now: a collapse at a neighbouring split may have changed them.
            let before = quality_around(positions, out, &out.splits, cells, triangles);
            let mut fewer = out.splits.clone();
            fewer[e].remove(i);
            let fan_after = quality_around(positions, out, &fewer, &[], triangles);
            let slide = Slide {
                positions,
                triangles,
                kinds,
                owner: &owner,
                cells,
                v,
            };
            let Some(u) = slide.best_target([prev, next], fan_after, &before) else {
                continue;
            };
            touched.insert(o);
            // All the old edges out first, then the new ones in: a dead cell's edge may be
            // the very edge a live one takes.
            let cells = cells_at.remove(&v).unwrap_or_default();
            for &c in &cells {
                let tri = triangles[c as usize];
                for k in 0..3 {
                    owner.remove(&(tri[k], tri[(k + 1) % 3]));
                }
            }
            for c in collapse_cells(v, u, &cells, triangles, &mut alive, &mut cells_at) {
                let new = triangles[c as usize];
                for k in 0..3 {
                    owner.insert((new[k], new[(k + 1) % 3]), c);
                }
            }
            // The ring beyond loses v.
            owner.remove(&(prev, v));
            owner.remove(&(v, next));
            owner.insert((prev, next), BEYOND);
            outside[o].splits[e].remove(i);
            collapsed.push((v, u));
            changed = true;
        }
        if !changed {
            break;
        }
    }
    drop_dead(triangles, kinds, created, &alive);
    collapsed
}

/// The owner standing for a triangle beyond the region that is not fanned yet.
const BEYOND: u32 = u32::MAX;

/// The region's cells at each split vertex of the triangles `outside`.
fn cells_at_splits(
    outside: &[SplitTriangle],
    created: &[u32],
    triangles: &[[u32; 3]],
) -> HashMap<u32, Vec<u32>> {
    let mut cells_at: HashMap<u32, Vec<u32>> = HashMap::new();
    for o in outside {
        for &v in o.splits.iter().flatten() {
            cells_at.entry(v).or_default();
        }
    }
    for &t in created {
        for v in triangles[t as usize] {
            if let Some(list) = cells_at.get_mut(&v) {
                list.push(t);
            }
        }
    }
    cells_at
}

/// Who owns each directed edge. The triangles beyond are not fanned yet: their rings
/// stand for them (owner [`BEYOND`]), so a region cell cannot take an edge one of their
/// cells will have.
fn edge_owners(triangles: &[[u32; 3]], outside: &[SplitTriangle]) -> HashMap<(u32, u32), u32> {
    let mut owner: HashMap<(u32, u32), u32> = HashMap::new();
    for (t, tri) in triangles.iter().enumerate() {
        for k in 0..3 {
            owner.insert((tri[k], tri[(k + 1) % 3]), t as u32);
        }
    }
    for out in outside {
        let ring: Vec<u32> = (0..3)
            .flat_map(|e| std::iter::once(out.corners[e]).chain(out.splits[e].iter().copied()))
            .collect();
        for k in 0..ring.len() {
            owner.insert((ring[k], ring[(k + 1) % ring.len()]), BEYOND);
        }
    }
    owner
}

/// The quality of the fan the triangle beyond gets with `splits`, together with the
/// region's `cells` (at a split).
fn quality_around(
    positions: &[Vec3],
    out: &SplitTriangle,
    splits: &[Vec<u32>; 3],
    cells: &[u32],
    triangles: &[[u32; 3]],
) -> Quality {
    Quality::of(plan_fan(positions, out.corners, splits).angles(positions)).with(
        cells
            .iter()
            .map(|&c| cell_min_angle_deg(positions, triangles[c as usize])),
    )
}

/// Split `v` on the region's boundary sliding into a neighbour along its original edge.
struct Slide<'a> {
    positions: &'a [Vec3],
    triangles: &'a [[u32; 3]],
    kinds: &'a [FaceKind],
    owner: &'a HashMap<(u32, u32), u32>,
    /// The region's cells at `v`.
    cells: &'a [u32],
    v: u32,
}

impl Slide<'_> {
    /// The neighbour among `targets` whose collapse improves most on `before` (the fan
    /// beyond without `v` scoring `fan_after`): the cells must all be skin, exactly one
    /// of them on the edge to it, none may turn by more than the collapse limit, and no
    /// directed edge may be taken twice.
    fn best_target(&self, targets: [u32; 2], fan_after: Quality, before: &Quality) -> Option<u32> {
        let max_turn = COLLAPSE_MAX_TURN_DEG.to_radians().cos();
        let (positions, triangles, cells, v) = (self.positions, self.triangles, self.cells, self.v);
        let mut best: Option<(Quality, u32)> = None;
        'target: for u in targets {
            let on_edge: Vec<u32> = cells
                .iter()
                .copied()
                .filter(|&c| triangles[c as usize].contains(&u))
                .collect();
            if on_edge.len() != 1
                || cells
                    .iter()
                    .any(|&c| self.kinds[c as usize] != FaceKind::Skin)
            {
                continue;
            }
            let mut after = fan_after;
            let mut new_edges: HashSet<(u32, u32)> = HashSet::new();
            for &c in cells.iter().filter(|&&c| c != on_edge[0]) {
                let old = triangles[c as usize];
                let new = old.map(|w| if w == v { u } else { w });
                let (Some(n_old), Some(n_new)) =
                    (cell_normal(positions, old), cell_normal(positions, new))
                else {
                    continue 'target;
                };
                if n_old.dot(&n_new) < max_turn {
                    continue 'target;
                }
                // Each directed edge once, or the surface would pinch at u.
                for k in 0..3 {
                    let edge = (new[k], new[(k + 1) % 3]);
                    let taken = self.owner.get(&edge).is_some_and(|&t| !cells.contains(&t));
                    if taken || !new_edges.insert(edge) {
                        continue 'target;
                    }
                }
                after = after.with([cell_min_angle_deg(positions, new)]);
            }
            if after.improves_on(before) && best.is_none_or(|b| after.improves_on(&b.0)) {
                best = Some((after, u));
            }
        }
        best.map(|(_, u)| u)
    }
}

/// Collapses v into u over v's `cells`: the cells on edge v–u die and leave every list in
/// `lists` they are on (a corner cell can hold two boundary splits), the others take u for v
/// and join u's list (if it has one). The cells that took u.
fn collapse_cells(
    v: u32,
    u: u32,
    cells: &[u32],
    triangles: &mut [[u32; 3]],
    alive: &mut [bool],
    lists: &mut HashMap<u32, Vec<u32>>,
) -> Vec<u32> {
    let mut kept = Vec::with_capacity(cells.len());
    for &c in cells {
        let tri = triangles[c as usize];
        if tri.contains(&u) {
            alive[c as usize] = false;
            for w in tri {
                if let Some(list) = lists.get_mut(&w) {
                    list.retain(|&x| x != c);
                }
            }
        } else {
            triangles[c as usize] = tri.map(|w| if w == v { u } else { w });
            if let Some(list) = lists.get_mut(&u) {
                list.push(c);
            }
            kept.push(c);
        }
    }
    kept
}

/// How far the cells of a neighbourhood are from the collapse limit.
#[derive(Debug, Clone, Copy)]
struct Quality {
    /// The smallest angle (degrees).
    min: f64,
    /// The sum over cells of how far their smallest angle is under [`COLLAPSE_BELOW_DEG`].
    deficit: f64,
}

impl Quality {
    fn of(angles: impl IntoIterator<Item = f64>) -> Self {
        Quality {
            min: 180.0,
            deficit: 0.0,
        }
        .with(angles)
    }

    fn with(mut self, angles: impl IntoIterator<Item = f64>) -> Self {
        for a in angles {
            self.min = self.min.min(a);
            self.deficit += (COLLAPSE_BELOW_DEG - a).max(0.0);
        }
        self
    }

    /// A larger smallest angle, or the same one with cells nearer the limit elsewhere (a
    /// triangle split several times next to a corner loses its needles one split at a time).
    fn improves_on(&self, before: &Quality) -> bool {
        self.min > before.min + COLLAPSE_GAIN_DEG
            || (self.min >= before.min && self.deficit < before.deficit - COLLAPSE_GAIN_DEG)
    }
}

/// Drops the cells not `alive` from `triangles` and `kinds`, keeping `created` pointing at
/// the same cells.
fn drop_dead(
    triangles: &mut Vec<[u32; 3]>,
    kinds: &mut Vec<FaceKind>,
    created: &mut Vec<u32>,
    alive: &[bool],
) {
    if alive.iter().all(|&a| a) {
        return;
    }
    let new_index = renumbering(alive);
    retain_indexed(triangles, |t| alive[t]);
    retain_indexed(kinds, |t| alive[t]);
    created.retain(|&c| alive[c as usize]);
    created.iter_mut().for_each(|c| *c = new_index[*c as usize]);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::triangle_min_angle_deg;

    const MM: f64 = 1e-3;

    fn at(x: f64, y: f64) -> Vec3 {
        Vec3::new(x * MM, y * MM, 0.0)
    }

    fn smallest_of(positions: &[Vec3], cells: &[[u32; 3]]) -> f64 {
        cells
            .iter()
            .map(|c| triangle_min_angle_deg(c.map(|v| positions[v as usize])))
            .fold(180.0, f64::min)
    }

    /// Region cells below the edge a–b of a 1.4 mm triangle beyond (a, b, c), the edge
    /// split at the given fractions from a: the region's cells fan from d = (0.7, −1.2) mm.
    fn split_edge(fractions: &[f64]) -> (Vec<Vec3>, Vec<[u32; 3]>, SplitTriangle) {
        let mut positions = vec![at(0.0, 0.0), at(1.4, 0.0), at(0.7, 1.2), at(0.7, -1.2)];
        let mut chain = vec![1u32]; // b … a, the region's side runs the edge backwards
        let mut splits = Vec::new();
        for &f in fractions {
            positions.push(at(1.4 * f, 0.0));
            splits.push((positions.len() - 1) as u32);
        }
        chain.extend(splits.iter().rev());
        chain.push(0);
        let cells = chain.windows(2).map(|w| [w[0], w[1], 3]).collect();
        let beyond = SplitTriangle {
            corners: [0, 1, 2],
            splits: [splits, Vec::new(), Vec::new()],
            kind: FaceKind::Skin,
        };
        (positions, cells, beyond)
    }

    /// `collapse_boundary_splits` on the region cells `triangles` (skin but for `lids`)
    /// and the triangles beyond: what went, and the cells left.
    fn collapse_at_boundary(
        positions: &[Vec3],
        mut triangles: Vec<[u32; 3]>,
        lids: &[usize],
        outside: &mut [SplitTriangle],
    ) -> (Vec<(u32, u32)>, Vec<[u32; 3]>) {
        let mut kinds: Vec<FaceKind> = (0..triangles.len())
            .map(|t| {
                if lids.contains(&t) {
                    FaceKind::Lid
                } else {
                    FaceKind::Skin
                }
            })
            .collect();
        let mut created: Vec<u32> = (0..triangles.len() as u32).collect();
        let gone =
            collapse_boundary_splits(positions, &mut triangles, &mut kinds, &mut created, outside);
        assert_eq!(
            (kinds.len(), created.len()),
            (triangles.len(), triangles.len())
        );
        assert!(created.iter().enumerate().all(|(i, &t)| t as usize == i));
        (gone, triangles)
    }

    #[test]
    fn a_boundary_split_next_to_a_corner_is_collapsed_into_it() {
        let (positions, triangles, beyond) = split_edge(&[0.1]);
        let mut outside = [beyond];
        assert!(smallest_of(&positions, &triangles) < 7.0);
        let (gone, triangles) = collapse_at_boundary(&positions, triangles, &[], &mut outside);
        // v slid into a: the region's cell on the short piece went, the other took a.
        assert_eq!(gone, vec![(4, 0)]);
        assert_eq!(triangles, vec![[1, 0, 3]]);
        assert!(outside[0].splits.iter().all(Vec::is_empty));
        assert!(smallest_of(&positions, &triangles) > 49.0);
    }

    #[test]
    fn splits_at_both_ends_of_an_edge_go_one_at_a_time() {
        // Removing either alone leaves the other's needle: the smallest angle holds, the
        // cells under the limit get fewer, and the second pass takes the other.
        let (positions, triangles, beyond) = split_edge(&[0.08, 0.92]);
        let (gone, triangles) = collapse_at_boundary(&positions, triangles, &[], &mut [beyond]);
        assert_eq!(gone.len(), 2, "{gone:?}");
        assert_eq!(triangles, vec![[1, 0, 3]]);
    }

    #[test]
    fn a_middle_split_and_a_split_at_a_lid_stay() {
        // In the middle: every cell is fair, nothing to gain.
        let (positions, triangles, beyond) = split_edge(&[0.5]);
        let (gone, triangles) = collapse_at_boundary(&positions, triangles, &[], &mut [beyond]);
        assert!(gone.is_empty());
        assert_eq!(triangles.len(), 2);
        // Next to a corner, but one of its cells is the lid over an opening: not moved.
        let (positions, triangles, beyond) = split_edge(&[0.1]);
        let mut outside = [beyond];
        let (gone, _) = collapse_at_boundary(&positions, triangles, &[1], &mut outside);
        assert!(gone.is_empty());
        assert_eq!(outside[0].splits[0], vec![4]);
    }

    #[test]
    fn splits_on_both_edges_at_a_corner_both_go() {
        // R is the triangle (a, p, q) with a vertex e inside; its edges at a were split
        // 0.1 of the way from a (v1 on a–q, v2 on p–a), one cell holds both splits, and
        // the triangles beyond are long (a split fans them into needles). Once one split
        // is gone, the corner cell must be gone from the other's cells too.
        let positions = vec![
            at(0.0, 0.0),    // 0 a
            at(0.7, -1.2),   // 1 p
            at(1.4, 0.0),    // 2 q
            at(0.3, -0.25),  // 3 e
            at(0.14, 0.0),   // 4 v1
            at(0.07, -0.12), // 5 v2
            at(0.7, 5.0),    // 6 beyond a–q
            at(-4.5, -3.9),  // 7 beyond p–a
        ];
        let triangles = vec![[0, 5, 4], [4, 5, 3], [5, 1, 3], [3, 1, 2], [4, 3, 2]];
        let beyond = |corners: [u32; 3], split: u32| SplitTriangle {
            corners,
            splits: [vec![split], Vec::new(), Vec::new()],
            kind: FaceKind::Skin,
        };
        let mut outside = [beyond([0, 2, 6], 4), beyond([1, 0, 7], 5)];
        let (mut gone, triangles) = collapse_at_boundary(&positions, triangles, &[], &mut outside);
        gone.sort_unstable();
        assert_eq!(gone, vec![(4, 0), (5, 0)]);
        // What is left is R fanned from e.
        let mut cells: Vec<[u32; 3]> = triangles
            .iter()
            .map(|t| {
                let k = (0..3).min_by_key(|&k| t[k]).unwrap();
                [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
            })
            .collect();
        cells.sort_unstable();
        assert_eq!(cells, vec![[0, 1, 3], [0, 3, 2], [1, 2, 3]]);
        assert!(outside.iter().all(|o| o.splits.iter().all(Vec::is_empty)));
    }

    #[test]
    fn a_vertex_inside_next_to_a_corner_is_collapsed_but_never_folds_a_cell() {
        // A 1 mm square fanned from a vertex 0.05 mm from its corner a.
        let square = vec![
            at(0.0, 0.0),
            at(1.0, 0.0),
            at(1.0, 1.0),
            at(0.0, 1.0),
            at(0.05, 0.05),
        ];
        let movable: HashSet<u32> = [4].into();
        let run = |positions: &[Vec3], fan: &[[u32; 3]]| {
            let mut triangles = fan.to_vec();
            let mut kinds = vec![FaceKind::Skin; fan.len()];
            let mut created: Vec<u32> = (0..fan.len() as u32).collect();
            let gone = collapse_to_quality(
                positions,
                &mut triangles,
                &mut kinds,
                &mut created,
                &movable,
            );
            (gone, triangles, created)
        };
        let fan = [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]];
        assert!(smallest_of(&square, &fan) < 5.0);
        let (gone, triangles, created) = run(&square, &fan);
        assert_eq!(gone, vec![(4, 0)]);
        assert_eq!(triangles, vec![[1, 2, 0], [2, 3, 0]]);
        assert_eq!(created, vec![0, 1]);
        assert!(smallest_of(&square, &triangles) > 44.9);
        // An arrowhead (a, b, c, r, d with r reflex) fanned from v just below r: into a, b
        // or c a cell would fold over (facing down, with fair angles); only r is allowed.
        let arrow = vec![
            at(0.0, 0.0), // 0 a
            at(2.0, 0.0), // 1 b
            at(2.0, 2.0), // 2 c
            at(1.0, 0.6), // 3 r
            at(0.0, 2.0), // 4 d
            at(1.0, 0.3), // 5 v
        ];
        let movable: HashSet<u32> = [5].into();
        let fan = [[0, 1, 5], [1, 2, 5], [2, 3, 5], [3, 4, 5], [4, 0, 5]];
        let mut triangles = fan.to_vec();
        let mut kinds = vec![FaceKind::Skin; fan.len()];
        let mut created: Vec<u32> = (0..fan.len() as u32).collect();
        assert!(smallest_of(&arrow, &fan) < 20.0);
        let gone = collapse_to_quality(&arrow, &mut triangles, &mut kinds, &mut created, &movable);
        assert_eq!(gone, vec![(5, 3)]);
        for t in &triangles {
            let [a, b, c] = t.map(|v| arrow[v as usize]);
            assert!((b - a).cross(&(c - a)).z > 0.0, "{t:?} folded over");
        }
    }
}
