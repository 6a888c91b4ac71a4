//! The surface incision (paper §3, made robust per physics.md §5.1–5.2, option 6b).
//!
//! Given the path the blade cut along the surface (rest space) and how deep it went, the
//! skin around the path is re-triangulated with the wound opened between two lips:
//!
//! 1. **Region R**: the skin triangles the opening touches plus their one-ring, chosen in
//!    the plane ⊥ n̄ (area-weighted normal near the path), a disk laid flat in a conformal
//!    chart of its own (super::chart) in coordinates (s, t) — turned to lie over that
//!    plane, its angles kept, so R may also grow onto faces that do not face n̄ (a thin
//!    part's rim) — or projected onto the plane where it has no such chart. Its boundary
//!    keeps the original vertices and edges (no T-junctions).
//! 2. **Lips**: offsets of the path by ±w(u) with the parabolic profile
//!    `w(u) = 4 w_o (u/L)(1 − u/L)`. For a straight path these are exactly the paper's
//!    quadratic Bézier curves A–C–B and A–D–B with `C, D = M ± 2 w_o e₂` (a symmetric
//!    quadratic Bézier is a parabola reaching w_o at its middle); for a curved path they
//!    follow it. The half-opening `w_o = min(0.15 L, k_open · depth)` is physical, not a
//!    function of the mesh resolution, and clamped to stay inside R.
//! 3. **Re-triangulation**: a constrained Delaunay triangulation of R with the lips as
//!    constraints, refined (Ruppert/Chew, spade) to a minimum angle, boundary edges kept.
//!    New vertices are lifted onto the original surface through the original triangles.
//!    There, cells that lost much of their angle in the lift are mended: splits of R's
//!    boundary are collapsed along their edge where that helps (super::collapse), the
//!    triangles beyond a split boundary are fanned (super::fan), pairs of cells are
//!    flipped, new vertices inside R are collapsed into a neighbour where that helps, and
//!    those left moved within their rings where their cells are still poor (super::smooth).
//! 4. **Wound walls** from each lip down to the cut's bottom curve (the blade tip's track),
//!    two structured strips meeting at the bottom and at the two ends, material `Wall`
//!    (super::wound: gridded column by column, graded like the lips at the ends, flipped).
//! 5. **Lid**: the faces between the lips are kept as `Lid` faces: not drawn, but they
//!    close the envelope of the tissue for blade contact (a blade in its own cut is still
//!    in the tissue, though it is outside the drawn surface).
//!
//! Skin + walls is a closed, edge-manifold, consistently oriented surface; so is skin +
//! lids. Both are checked by the tests.
//!
//! The rooms: `types` (what goes in and out), `path` (the path as the incision reads it),
//! `region` (where R is and how it grows or falls back between tries), `layout` (one try:
//! R's chart, the lips, the triangulation), `assemble` (the skin around the new
//! triangulation), `columns` (the wound's wall columns), `quality` (flips), `plane` (2D
//! geometry). [`incise`] drives them in that order.

mod assemble;
mod columns;
mod layout;
mod path;
mod plane;
mod region;
mod types;

use crate::geometry::TriMesh;
use crate::geometry::angle_deg;
use crate::geometry::topology::check_surface;

use super::wall_grid::{build_walls_choosing_ends, limit_slope};
use super::wound::{Assembly, EdgeSplits, Wound, carry_wounds};
use super::{FaceKind, PathSample};
use assemble::{Assembled, Lifter, assemble};
use layout::{Context, Layout, Try, lay_out};
use path::IncisionPath;
use region::{Region, choose_site};

pub(crate) use path::tracks_across;
pub(crate) use types::source_through;
pub use types::{Incised, IncisionError, IncisionParams};

/// Largest turn of a lip from one segment to the next on a curved path (degrees), unless
/// that would take segments shorter than a quarter of the spacing.
const LIP_TURN_DEG: f64 = 10.0;

/// The lips stay within this fraction of the way from the path to the region's boundary
/// (the region's reach, the part of it the lips' room takes in, and the opening's cap all
/// follow from it).
const LIP_ROOM: f64 = 0.45;

/// Re-triangulates `mesh` around the path and opens the incision (see the module docs);
/// `wounds` are the incisions already in `mesh`.
pub fn incise(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    wounds: &[Wound],
    path: &[PathSample],
    params: &IncisionParams,
) -> Result<Incised, IncisionError> {
    let path = IncisionPath::new(mesh, path)?;
    let site = choose_site(mesh, kinds, &path, params)?;
    let ctx = Context {
        mesh,
        path: &path,
        site: &site,
        params,
    };
    // Tried until R is triangulated: R grows where it is no disk or its boundary was
    // split, and falls back by its policy where a try fails (region::Policy).
    let mut region = Region::new(&site);
    let layout = loop {
        match lay_out(&ctx, &region) {
            Ok(Try::Mend(joining)) => {
                region.grow(&joining, |t| site.facing_well(mesh, t));
                region.mended += 1;
            }
            Ok(Try::Grow(joining)) => {
                region.grow(&joining, |t| site.facing_well(mesh, t));
                region.attempt += 1;
            }
            Ok(Try::Done(layout)) => break layout,
            Err(error) => region.fall_back(error)?,
        }
    };
    let lifter = Lifter::new(mesh, &layout);
    let assembled = assemble(mesh, kinds, &layout, site.edge, &lifter);
    let wound = columns::wound(mesh, kinds, &site, &layout, &lifter, &assembled);
    finish(mesh, wounds, &layout, assembled, wound)
}

/// The walls built, the wounds carried, the surface checked sound, and the figures.
fn finish(
    mesh: &TriMesh,
    wounds: &[Wound],
    layout: &Layout,
    assembled: Assembled,
    mut wound: Wound,
) -> Result<Incised, IncisionError> {
    let Assembled {
        mut assembly,
        boundary_inserts,
        ..
    } = assembled;
    let boundary = &layout.boundary;
    // Across a step in the floor taller than the columns are apart the walls' cells would
    // be slivers: eased to 45° or less, never deeper than the cut (as a deeper pass's).
    let gap = wound.column_gap_m();
    limit_slope(&mut wound.columns, None, gap);
    build_walls_choosing_ends(&mut wound, None, &mut assembly);
    let min_angle = assembly.min_created_angle_deg();
    let depth_max_out = wound.depth_m();
    // R's boundary may run along an earlier wound's lip: the vertices put on it go into
    // that wound's record.
    let splits: EdgeSplits = boundary_inserts
        .iter()
        .map(|(&k, list)| {
            (
                (boundary[k], boundary[(k + 1) % boundary.len()]),
                list.clone(),
            )
        })
        .collect();
    let mut wounds = carry_wounds(wounds, &assembly.source, mesh.positions.len(), &splits);
    wounds.push(wound);
    let Assembly {
        positions,
        source,
        triangles,
        kinds: out_kinds,
        created,
    } = assembly;
    // Whatever the path did (a hand's noise can double it back on itself), the surface
    // must stay sound: an incision that would leave a hole or a fin is refused, and the
    // surface kept as it was (a fault run's noisy stroke left a hole in the envelope,
    // through which the blade then fell out of the tissue).
    for (which, left_out) in [("drawn", FaceKind::Lid), ("envelope", FaceKind::Wall)] {
        let kept: Vec<[u32; 3]> = triangles
            .iter()
            .zip(&out_kinds)
            .filter(|(_, k)| **k != left_out)
            .map(|(t, _)| *t)
            .collect();
        let check = check_surface(&kept, positions.len());
        if !(check.closed && check.manifold && check.oriented) {
            return Err(IncisionError::Unsound { which, check });
        }
    }
    let out = TriMesh::new(positions, triangles);
    // The lips' own smoothness, in the incision's tangent plane (the facets of the surface
    // they are lifted onto add their dihedral angles on top).
    let turn = |lip: &[[f64; 2]]| {
        lip.windows(3)
            .map(|w| {
                let d0 = crate::math::Vec3::new(w[1][0] - w[0][0], w[1][1] - w[0][1], 0.0);
                let d1 = crate::math::Vec3::new(w[2][0] - w[1][0], w[2][1] - w[1][1], 0.0);
                angle_deg(d0, d1)
            })
            .fold(0.0, f64::max)
    };
    let lip_max_turn_deg = turn(&layout.upper).max(turn(&layout.lower));
    Ok(Incised {
        mesh: out,
        kinds: out_kinds,
        source,
        created,
        wounds,
        lip_max_turn_deg,
        min_angle_deg: min_angle,
        opening_m: layout.w_o,
        depth_m: depth_max_out,
        length_m: layout.length,
    })
}

#[cfg(test)]
mod tests;
