//! From R triangulated in its chart to the incised surface: the new vertices lifted onto the
//! original surface, the triangles outside R (fanned where R's boundary was split), and the
//! cells that lost much of their angle in the lift mended — splits collapsed along their
//! edge (super::super::collapse), fans from the best point (super::super::fan), flips,
//! collapses and smoothing (super::super::smooth).

use std::collections::{HashMap, HashSet};

use spade::Triangulation;
use spade::handles::FixedVertexHandle;

use crate::geometry::TriMesh;
use crate::math::Vec3;

use super::layout::Layout;
use super::plane::{barycentric_2d, dist_sq_point_segment_2d, point_in_polygon, sub2};
use crate::cut::cells::{FaceKind, flip_to_surface_quality};
use crate::cut::collapse::{
    SplitTriangle, collapse_boundary_splits, collapse_to_quality, drop_vertices,
};
use crate::cut::fan::plan_fan;
use crate::cut::smooth::smooth_to_quality;
use crate::cut::wound::Assembly;

/// Points of the chart lifted onto the original surface through R's triangles.
pub(super) struct Lifter<'a> {
    mesh: &'a TriMesh,
    region2: Vec<([[f64; 2]; 3], usize)>,
}

impl<'a> Lifter<'a> {
    pub fn new(mesh: &'a TriMesh, layout: &Layout) -> Self {
        Self {
            mesh,
            region2: layout
                .region
                .iter()
                .map(|&t| (layout.chart.triangle(mesh, t), t))
                .collect(),
        }
    }

    /// `p` of the chart on the surface.
    pub fn lift(&self, p: [f64; 2]) -> Vec3 {
        let mut best = (f64::INFINITY, self.region2[0].1, [1.0 / 3.0; 3]);
        for &(tri, t) in &self.region2 {
            if let Some(bary) = barycentric_2d(&tri, p) {
                let outside = bary.iter().map(|&x| (-x).max(0.0)).sum::<f64>();
                if outside < best.0 {
                    best = (outside, t, bary);
                }
                if outside == 0.0 {
                    break;
                }
            }
        }
        let (_, t, mut bary) = best;
        // Clamp onto the triangle (points a rounding error outside R).
        bary.iter_mut().for_each(|x| *x = x.max(0.0));
        let sum: f64 = bary.iter().sum();
        let [a, b, c] = self.mesh.corners(t);
        (a * bary[0] + b * bary[1] + c * bary[2]) / sum
    }
}

/// Which input segment a new vertex of the triangulation was put on (boundary k, upper lip
/// r, lower lip r).
#[derive(Clone, Copy)]
enum On {
    Boundary(usize),
    Upper(usize),
    Lower(usize),
}

/// Vertices put on segments: (parameter along the segment, vertex), by segment.
type Inserts = HashMap<usize, Vec<(f64, u32)>>;

/// The incised skin, before the walls.
pub(super) struct Assembled {
    pub assembly: Assembly,
    /// The lips as refined: (parameter along the lip in [0, 1], vertex).
    pub upper_chain: Vec<(f64, u32)>,
    pub lower_chain: Vec<(f64, u32)>,
    /// Vertices put on R's boundary edges, in order along each edge (boundary edge k).
    pub boundary_inserts: Inserts,
}

/// The new vertices the refinement put on R's boundary and the lips, with the segment and
/// the parameter along it.
fn on_segments(layout: &Layout, edge: f64) -> HashMap<usize, (On, f64)> {
    let Layout {
        cdt,
        cdt_to_mesh,
        upper_handles,
        lower_handles,
        boundary2,
        upper,
        lower,
        m,
        length,
        ..
    } = layout;
    let tol2 = (1e-9 * edge.max(*length)).powi(2);
    let lip_seg = |lip: &[[f64; 2]], r: usize| (lip[r], lip[r + 1]);
    let mut on_segment: HashMap<usize, (On, f64)> = HashMap::new();
    let known: HashSet<usize> = cdt_to_mesh
        .keys()
        .copied()
        .chain(upper_handles.iter().map(|h| h.index()))
        .chain(lower_handles.iter().map(|h| h.index()))
        .collect();
    for vh in cdt.fixed_vertices() {
        if known.contains(&vh.index()) {
            continue;
        }
        let p = cdt.vertex(vh).position();
        let q = [p.x, p.y];
        let param = |a: [f64; 2], b: [f64; 2]| {
            let ab = sub2(b, a);
            let len2 = ab[0] * ab[0] + ab[1] * ab[1];
            let aq = sub2(q, a);
            (aq[0] * ab[0] + aq[1] * ab[1]) / len2
        };
        let mut found = None;
        for k in 0..boundary2.len() {
            let (a, b) = (boundary2[k], boundary2[(k + 1) % boundary2.len()]);
            if dist_sq_point_segment_2d(q, a, b) < tol2 {
                found = Some((On::Boundary(k), param(a, b)));
                break;
            }
        }
        if found.is_none() {
            for r in 0..*m {
                let (a, b) = lip_seg(upper, r);
                if dist_sq_point_segment_2d(q, a, b) < tol2 {
                    found = Some((On::Upper(r), param(a, b)));
                    break;
                }
                let (a, b) = lip_seg(lower, r);
                if dist_sq_point_segment_2d(q, a, b) < tol2 {
                    found = Some((On::Lower(r), param(a, b)));
                    break;
                }
            }
        }
        if let Some(f) = found {
            on_segment.insert(vh.index(), f);
        }
    }
    on_segment
}

/// The vertices of the incised surface: the input's, minus the interior vertices of R that
/// were dropped, then the triangulation's new ones, lifted.
struct Vertices {
    positions: Vec<Vec3>,
    source: Vec<Option<u32>>,
    /// Input vertex → output vertex.
    remap: Vec<u32>,
    /// Triangulation vertex (handle index) → output vertex.
    cdt_vertex: HashMap<usize, u32>,
}

fn vertices(
    mesh: &TriMesh,
    layout: &Layout,
    on_segment: &HashMap<usize, (On, f64)>,
    lifter: &Lifter,
) -> Vertices {
    let Layout {
        cdt,
        cdt_to_mesh,
        interior,
        boundary,
        ..
    } = layout;
    let kept: HashSet<u32> = cdt_to_mesh.values().copied().collect();
    let dropped: HashSet<u32> = interior
        .iter()
        .copied()
        .filter(|v| !kept.contains(v))
        .collect();
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    let mut positions = Vec::with_capacity(mesh.positions.len() + 64);
    let mut source = Vec::with_capacity(mesh.positions.len() + 64);
    for (v, p) in mesh.positions.iter().enumerate() {
        if !dropped.contains(&(v as u32)) {
            remap[v] = positions.len() as u32;
            positions.push(*p);
            source.push(Some(v as u32));
        }
    }
    let mut cdt_vertex: HashMap<usize, u32> = HashMap::new();
    for vh in cdt.fixed_vertices() {
        let id = match cdt_to_mesh.get(&vh.index()) {
            Some(&v) => remap[v as usize],
            None => {
                let p = cdt.vertex(vh).data().0;
                let x = match on_segment.get(&vh.index()) {
                    // On R's boundary: exactly on the original edge, so the triangle outside
                    // R that shares the edge can be split without a crack.
                    Some(&(On::Boundary(k), t)) => {
                        let a = mesh.positions[boundary[k] as usize];
                        let b = mesh.positions[boundary[(k + 1) % boundary.len()] as usize];
                        a + (b - a) * t.clamp(0.0, 1.0)
                    }
                    _ => lifter.lift([p.x, p.y]),
                };
                positions.push(x);
                source.push(None);
                (positions.len() - 1) as u32
            }
        };
        cdt_vertex.insert(vh.index(), id);
    }
    Vertices {
        positions,
        source,
        remap,
        cdt_vertex,
    }
}

/// Re-assembles the surface around R's triangulation (the module docs).
pub(super) fn assemble(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    layout: &Layout,
    edge: f64,
    lifter: &Lifter,
) -> Assembled {
    let on_segment = on_segments(layout, edge);
    let Vertices {
        mut positions,
        mut source,
        remap,
        mut cdt_vertex,
    } = vertices(mesh, layout, &on_segment, lifter);
    let [mut boundary_inserts, mut upper_inserts, mut lower_inserts] =
        inserts_of(&on_segment, &cdt_vertex);
    let (mut triangles, mut out_kinds, mut created, split_outside) =
        triangles_of(mesh, kinds, layout, &remap, &cdt_vertex, &boundary_inserts);
    // Lifted onto a steep side, R's cells on a piece of its boundary split a fraction of a
    // millimetre from a corner lose more than half their angle (the tumour's default cut:
    // 27° in the plane, 10° on the surface), and the triangle beyond is fanned into
    // needles: such splits are collapsed along their edge where that helps (super::collapse).
    let mut split_outside = split_outside;
    let mut gone: Vec<(u32, u32)> = collapse_boundary_splits(
        &positions,
        &mut triangles,
        &mut out_kinds,
        &mut created,
        &mut split_outside,
    );
    // The triangles beyond R's split boundary, fanned from the point that gives the best
    // smallest angle: the corner opposite a lone split edge, or a new vertex inside (the
    // triangle is flat, so the fan keeps its shape). A split piece much shorter than the
    // triangle is tall fans from the corner into a needle (the tumour's 1.2 mm skin
    // triangles split 0.25 mm from a corner: 9.1°); from a point nearer the split edge it
    // does not.
    for out in split_outside {
        for f in plan_fan(&positions, out.corners, &out.splits).commit(&mut positions, &mut source)
        {
            created.push(triangles.len() as u32);
            triangles.push(f);
            out_kinds.push(out.kind);
        }
    }
    flip_to_surface_quality(
        &positions,
        &mut triangles,
        &out_kinds,
        &created,
        FaceKind::Skin,
        |_, _| false,
    );
    // R's own new vertices where their cells, lifted, came out poorly: collapsed into a
    // neighbour where that helps.
    let lip_handles: HashSet<usize> = layout
        .upper_handles
        .iter()
        .chain(&layout.lower_handles)
        .map(|h| h.index())
        .collect();
    // (New vertices of R off its boundary and the lips.)
    let steiner_of = |cdt_vertex: &HashMap<usize, u32>| -> HashSet<u32> {
        cdt_vertex
            .iter()
            .filter(|(h, _)| {
                !layout.cdt_to_mesh.contains_key(h)
                    && !lip_handles.contains(h)
                    && !on_segment.contains_key(h)
            })
            .map(|(_, &id)| id)
            .collect()
    };
    gone.extend(collapse_to_quality(
        &positions,
        &mut triangles,
        &mut out_kinds,
        &mut created,
        &steiner_of(&cdt_vertex),
    ));
    if !gone.is_empty() {
        let gone: HashSet<u32> = gone.iter().map(|&(v, _)| v).collect();
        let new_id = drop_vertices(&gone, &mut positions, &mut source);
        for tri in &mut triangles {
            *tri = tri.map(|w| new_id[w as usize]);
        }
        cdt_vertex.retain(|_, w| !gone.contains(w));
        cdt_vertex
            .values_mut()
            .for_each(|w| *w = new_id[*w as usize]);
        for list in boundary_inserts
            .values_mut()
            .chain(upper_inserts.values_mut())
            .chain(lower_inserts.values_mut())
        {
            list.retain(|&(_, w)| !gone.contains(&w));
            list.iter_mut().for_each(|(_, w)| *w = new_id[*w as usize]);
        }
        boundary_inserts.retain(|_, list| !list.is_empty());
    }
    // Those left whose cells are still poor on the surface: moved within their rings.
    smooth_to_quality(
        &mut positions,
        &triangles,
        &steiner_of(&cdt_vertex),
        |p| layout.chart.point(mesh, p),
        |p| lifter.lift(p),
    );
    let upper_chain = chain(layout, &layout.upper_handles, &upper_inserts, &cdt_vertex);
    let lower_chain = chain(layout, &layout.lower_handles, &lower_inserts, &cdt_vertex);
    Assembled {
        assembly: Assembly {
            positions,
            source,
            triangles,
            kinds: out_kinds,
            created,
        },
        upper_chain,
        lower_chain,
        boundary_inserts,
    }
}

/// The vertices put on R's boundary edges, the upper and the lower lip, in order along each
/// segment.
fn inserts_of(
    on_segment: &HashMap<usize, (On, f64)>,
    cdt_vertex: &HashMap<usize, u32>,
) -> [Inserts; 3] {
    let mut boundary_inserts: Inserts = HashMap::new();
    let mut upper_inserts: Inserts = HashMap::new();
    let mut lower_inserts: Inserts = HashMap::new();
    for (&h, &(on, t)) in on_segment {
        let id = cdt_vertex[&h];
        let (map, key) = match on {
            On::Boundary(k) => (&mut boundary_inserts, k),
            On::Upper(r) => (&mut upper_inserts, r),
            On::Lower(r) => (&mut lower_inserts, r),
        };
        map.entry(key).or_default().push((t, id));
    }
    for list in boundary_inserts
        .values_mut()
        .chain(upper_inserts.values_mut())
        .chain(lower_inserts.values_mut())
    {
        list.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    [boundary_inserts, upper_inserts, lower_inserts]
}

/// A lip as refined: (parameter along the lip in [0, 1], vertex), from its handles and the
/// vertices the refinement put on its segments.
fn chain(
    layout: &Layout,
    handles: &[FixedVertexHandle],
    inserts: &Inserts,
    cdt_vertex: &HashMap<usize, u32>,
) -> Vec<(f64, u32)> {
    let m = layout.m;
    let mut out = Vec::new();
    for r in 0..=m {
        out.push((r as f64 / m as f64, cdt_vertex[&handles[r].index()]));
        if r < m
            && let Some(list) = inserts.get(&r)
        {
            out.extend(list.iter().map(|&(t, id)| ((r as f64 + t) / m as f64, id)));
        }
    }
    out
}

/// The triangles, their kinds and the created ones: those outside R unchanged (those whose
/// edge on R's boundary was split are set aside, to be fanned), and R's triangulation —
/// skin, and lids in the lens between the lips.
fn triangles_of(
    mesh: &TriMesh,
    kinds: &[FaceKind],
    layout: &Layout,
    remap: &[u32],
    cdt_vertex: &HashMap<usize, u32>,
    boundary_inserts: &Inserts,
) -> (Vec<[u32; 3]>, Vec<FaceKind>, Vec<u32>, Vec<SplitTriangle>) {
    let Layout {
        boundary,
        boundary2,
        lens,
        cdt,
        excluded,
        in_region,
        ..
    } = layout;
    let mut triangles: Vec<[u32; 3]> = Vec::with_capacity(mesh.triangles.len() + 256);
    let mut out_kinds = Vec::with_capacity(mesh.triangles.len() + 256);
    let mut created = Vec::new();
    // Triangles outside R: unchanged, unless R's boundary edge they share was split.
    let mut split_of: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (&k, list) in boundary_inserts {
        let (a, b) = (boundary[k], boundary[(k + 1) % boundary.len()]);
        // The outside triangle runs the edge from b to a.
        split_of.insert((b, a), list.iter().rev().map(|&(_, id)| id).collect());
    }
    // Triangles outside R whose edge was split are covered once R's boundary splits are
    // settled (by the caller).
    let mut split_outside: Vec<SplitTriangle> = Vec::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if in_region[t] {
            continue;
        }
        let splits: [Vec<u32>; 3] = std::array::from_fn(|e| {
            split_of
                .get(&(tri[e], tri[(e + 1) % 3]))
                .cloned()
                .unwrap_or_default()
        });
        let corners = tri.map(|v| remap[v as usize]);
        if splits.iter().all(|s| s.is_empty()) {
            triangles.push(corners);
            out_kinds.push(kinds[t]);
        } else {
            split_outside.push(SplitTriangle {
                corners,
                splits,
                kind: kinds[t],
            });
        }
    }
    for face in cdt.inner_faces() {
        let vs = face.vertices();
        let p = vs.map(|v| v.position());
        let c = [
            (p[0].x + p[1].x + p[2].x) / 3.0,
            (p[0].y + p[1].y + p[2].y) / 3.0,
        ];
        let kind = if !excluded.contains(&face.fix()) {
            FaceKind::Skin
        } else if point_in_polygon(lens, c) && point_in_polygon(boundary2, c) {
            FaceKind::Lid
        } else {
            continue;
        };
        // spade's faces are counter-clockwise in (s, t), i.e. their normal is +n̄: outward.
        created.push(triangles.len() as u32);
        triangles.push(vs.map(|v| cdt_vertex[&v.fix().index()]));
        out_kinds.push(kind);
    }
    (triangles, out_kinds, created, split_outside)
}
