//! A deeper pass along a wound. A later stroke that runs along the wound deeper than its
//! walls (a surgeon deepening an incision, or a deeper cut across it) cuts below the old
//! floor; [`deepen`] takes the walls of every such column down to the new depth. A wound
//! deepened along at least half its columns is then opened again as one incision at the
//! new depths (its lid back to skin), so its lips part as a first pass that deep would have
//! opened them; if that incision is refused, or less than half the wound was deepened, only
//! the walls change.

use std::collections::{HashMap, HashSet};

use crate::geometry::TriMesh;

use super::incision::{Incised, IncisionParams, incise, source_through, tracks_across};
use super::wall_grid::{
    build_walls_choosing_ends, even_out_bottoms, held_short, limit_slope, path_cut_near,
};
use super::wound::{Assembly, EdgeSplits, Wound, edge_key};
use super::{FaceKind, PathSample};

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
    use crate::cut::corners_of_kind;
    use crate::cut::{IncisionParams, incise};
    use crate::math::Vec3;
    use crate::pipeline::script::vertical_extent;
    use crate::scene::BuiltinMesh;

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
