//! The wound's walls as columns under the lips: from each lip down to the bottom curve (the
//! blade tip's track), square to the path, leaning the way the blade cut (super::super::wound
//! grids them).

use crate::geometry::TriMesh;
use crate::math::Vec3;

use super::assemble::{Assembled, Lifter};
use super::layout::Layout;
use super::region::Site;
use crate::cut::cells::FaceKind;
use crate::cut::wall_grid::{even_out_bottoms, held_short};
use crate::cut::wound::{WallColumn, Wound};

/// Largest lean of a wound wall from the surface normal (degrees). A blade held flatter
/// than this cuts a flap thinner than the lips' opening; its walls are drawn at this lean.
pub(super) const MAX_WALL_LEAN_DEG: f64 = 60.0;

/// The wound of `layout`'s incision: its lips and the columns of its walls.
pub(super) fn wound(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    site: &Site,
    layout: &Layout,
    lifter: &Lifter,
    assembled: &Assembled,
) -> Wound {
    let Layout {
        path2,
        tracks,
        length,
        spacing,
        region,
        in_region,
        w_o,
        ..
    } = layout;
    let (length, spacing, edge, n_bar) = (*length, *spacing, site.edge, site.n_bar);
    let (upper_chain, lower_chain) = (&assembled.upper_chain, &assembled.lower_chain);
    let sample_arc: Vec<f64> = path2.arc.clone();
    // The blade's track (tip − entry) at arc length u.
    let bottom_at = |u: f64| -> Vec3 {
        let i = sample_arc
            .partition_point(|&a| a <= u)
            .clamp(1, sample_arc.len() - 1)
            - 1;
        let seg = sample_arc[i + 1] - sample_arc[i];
        let f = if seg > 0.0 {
            ((u - sample_arc[i]) / seg).clamp(0.0, 1.0)
        } else {
            0.0
        };
        tracks[i] * (1.0 - f) + tracks[i + 1] * f
    };
    // Columns below the lips: evenly spaced, as many as the denser lip has vertices.
    let n_cols = upper_chain.len().max(lower_chain.len());
    // A wall has at least two rows (super::wound): shallower than a column gap, its cells
    // would be slivers (a stab's slit rises to the surface at its end). No deeper floor: the
    // lips' step already shrinks with the depth, and half the mesh's spacing drew shallow
    // cuts on coarse meshes far too deep.
    let min_depth = length / (n_cols - 1).max(1) as f64;
    let other_skin: Vec<usize> = (0..mesh.triangles.len())
        .filter(|&t| kinds[t] == FaceKind::Skin && !in_region[t])
        .collect();
    // Columns go into the tissue the way the blade cut, square to the path: along its
    // track below the path (`tracks_across`), so that the walls lie in the cut surface Σ —
    // a blade held upright on a sloping surface cuts upright walls, one tilted sideways
    // cuts leaning ones — and the wall's cells stay rectangles where the surface slopes
    // along the cut. Where the blade's cut sums to nothing over the window below, they go
    // along the inward surface normal. Both are averaged along the path over the depth:
    // columns a fraction of a millimetre apart that lean by a degree more than their
    // neighbours (the path crosses a facet edge between them, or the hand wavers) would
    // cross a few millimetres down in a short, deep cut, and a wall does not bend on a
    // scale shorter than its depth.
    let params_of = |c: usize| c as f64 / (n_cols - 1) as f64;
    let tops: Vec<Vec3> = (0..n_cols)
        .map(|c| lifter.lift(path2.at(params_of(c) * length)))
        .collect();
    let cuts: Vec<Vec3> = (0..n_cols)
        .map(|c| bottom_at(params_of(c) * length))
        .collect();
    let depths: Vec<f64> = cuts.iter().map(|t| t.norm().max(min_depth)).collect();
    let normals: Vec<Vec3> = tops
        .iter()
        .map(|top| {
            let mut normal = Vec3::zeros();
            for &t in region {
                let [a, b, c] = mesh.corners(t);
                if ((a + b + c) / 3.0 - top).norm() < edge {
                    normal += mesh.doubled_area_normal(t);
                }
            }
            normal.try_normalize(1e-300).unwrap_or(n_bar)
        })
        .collect();
    let window = depths.iter().copied().fold(0.0, f64::max);
    let delta = window.max(0.5 * spacing);
    let max_lean = MAX_WALL_LEAN_DEG.to_radians();
    // A thin part: a wall stops short of the far side of the organ.
    let hold_short = |col: &mut WallColumn| {
        col.depth = held_short(mesh, &other_skin, &col.top, &col.inward, col.depth, spacing);
    };
    let mut columns = Vec::with_capacity(n_cols);
    for c in 0..n_cols {
        let param = params_of(c);
        let u = param * length;
        let top = tops[c];
        let tangent = (lifter.lift(path2.at((u + delta).min(length)))
            - lifter.lift(path2.at((u - delta).max(0.0))))
        .try_normalize(1e-300);
        let square = |v: Vec3| match tangent {
            Some(t) => (v - t * v.dot(&t)).try_normalize(1e-9),
            None => v.try_normalize(1e-9),
        };
        // The surface normals and the cuts of the columns within the window, summed.
        let (mut normal, mut cut) = (Vec3::zeros(), Vec3::zeros());
        for k in (0..n_cols).filter(|k| (params_of(*k) - param).abs() * length <= window) {
            normal += normals[k];
            cut += cuts[k];
        }
        let straight_in = -normal.try_normalize(1e-300).unwrap_or(n_bar);
        let straight_in = square(straight_in).unwrap_or(straight_in);
        let (inward, shorten) = match square(cut) {
            Some(along_cut) => match along_cut.dot(&straight_in) {
                cos if cos >= max_lean.cos() => (along_cut, 1.0),
                // Flatter than the largest lean: turned up to it, in the plane the two
                // span, and shortened to reach as far below the surface as the cut does (at
                // its full length it would end in tissue the blade never reached).
                cos if cos > 0.0 => {
                    let side = (along_cut - straight_in * cos)
                        .try_normalize(1e-9)
                        .unwrap_or(straight_in);
                    (
                        straight_in * max_lean.cos() + side * max_lean.sin(),
                        cos / max_lean.cos(),
                    )
                }
                _ => (straight_in, 1.0),
            },
            None => (straight_in, 1.0),
        };
        let mut column = WallColumn {
            param,
            top,
            inward,
            depth: (depths[c] * shorten).max(min_depth),
        };
        hold_short(&mut column);
        columns.push(column);
    }
    // A column turned toward a new bottom may now run toward the far side of a thin part.
    for c in even_out_bottoms(&mut columns) {
        hold_short(&mut columns[c]);
    }
    Wound {
        upper: upper_chain.clone(),
        lower: lower_chain.clone(),
        columns,
        opening_m: *w_o,
        length_m: length,
        spacing_m: spacing,
    }
}
