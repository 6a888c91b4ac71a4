//! Isotropic remeshing of a scanned surface (Botsch & Kobbelt 2004, "A remeshing approach to
//! multiresolution modeling"): split edges longer than 4/3 of the target length, collapse
//! those shorter than 4/5 of it, flip edges towards valence six, move every vertex towards
//! its neighbours' centroid in its tangent plane and back onto the original surface; ten
//! rounds, then flips that raise the smallest angle.
//!
//! Why: scans come with needles and caps (the deltoid's triangles have edges from 0.06 to
//! 35 mm and angles down to 1°). An incision re-meshes only around its path and keeps the
//! triangles it does not split, so on such a surface the remeshed region inherits angles
//! far below the 15° the cutting code holds itself to, and the path's splits meet needles
//! it cannot place a lip point in. Remeshing once at import gives the cut a surface it can
//! work with. Vertices are put back onto the original surface after every move (except
//! where two creases are zipped, and by the final offset that restores the volume), and
//! flips cross bends of at most 30°, so the shape is kept to within a fraction of the target
//! length; the report says how close, both ways.

use serde::Serialize;

use super::halfedge::{HalfEdgeError, HalfEdgeMesh, NONE};
use crate::geometry::parry_adapter::TriangleBvh;
use crate::geometry::predicates::closest_point_on_triangle;
use crate::geometry::topology::triangle_components;
use crate::geometry::{TriMesh, triangle_min_angle_deg};
use crate::math::Vec3;

/// A triangle with an angle under this (degrees) is poor: the incision holds the triangles
/// it makes to it, and a scan with such triangles is remeshed (`mesh.remesh = "auto"`).
pub const POOR_ANGLE_DEG: f64 = 15.0;

/// Rounds of split, collapse, flip and relax.
const ROUNDS: usize = 10;

/// Largest angle between the two triangles of an edge that may be flipped (degrees): a flip
/// moves the surface by no more than the bend it crosses.
const MAX_FLIP_BEND_DEG: f64 = 30.0;

/// An edge whose two faces meet at more than this (degrees) is a crease of the shape (the
/// built-in liver's thin tip lost 4 mm at half its edge length with creases smoothed like
/// the rest). Creases are never flipped; a vertex on one moves only along it, by collapses;
/// a vertex where creases end or meet does not move.
const CREASE_BEND_DEG: f64 = 45.0;

/// Largest move that restores a component's volume, in target edge lengths.
const MAX_VOLUME_OFFSET: f64 = 0.1;

/// Largest turn of a triangle's normal that a collapse or a relaxing move may cause
/// (degrees): more and the surface starts to fold.
const MAX_TURN_DEG: f64 = 30.0;

/// What remeshing did to a surface.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RemeshReport {
    /// Target edge length (m).
    pub target_edge_m: f64,
    /// Triangles before.
    pub triangles_before: usize,
    /// Triangles after.
    pub triangles_after: usize,
    /// Smallest triangle angle before (degrees).
    pub min_angle_before_deg: f64,
    /// Smallest triangle angle after (degrees).
    pub min_angle_after_deg: f64,
    /// Triangles with an angle under 15° before.
    pub under_15_before: usize,
    /// Triangles with an angle under 15° after.
    pub under_15_after: usize,
    /// Farthest any vertex of either surface lies from the other (m).
    pub max_deviation_m: f64,
    /// Relative change of the enclosed volume.
    pub volume_change: f64,
}

/// The original surface, for projecting moved vertices back onto it.
struct Reference<'a> {
    mesh: &'a TriMesh,
    bvh: TriangleBvh,
    normals: Vec<Vec3>,
    /// First search radius for the nearest triangle: its mean edge length.
    reach: f64,
}

impl<'a> Reference<'a> {
    fn new(mesh: &'a TriMesh) -> Self {
        let normals = (0..mesh.triangles.len())
            .map(|t| {
                mesh.doubled_area_normal(t)
                    .try_normalize(1e-300)
                    .unwrap_or_else(Vec3::zeros)
            })
            .collect();
        Self {
            mesh,
            bvh: TriangleBvh::build(mesh),
            normals,
            reach: mesh.mean_edge_length().max(1e-9),
        }
    }

    /// The triangle nearest to `p` and its point nearest to `p`.
    fn nearest(&self, p: &Vec3) -> Option<(usize, Vec3)> {
        let mut r = self.reach;
        // (Doubling from the mean edge: 40 times covers any mesh.)
        for _ in 0..40 {
            let mut best: Option<(f64, usize, Vec3)> = None;
            self.bvh
                .for_each_overlapping(&(p - Vec3::repeat(r)), &(p + Vec3::repeat(r)), |t| {
                    let q = closest_point_on_triangle(p, &self.mesh.corners(t));
                    let d = (q - p).norm_squared();
                    if best.is_none_or(|(bd, ..)| d < bd) {
                        best = Some((d, t, q));
                    }
                });
            if let Some((d, t, q)) = best
                && d <= r * r
            {
                return Some((t, q));
            }
            r *= 2.0;
        }
        None
    }

    /// The nearest point of the original surface to `p` on a sheet facing the way `n`
    /// does (so a vertex on one side of a thin part is not pulled onto the other side),
    /// searched within `reach` and then twice, four and eight times as far; `None` if
    /// there is none.
    fn project(&self, p: &Vec3, n: &Vec3, reach: f64) -> Option<Vec3> {
        let mut r = reach;
        for _ in 0..4 {
            let lo = p - Vec3::repeat(r);
            let hi = p + Vec3::repeat(r);
            let mut best: Option<(f64, Vec3)> = None;
            self.bvh.for_each_overlapping(&lo, &hi, |t| {
                if self.normals[t].dot(n) <= 0.0 {
                    return;
                }
                let q = closest_point_on_triangle(p, &self.mesh.corners(t));
                let d = (q - p).norm_squared();
                if best.is_none_or(|(bd, _)| d < bd) {
                    best = Some((d, q));
                }
            });
            if let Some((d, q)) = best
                && d <= r * r
            {
                return Some(q);
            }
            r *= 2.0;
        }
        None
    }
}

/// Remeshes a closed, manifold, oriented `mesh` to edges of about `target_m`.
pub fn remesh_isotropic(
    mesh: &TriMesh,
    target_m: f64,
) -> Result<(TriMesh, RemeshReport), HalfEdgeError> {
    let reference = Reference::new(mesh);
    let mut hm = HalfEdgeMesh::new(mesh)?;
    let (low, high) = (0.8 * target_m, 4.0 / 3.0 * target_m);
    let mut scratch = Vec::new();
    mark_creases(&mut hm);
    for _ in 0..ROUNDS {
        split_long_edges(&mut hm, high, &reference);
        collapse_short_edges(&mut hm, low, high, &mut scratch);
        flip_to_valence_six(&mut hm);
        relax(&mut hm, &reference, target_m, &mut scratch);
    }
    flip_to_larger_angles(&mut hm);
    let mut out = hm.to_trimesh();
    restore_volume(&mut out, mesh, &reference, MAX_VOLUME_OFFSET * target_m);
    let report = report(mesh, &out, target_m);
    Ok((out, report))
}

/// Marks the edges bent by more than [`CREASE_BEND_DEG`].
fn mark_creases(hm: &mut HalfEdgeMesh) {
    let sharp = CREASE_BEND_DEG.to_radians().cos();
    for h in 0..hm.half_edge_slots() as u32 {
        hm.marked[h as usize] = bend_cos(hm, h) < sharp;
    }
}

/// Where a vertex may go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Freedom {
    /// On a smooth part: anywhere on the surface.
    Free,
    /// On a crease (two crease edges): along it.
    Crease,
    /// Where creases end or meet: nowhere.
    Corner,
}

/// Where `v` may go, by the creases at it.
fn freedom(hm: &HalfEdgeMesh, v: u32, scratch: &mut Vec<u32>) -> Freedom {
    hm.outgoing(v, scratch);
    match scratch.iter().filter(|&&o| hm.marked[o as usize]).count() {
        0 => Freedom::Free,
        2 => Freedom::Crease,
        _ => Freedom::Corner,
    }
}

/// Twice the area-weighted normal of the face of `h`, with vertex `moved.0` at `moved.1`.
fn face_normal(hm: &HalfEdgeMesh, h: u32, moved: (u32, Vec3)) -> Vec3 {
    let at = |v: u32| {
        if v == moved.0 {
            moved.1
        } else {
            hm.pos[v as usize]
        }
    };
    let [a, b, c] = hm.face_corners(h).map(at);
    (b - a).cross(&(c - a))
}

/// Twice the area-weighted normal of the face of `h` as it is.
fn normal(hm: &HalfEdgeMesh, h: u32) -> Vec3 {
    face_normal(hm, h, (NONE, Vec3::zeros()))
}

/// Whether a face's normal turned by more than [`MAX_TURN_DEG`] (or vanished).
fn turned(before: &Vec3, after: &Vec3) -> bool {
    let scale = before.norm() * after.norm();
    scale == 0.0 || before.dot(after) < MAX_TURN_DEG.to_radians().cos() * scale
}

/// The area-weighted unit normal at `v`.
fn vertex_normal(hm: &HalfEdgeMesh, v: u32, scratch: &mut Vec<u32>) -> Vec3 {
    hm.outgoing(v, scratch);
    let sum: Vec3 = scratch.iter().map(|&o| normal(hm, o)).sum();
    sum.try_normalize(1e-300).unwrap_or_else(Vec3::zeros)
}

fn length(hm: &HalfEdgeMesh, h: u32) -> f64 {
    (hm.pos[hm.head(h) as usize] - hm.pos[hm.tail(h) as usize]).norm()
}

/// Splits every edge longer than `high` at its midpoint, put back on the surface (if that is
/// near: the midpoint of a chord across a thin part may lie far from either side).
fn split_long_edges(hm: &mut HalfEdgeMesh, high: f64, reference: &Reference<'_>) {
    // A split half may still be too long: a few passes, each over the edges there are.
    for _ in 0..8 {
        let mut split = 0;
        for h in 0..hm.half_edge_slots() as u32 {
            if !hm.alive(h) || h > hm.twin(h) || length(hm, h) <= high {
                continue;
            }
            let (a, b) = (hm.pos[hm.tail(h) as usize], hm.pos[hm.head(h) as usize]);
            let n = normal(hm, h) + normal(hm, hm.twin(h));
            let mid = 0.5 * (a + b);
            let half = 0.5 * (b - a).norm();
            let at = reference
                .project(&mid, &n, half)
                .filter(|q| (q - mid).norm() <= half && !split_folds(hm, h, *q))
                .unwrap_or(mid);
            hm.split(h, at);
            split += 1;
        }
        if split == 0 {
            break;
        }
    }
}

/// Whether splitting `h` at `p` would turn one of the four new faces by more than
/// [`MAX_TURN_DEG`] from the face it is cut from (at the midpoint none turns: they lie in
/// the old faces).
fn split_folds(hm: &HalfEdgeMesh, h: u32, p: Vec3) -> bool {
    [h, hm.twin(h)].into_iter().any(|e| {
        let old = normal(hm, e);
        // The face (a, b, c) of e (a → b) becomes (a, p, c) and (p, b, c).
        let [a, b, c] = hm.face_corners(e).map(|v| hm.pos[v as usize]);
        let halves = [(p - a).cross(&(c - a)), (b - p).cross(&(c - p))];
        halves.iter().any(|n| turned(&old, n))
    })
}

/// Collapses every edge shorter than `low` into its midpoint where that keeps the surface a
/// manifold, makes no edge longer than `high` and turns no face by more than
/// [`MAX_TURN_DEG`].
fn collapse_short_edges(hm: &mut HalfEdgeMesh, low: f64, high: f64, scratch: &mut Vec<u32>) {
    let mut ring = Vec::new();
    for e in 0..hm.half_edge_slots() as u32 {
        if !hm.alive(e) || length(hm, e) >= low {
            continue;
        }
        // A vertex leaves a smooth part for anywhere, a crease only along it, a corner
        // never: into the end that stays, or to the middle when both may go.
        let (ta, tb) = (hm.tail(e), hm.head(e));
        let along = hm.marked[e as usize];
        let goes = |f: Freedom| f == Freedom::Free || (f == Freedom::Crease && along);
        let (fa, fb) = (freedom(hm, ta, scratch), freedom(hm, tb, scratch));
        let (pa, pb) = (hm.pos[ta as usize], hm.pos[tb as usize]);
        // Two creases closer than 0.4 of the target length (a thin rim's two edges) are
        // zipped into one: the band between them cannot hold good triangles. And an edge
        // under 0.2 of it goes whatever its ends are: two corners that close are one at
        // this resolution.
        let short = length(hm, e);
        let zip = !along && fa == Freedom::Crease && fb == Freedom::Crease && short < 0.5 * low;
        // (Both ends may go only if both are free or both on the crease the edge runs along:
        // a marked edge has no free end.)
        let (h, p) = match (goes(fa), goes(fb)) {
            (false, false) if zip || short < 0.25 * low => (e, 0.5 * (pa + pb)),
            (false, false) => continue,
            (true, false) => (e, pb),
            (false, true) => (hm.twin(e), pa),
            (true, true) => (e, 0.5 * (pa + pb)),
        };
        if !hm.can_collapse(h, scratch) {
            continue;
        }
        let (a, b) = (hm.tail(h), hm.head(h));
        let mut ok = true;
        for v in [a, b] {
            hm.outgoing(v, &mut ring);
            for &o in &ring {
                let far = hm.head(o);
                if far != a && far != b && (hm.pos[far as usize] - p).norm() > high {
                    ok = false;
                }
                // The two faces of the edge go; every other face around it keeps its
                // corners, with v at p.
                let corners = hm.face_corners(o);
                if corners.contains(&a) && corners.contains(&b) {
                    continue;
                }
                let before = normal(hm, o);
                if turned(&before, &face_normal(hm, o, (v, p))) {
                    ok = false;
                }
            }
        }
        if ok {
            hm.collapse(h, p, scratch);
        }
    }
}

/// The bend between the two faces of `h` as the cosine of their normals' angle.
fn bend_cos(hm: &HalfEdgeMesh, h: u32) -> f64 {
    let n0 = normal(hm, h);
    let n1 = normal(hm, hm.twin(h));
    let scale = n0.norm() * n1.norm();
    if scale == 0.0 {
        return -1.0;
    }
    n0.dot(&n1) / scale
}

/// The two faces `h`'s edge would have after a flip: `(c, d, b)` and `(d, c, a)`.
fn flipped_corners(hm: &HalfEdgeMesh, h: u32) -> [[Vec3; 3]; 2] {
    let (a, b) = (hm.tail(h), hm.head(h));
    let (c, d) = (hm.opposite(h), hm.opposite(hm.twin(h)));
    let p = |v: u32| hm.pos[v as usize];
    [[p(c), p(d), p(b)], [p(d), p(c), p(a)]]
}

/// Whether flipping `h` crosses a bend of at most [`MAX_FLIP_BEND_DEG`] and leaves two
/// faces that neither fold against each other nor turn over.
fn flip_is_flat(hm: &HalfEdgeMesh, h: u32) -> bool {
    let max_bend = MAX_FLIP_BEND_DEG.to_radians().cos();
    if hm.marked[h as usize] || bend_cos(hm, h) < max_bend {
        return false;
    }
    let corner_normal = |[a, b, c]: [Vec3; 3]| (b - a).cross(&(c - a));
    let [f0, f1] = flipped_corners(hm, h).map(corner_normal);
    let old = normal(hm, h) + normal(hm, hm.twin(h));
    let scale = f0.norm() * f1.norm();
    scale > 0.0 && f0.dot(&f1) >= max_bend * scale && f0.dot(&old) > 0.0 && f1.dot(&old) > 0.0
}

/// Flips edges where that brings the four vertices involved closer to valence six.
fn flip_to_valence_six(hm: &mut HalfEdgeMesh) {
    for h in 0..hm.half_edge_slots() as u32 {
        if !hm.alive(h) || h > hm.twin(h) || !hm.can_flip(h) {
            continue;
        }
        let (a, b) = (hm.tail(h), hm.head(h));
        let (c, d) = (hm.opposite(h), hm.opposite(hm.twin(h)));
        let dev = |v: u32, change: i64| (hm.valence(v) as i64 + change - 6).pow(2);
        let before = dev(a, 0) + dev(b, 0) + dev(c, 0) + dev(d, 0);
        let after = dev(a, -1) + dev(b, -1) + dev(c, 1) + dev(d, 1);
        if after < before && flip_is_flat(hm, h) {
            hm.flip(h);
        }
    }
}

/// Moves each vertex off the creases towards the centroid of its neighbours within its
/// tangent plane, then back onto the original surface; a move that would turn a face by
/// more than [`MAX_TURN_DEG`] is not made.
fn relax(hm: &mut HalfEdgeMesh, reference: &Reference<'_>, target: f64, scratch: &mut Vec<u32>) {
    for v in 0..hm.pos.len() as u32 {
        if hm.out[v as usize] == NONE || freedom(hm, v, scratch) != Freedom::Free {
            continue;
        }
        let n = vertex_normal(hm, v, scratch);
        hm.outgoing(v, scratch);
        let p = hm.pos[v as usize];
        let centroid: Vec3 = scratch
            .iter()
            .map(|&o| hm.pos[hm.head(o) as usize])
            .sum::<Vec3>()
            / scratch.len() as f64;
        let step = centroid - p;
        let moved = p + step - n * n.dot(&step);
        // (Nowhere on the surface facing its way within reach: it stays.)
        let Some(q) = reference.project(&moved, &n, target) else {
            continue;
        };
        let folds = scratch
            .iter()
            .any(|&o| turned(&normal(hm, o), &face_normal(hm, o, (v, q))));
        if !folds {
            hm.pos[v as usize] = q;
        }
    }
}

/// Flips edges where that raises the smaller of the two faces' smallest angles by more than
/// half a degree, across bends of at most [`MAX_FLIP_BEND_DEG`]; a few passes.
fn flip_to_larger_angles(hm: &mut HalfEdgeMesh) {
    for _ in 0..5 {
        let mut flipped = 0;
        for h in 0..hm.half_edge_slots() as u32 {
            if !hm.alive(h) || h > hm.twin(h) || !hm.can_flip(h) || !flip_is_flat(hm, h) {
                continue;
            }
            let corners = |e: u32| hm.face_corners(e).map(|v| hm.pos[v as usize]);
            let before =
                triangle_min_angle_deg(corners(h)).min(triangle_min_angle_deg(corners(hm.twin(h))));
            let [f0, f1] = flipped_corners(hm, h);
            let after = triangle_min_angle_deg(f0).min(triangle_min_angle_deg(f1));
            if after > before + 0.5 {
                hm.flip(h);
                flipped += 1;
            }
        }
        if flipped == 0 {
            break;
        }
    }
}

/// Moves the vertices of each component of `mesh` along their normals by the same distance
/// so that it encloses the volume of the part of `original` it was made from again:
/// vertices on the original's flat faces cut its curved parts short (a tumour 12 mm across
/// lost 2 % of its volume, and so of its mass, at 1.2 mm edges). The move is at most
/// `limit`: more could turn a thin part inside out.
fn restore_volume(mesh: &mut TriMesh, original: &TriMesh, reference: &Reference<'_>, limit: f64) {
    let volumes = |m: &TriMesh, component: &[u32], count: usize| {
        let (mut volume, mut area) = (vec![0.0; count], vec![0.0; count]);
        for (t, &c) in component.iter().enumerate() {
            let [a, b, d] = m.corners(t);
            volume[c as usize] += a.dot(&b.cross(&d)) / 6.0;
            area[c as usize] += 0.5 * m.doubled_area_normal(t).norm();
        }
        (volume, area)
    };
    let (was, was_count) = triangle_components(&original.triangles);
    let (was_volume, _) = volumes(original, &was, was_count);
    let (now, now_count) = triangle_components(&mesh.triangles);
    let (now_volume, now_area) = volumes(mesh, &now, now_count);
    // Each component's offset, against the original component nearest to its first vertex.
    let mut offset = vec![0.0; now_count];
    let mut seen = vec![false; now_count];
    for (t, &c) in now.iter().enumerate() {
        let c = c as usize;
        if std::mem::replace(&mut seen[c], true) || now_area[c] == 0.0 {
            continue;
        }
        let first = mesh.positions[mesh.triangles[t][0] as usize];
        if let Some((from, _)) = reference.nearest(&first) {
            let deficit = was_volume[was[from] as usize] - now_volume[c];
            offset[c] = (deficit / now_area[c]).clamp(-limit, limit);
        }
    }
    let mut normals = vec![Vec3::zeros(); mesh.positions.len()];
    let mut vertex_component = vec![0u32; mesh.positions.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let n = mesh.doubled_area_normal(t);
        for &v in tri {
            normals[v as usize] += n;
            vertex_component[v as usize] = now[t];
        }
    }
    for ((p, n), c) in mesh
        .positions
        .iter_mut()
        .zip(&normals)
        .zip(&vertex_component)
    {
        if let Some(n) = n.try_normalize(1e-300) {
            *p += n * offset[*c as usize];
        }
    }
}

/// Measures of the remeshing: counts, angles, volume, and how far the vertices of each
/// surface lie from the other.
fn report(before: &TriMesh, after: &TriMesh, target: f64) -> RemeshReport {
    let under_15 = |m: &TriMesh| {
        (0..m.triangles.len())
            .filter(|&t| triangle_min_angle_deg(m.corners(t)) < POOR_ANGLE_DEG)
            .count()
    };
    let farthest = |points: &[Vec3], from: &TriMesh| {
        let surface = Reference::new(from);
        points
            .iter()
            .filter_map(|p| surface.nearest(p).map(|(_, q)| (q - p).norm()))
            .fold(0.0, f64::max)
    };
    let max_deviation_m =
        farthest(&before.positions, after).max(farthest(&after.positions, before));
    let (v0, v1) = (before.signed_volume(), after.signed_volume());
    RemeshReport {
        target_edge_m: target,
        triangles_before: before.triangles.len(),
        triangles_after: after.triangles.len(),
        min_angle_before_deg: before.min_angle_deg(),
        min_angle_after_deg: after.min_angle_deg(),
        under_15_before: under_15(before),
        under_15_after: under_15(after),
        max_deviation_m,
        volume_change: if v0 != 0.0 { (v1 - v0) / v0 } else { 0.0 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::organs;
    use crate::geometry::topology::check_surface;

    /// The liver with needles: every edge split at 3 % of its length, each of its two faces
    /// fanned from the split point (two needle triangles per edge).
    fn with_needles(mesh: &TriMesh) -> TriMesh {
        let mut hm = HalfEdgeMesh::new(mesh).unwrap();
        let edges: Vec<u32> = (0..hm.half_edge_slots() as u32)
            .filter(|&h| h < hm.twin(h))
            .collect();
        for h in edges {
            let (a, b) = (hm.pos[hm.tail(h) as usize], hm.pos[hm.head(h) as usize]);
            hm.split(h, a + 0.03 * (b - a));
        }
        hm.to_trimesh()
    }

    fn assert_sound(mesh: &TriMesh, what: &str) {
        let check = check_surface(&mesh.triangles, mesh.positions.len());
        assert!(
            check.closed && check.manifold && check.oriented,
            "{what}: {check:?}"
        );
    }

    #[test]
    fn split_collapse_and_flip_keep_the_surface_closed() {
        let liver = organs::liver();
        let needles = with_needles(&liver);
        assert_eq!(needles.triangles.len(), 4 * liver.triangles.len());
        assert_sound(&needles, "split");
        assert!(needles.min_angle_deg() < 2.0, "{}", needles.min_angle_deg());
        let mut hm = HalfEdgeMesh::new(&needles).unwrap();
        let mut scratch = Vec::new();
        let (mut flips, mut collapses) = (0, 0);
        for h in 0..hm.half_edge_slots() as u32 {
            if hm.alive(h) && h % 7 == 0 && hm.can_flip(h) {
                hm.flip(h);
                flips += 1;
            }
        }
        for h in 0..hm.half_edge_slots() as u32 {
            if hm.alive(h) && h % 5 == 0 && hm.can_collapse(h, &mut scratch) {
                let p = hm.pos[hm.head(h) as usize];
                hm.collapse(h, p, &mut scratch);
                collapses += 1;
            }
        }
        assert!(
            flips > 100 && collapses > 100,
            "{flips} flips, {collapses} collapses"
        );
        let out = hm.to_trimesh();
        let check = check_surface(&out.triangles, out.positions.len());
        assert!(
            check.closed && check.manifold && check.oriented,
            "{check:?}"
        );
        assert_eq!(
            out.positions.len() as i64 - (out.triangles.len() as i64 * 3 / 2)
                + out.triangles.len() as i64,
            2,
            "Euler characteristic of a sphere"
        );
    }

    /// Needles on the liver and the cerebroma, remeshed to half their edge length: good
    /// triangles, on the same shape, with the same volume. The liver's thin tip is a crease
    /// whose corners keep a triangle or two under 15° (the creases meet there at acute
    /// angles); the cerebroma is smooth.
    #[test]
    fn a_surface_of_needles_is_remeshed_to_good_triangles_on_its_shape() {
        // (organ, smallest angle after, triangles under 15° after, farthest an original
        // vertex may lie from the new surface in target edges)
        let organs = [
            ("liver", organs::liver(), 10.0, 2, 0.25),
            ("cerebroma", organs::cerebroma(), 25.0, 0, 0.1),
        ];
        for (name, organ, min_angle, under_15, deviation) in organs {
            let needles = with_needles(&organ);
            let target = 0.5 * organ.mean_edge_length();
            let (out, report) = remesh_isotropic(&needles, target).unwrap();
            assert_sound(&out, name);
            // Nothing folded through the surface either.
            let options = crate::geometry::ValidationOptions::default();
            let validated = crate::geometry::validate(out.clone(), name, &options);
            assert!(validated.is_ok(), "{name}: {validated:?}");
            assert!(report.min_angle_before_deg < 2.0, "{name}: {report:?}");
            assert!(report.min_angle_after_deg > min_angle, "{name}: {report:?}");
            assert!(report.under_15_after <= under_15, "{name}: {report:?}");
            assert!(
                report.max_deviation_m < deviation * target,
                "{name}: {report:?}"
            );
            assert!(report.volume_change.abs() < 1e-3, "{name}: {report:?}");
            let edge = out.mean_edge_length();
            assert!(
                (0.8..1.25).contains(&(edge / target)),
                "{name}: {edge} for {target}"
            );
        }
    }

    /// The scans of ../shared/meshes as the scene build remeshes them (`remesh = "auto"`):
    /// those with angles under 15° are remeshed, pass validation, and keep their shape.
    /// Measured (`cargo test --release -p scalpel-sim --lib -- --ignored
    /// shared_meshes_are_remeshed --nocapture`): see docs/CUTTING.md, "Real organ meshes".
    #[test]
    #[ignore = "reads ../shared/meshes"]
    fn shared_meshes_are_remeshed() {
        use crate::geometry::{LengthUnit, MeshWarning};
        use crate::progress::Silent;
        use crate::scene::{build_scene, for_mesh_file};
        // (file, units, remeshed, most triangles left under 15°, farthest an original
        // vertex may lie from the new surface in target edges, largest volume change)
        let scans = [
            (
                "pig_liver_lobe0_surface500.obj",
                LengthUnit::M,
                true,
                8,
                0.3,
                0.02,
            ),
            ("sofa_sphere_05.obj", LengthUnit::Mm, false, 0, 0.0, 0.0),
            (
                "liver_tumour_PPP_Tumor.obj",
                LengthUnit::Cm,
                true,
                0,
                0.25,
                0.02,
            ),
            ("deltoid_tri.obj", LengthUnit::Mm, true, 0, 0.4, 0.02),
        ];
        for (file, units, remeshed, under_15, deviation, volume) in scans {
            let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../../../shared/meshes")
                .join(file);
            let bytes = std::fs::read(&path).unwrap_or_else(|e| {
                panic!("{}: {e} (is ../shared beside the project?)", path.display())
            });
            let started = std::time::Instant::now();
            let scene =
                build_scene(&for_mesh_file(path, units), Some(&bytes), &mut Silent).expect(file);
            let report = scene.mesh_warnings.iter().find_map(|w| match w {
                MeshWarning::Remeshed(r) => Some(r),
                _ => None,
            });
            println!(
                "{file}: built in {:.0} ms; {}",
                started.elapsed().as_secs_f64() * 1e3,
                scene
                    .mesh_warnings
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join("; ")
            );
            assert_eq!(
                report.is_some(),
                remeshed,
                "{file}: {:?}",
                scene.mesh_warnings
            );
            let Some(r) = report else { continue };
            assert_sound(&scene.model.surface, file);
            assert!(r.under_15_after <= under_15, "{file}: {r:?}");
            assert!(
                r.max_deviation_m <= deviation * r.target_edge_m,
                "{file}: {r:?}"
            );
            assert!(r.volume_change.abs() <= volume, "{file}: {r:?}");
        }
    }
}
