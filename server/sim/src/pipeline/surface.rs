//! The rendered surface in its current configuration.
//!
//! Vertices follow the meshless field (physics.md §5.3):
//! `x_v = Σ_k ŵ_vk (p_k + F_k (X_v − X_k))`. Only vertices that follow moved points are
//! recomputed, and only their triangles' boxes are updated in the BVH used for blade contact
//! (refitted in place, never rebuilt). After a cut, a vertex stops following points across the
//! cut surface Σ (its weights toward them drop to zero).

use std::sync::Arc;

use crate::cut::corners_of_kind;
use crate::cut::{Blade, FaceKind, Incised, SweptSurface, Wound, segment_meets_triangle};
use crate::geometry::TriMesh;
use crate::geometry::parry_adapter::TriangleBvh;
use crate::geometry::predicates::{closest_point_on_triangle, line_triangle};
use crate::math::{Aabb, Mat3, Vec3};
use crate::mls::MlsOperator;
use crate::mls::forces::Threads;
use crate::model::rows::Rows;
use crate::model::{Blockers, CoupledModel, Kernel, RestGrid, SurfaceEmbedding};

/// Where the blade meets the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceContact {
    /// The blade tip is inside the tissue.
    pub tip_inside: bool,
    /// Entry point on the current surface, where the edge crosses it going in (m).
    pub entry: Option<Vec3>,
    /// The entry triangle and barycentric coordinates.
    pub entry_triangle: Option<(usize, [f64; 3])>,
    /// Outward unit normal of the entry triangle.
    pub normal: Vec3,
    /// With the tip outside: where the edge leaves the tissue again, when it passes right
    /// through a part (m). The blade is then in the tissue between `entry` and `exit`.
    pub exit: Option<Vec3>,
}

impl SurfaceContact {
    /// Part of the edge is in the tissue: the tip, or a stretch between entry and exit.
    pub fn immersed(&self) -> bool {
        self.tip_inside || self.exit.is_some()
    }

    /// No blade.
    pub fn none() -> Self {
        Self {
            tip_inside: false,
            entry: None,
            entry_triangle: None,
            normal: Vec3::z(),
            exit: None,
        }
    }
}

/// New vertices' embedding rows computed before they land.
pub struct PrecomputedRows {
    pub(crate) rows: Vec<Option<Vec<(u32, f64)>>>,
    pub(crate) sigma_seen: usize,
}

impl PrecomputedRows {
    /// Vertex `v`'s row at `x`, if it was computed and no triangle Σ gained since (`sigma`
    /// whole, with `boxes`) hides one of its points: then it is the row
    /// [`SurfaceEmbedding::row_for`] gives against all of Σ, exactly (the points it finds
    /// are those the snapshot's Σ let through less those the new triangles hide, and the
    /// support it widened to is the same).
    pub fn take(
        &mut self,
        v: usize,
        x: &Vec3,
        body: &[Vec3],
        sigma: &[[Vec3; 3]],
        boxes: &[Aabb],
    ) -> Option<Vec<(u32, f64)>> {
        let row = self.rows.get_mut(v)?.take()?;
        let (new, new_boxes) = (&sigma[self.sigma_seen..], &boxes[self.sigma_seen..]);
        let hidden = row
            .iter()
            .any(|&(k, _)| SurfaceEmbedding::hidden(x, &body[k as usize], new, new_boxes));
        (!hidden).then_some(row)
    }
}

/// What a surface's queries need that depends only on its triangles and rest positions:
/// the triangles around each vertex, the vertices binned in rest space, and a triangle
/// hierarchy shaped over the rest positions. A re-cut's surface gets its index on the
/// re-cut worker (`recut_worker`), so that the tick it lands on only refits the hierarchy's
/// boxes to where the vertices are ([`TriangleBvh::refit_to`]) instead of building one.
pub struct SurfaceIndex {
    vertex_triangles: Rows,
    vertex_grid: RestGrid,
    bvh: TriangleBvh,
}

impl SurfaceIndex {
    /// The index of `mesh` (at rest), its vertices binned by `support_m`.
    pub(crate) fn of(mesh: &TriMesh, support_m: f64) -> Self {
        let vertex_triangles = Rows::build(
            mesh.positions.len(),
            (mesh.triangles.iter().enumerate())
                .flat_map(|(t, tri)| tri.iter().map(move |&v| (v, t as u32))),
        );
        Self {
            vertex_triangles,
            vertex_grid: RestGrid::build(&mesh.positions, support_m),
            bvh: TriangleBvh::build(mesh),
        }
    }
}

/// The current surface and what is needed to move it with the points.
pub struct CurrentSurface {
    /// Current positions (m) and the triangles.
    pub mesh: TriMesh,
    /// What each triangle is (skin, wound wall, lid).
    pub kinds: Vec<FaceKind>,
    /// The incisions opened in it, for a deeper pass to take their walls down (shared with
    /// the base of a stroke cut from it).
    pub wounds: Arc<Vec<Wound>>,
    rest: Vec<Vec3>,
    kernel: Kernel,
    bvh: TriangleBvh,
    vertex_triangles: Rows,
    point_vertices: Rows,
    embedding: SurfaceEmbedding,
    /// The embedding before the last re-mesh, whose buffers the next one fills.
    next_embedding: SurfaceEmbedding,
    /// Where a new vertex's row is found when the worker's no longer stands: the cut
    /// triangles near it, and the row.
    row_scratch: (Vec<u32>, Vec<(u32, f64)>),
    vertex_grid: RestGrid,
    support_m: f64,
    // Scratch, reused every tick.
    vertex_flag: Vec<bool>,
    vertex_list: Vec<u32>,
    triangle_flag: Vec<bool>,
    triangle_list: Vec<u32>,
    point_flag: Vec<bool>,
    /// Each point's position when the vertices that follow it were last placed.
    followed: Vec<Vec3>,
    point_list: Vec<u32>,
    gradients: Vec<Mat3>,
    /// The listed points' new gradients and the listed vertices' new places, in list order
    /// (made in two parts, then stored in order).
    new_gradients: Vec<Mat3>,
    new_places: Vec<Vec3>,
    crossings: Vec<Crossing>,
}

/// The surface's per-vertex and per-triangle buffers (and a stroke's base, `stroke_tracker`)
/// have room for this many times the uncut surface's vertices and triangles, so that a
/// re-cut landing or a stroke's start fills them without allocating (a 60 mm cut grows
/// the cerebroma's surface by 1.4×).
pub(crate) const SURFACE_ROOM: usize = 3;

/// An empty vector with room for `n` items.
fn room<T>(n: usize) -> Vec<T> {
    Vec::with_capacity(SURFACE_ROOM * n)
}

/// `n` copies of `value`, with room for [`SURFACE_ROOM`] times as many.
fn filled<T: Clone>(n: usize, value: T) -> Vec<T> {
    let mut v = room(n);
    v.resize(n, value);
    v
}

/// Vertices follow a point again once it has moved this far (m) since they were last
/// placed: well below what a display or the blade contact can resolve, and most awake
/// points near a cut are still at any one tick.
const FOLLOW_TOLERANCE_M: f64 = 1e-6;

/// A `followed` position that always counts as moved.
const STALE: Vec3 = Vec3::new(f64::NAN, f64::NAN, f64::NAN);

/// Where a segment passes through a surface triangle.
#[derive(Debug, Clone, Copy)]
pub struct Crossing {
    /// Parameter along the segment, 0 at its start.
    s: f64,
    triangle: usize,
    bary: [f64; 3],
    /// The segment goes in (against the outward normal) rather than out.
    entering: bool,
}

/// Crossings closer than this along a segment (as a fraction of it) are one crossing seen
/// by several triangles: a segment through a shared edge or vertex hits all of them.
const SAME_CROSSING: f64 = 1e-9;

/// Sorts `crossings` along the segment and merges each cluster of hits at one place into a
/// single crossing with the net direction of the cluster (none when it goes in and out
/// again, a touch). Parity counts on the result are right even when the segment passes
/// exactly through a mesh edge or vertex, as a blade on a symmetric part's centre line does.
fn merge_crossings(crossings: &mut Vec<Crossing>) {
    crossings.sort_by(|a, b| a.s.total_cmp(&b.s));
    let (mut read, mut write) = (0, 0);
    while read < crossings.len() {
        let start = read;
        let mut net = 0i32;
        while read < crossings.len() && crossings[read].s - crossings[start].s <= SAME_CROSSING {
            net += if crossings[read].entering { 1 } else { -1 };
            read += 1;
        }
        if net != 0 {
            let mut kept = crossings[start];
            kept.entering = net > 0;
            crossings[write] = kept;
            write += 1;
        }
    }
    crossings.truncate(write);
}

impl CurrentSurface {
    /// The surface of `model` at rest, for a solver with `spare_nodes` virtual nodes after
    /// the body's points.
    pub fn new(model: &CoupledModel, spare_nodes: usize) -> Self {
        let mesh = model.surface.clone();
        let nv = mesh.positions.len();
        let SurfaceIndex {
            vertex_triangles,
            vertex_grid,
            bvh,
        } = SurfaceIndex::of(&mesh, model.kernel.support_m);
        let emb = &model.embedding;
        // A landing lists the vertices of every solver point, the virtual nodes included.
        let mut point_vertices = Rows::default();
        point_vertices.reserve(
            model.points.len() + spare_nodes,
            SURFACE_ROOM * emb.points.len(),
        );
        point_vertices.refill(
            model.points.len(),
            (0..nv).flat_map(|v| emb.of(v).0.iter().map(move |&k| (k, v as u32))),
        );
        let nt = mesh.triangles.len();
        // The embedding's buffers with room to grow, twice (the current and the one
        // before, which the next landing fills).
        let embedding = || {
            let mut e = SurfaceEmbedding {
                start: room(nv + 1),
                points: room(emb.points.len()),
                weights: room(emb.weights.len()),
                widened: emb.widened,
            };
            e.start.extend_from_slice(&emb.start);
            e.points.extend_from_slice(&emb.points);
            e.weights.extend_from_slice(&emb.weights);
            e
        };
        let mut rest = room(nv);
        rest.extend_from_slice(&mesh.positions);
        Self {
            bvh,
            kinds: filled(nt, FaceKind::Skin),
            wounds: Arc::default(),
            kernel: model.kernel,
            rest,
            vertex_grid,
            support_m: model.kernel.support_m,
            vertex_flag: filled(nv, false),
            vertex_list: room(nv),
            triangle_flag: filled(nt, false),
            triangle_list: room(nt),
            point_flag: vec![false; model.points.len()],
            followed: vec![STALE; model.points.len()],
            point_list: Vec::with_capacity(model.points.len()),
            gradients: vec![Mat3::identity(); model.points.len()],
            new_gradients: Vec::with_capacity(model.points.len()),
            new_places: room(nv),
            crossings: Vec::with_capacity(64),
            mesh,
            vertex_triangles,
            point_vertices,
            embedding: embedding(),
            next_embedding: embedding(),
            row_scratch: (Vec::with_capacity(1024), Vec::with_capacity(256)),
        }
    }

    /// Rest position of a point on the surface given by triangle and barycentrics.
    pub fn rest_point(&self, triangle: usize, bary: [f64; 3]) -> Vec3 {
        let [a, b, c] = self.mesh.triangles[triangle];
        self.rest[a as usize] * bary[0]
            + self.rest[b as usize] * bary[1]
            + self.rest[c as usize] * bary[2]
    }

    /// Moves the vertices that follow any of `moved` points to their place in the field at
    /// positions `p`, and updates their triangles in the BVH. Returns how many moved.
    pub fn follow(
        &mut self,
        op: &MlsOperator,
        rest_points: &[Vec3],
        p: &[Vec3],
        moved: &[u32],
        threads: Threads,
    ) -> usize {
        let count = self.place_followers(op, rest_points, p, moved, threads);
        for &t in &self.triangle_list {
            let t = t as usize;
            self.bvh.update(t, &self.mesh.corners(t));
        }
        count
    }

    /// [`Self::follow`] without the BVH: the vertices move, `triangle_list` lists the
    /// triangles they moved.
    fn place_followers(
        &mut self,
        op: &MlsOperator,
        rest_points: &[Vec3],
        p: &[Vec3],
        moved: &[u32],
        threads: Threads,
    ) -> usize {
        self.vertex_list.clear();
        self.list_followers(p, moved);
        self.place_listed(op, rest_points, p, threads)
    }

    /// Adds to `vertex_list` the vertices of the points in `moved` that have moved since
    /// their vertices were last placed.
    fn list_followers(&mut self, p: &[Vec3], moved: &[u32]) {
        for &k in moved {
            let k = k as usize;
            // Nodes after the body's points (virtual points) carry no surface.
            if k >= self.followed.len() {
                continue;
            }
            // A point that has not moved by more than the tolerance since its vertices were
            // last placed leaves them where they are.
            if (p[k] - self.followed[k]).norm_squared() < FOLLOW_TOLERANCE_M * FOLLOW_TOLERANCE_M {
                continue;
            }
            self.followed[k] = p[k];
            for &v in self.point_vertices.of(k) {
                if !std::mem::replace(&mut self.vertex_flag[v as usize], true) {
                    self.vertex_list.push(v);
                }
            }
        }
    }

    /// Places the vertices in `vertex_list` in the field; `triangle_list` lists the
    /// triangles they moved. Returns how many.
    fn place_listed(
        &mut self,
        op: &MlsOperator,
        rest_points: &[Vec3],
        p: &[Vec3],
        threads: Threads,
    ) -> usize {
        // The gradients those vertices read: a frozen point next to a moving one deforms too.
        self.point_list.clear();
        for &v in &self.vertex_list {
            for &k in self.embedding.of(v as usize).0 {
                if !std::mem::replace(&mut self.point_flag[k as usize], true) {
                    self.point_list.push(k);
                }
            }
        }
        // Each gradient and each place depends on its own point or vertex only: two parts
        // give one's bits.
        in_two_parts(threads, &self.point_list, &mut self.new_gradients, |&k| {
            op.deformation_gradient(k as usize, p)
        });
        for (&k, g) in self.point_list.iter().zip(&self.new_gradients) {
            self.point_flag[k as usize] = false;
            self.gradients[k as usize] = *g;
        }
        let (embedding, rest, gradients) = (&self.embedding, &self.rest, &self.gradients);
        in_two_parts(threads, &self.vertex_list, &mut self.new_places, |&v| {
            let v = v as usize;
            let (points, weights) = embedding.of(v);
            let xv = rest[v];
            let mut x = Vec3::zeros();
            for (&k, &w) in points.iter().zip(weights) {
                if w == 0.0 {
                    continue;
                }
                let k = k as usize;
                x += (p[k] + gradients[k] * (xv - rest_points[k])) * w;
            }
            x
        });
        self.triangle_list.clear();
        for (&v, &x) in self.vertex_list.iter().zip(&self.new_places) {
            let v = v as usize;
            self.vertex_flag[v] = false;
            self.mesh.positions[v] = x;
            for &t in self.vertex_triangles.of(v) {
                if !std::mem::replace(&mut self.triangle_flag[t as usize], true) {
                    self.triangle_list.push(t);
                }
            }
        }
        for &t in &self.triangle_list {
            self.triangle_flag[t as usize] = false;
        }
        self.vertex_list.len()
    }

    /// Stops vertices near the rest-space triangle `cut` from following points across it.
    pub fn cut_embedding(&mut self, cut: &[Vec3; 3], rest_points: &[Vec3]) {
        let lo = cut[0].inf(&cut[1]).inf(&cut[2]);
        let hi = cut[0].sup(&cut[1]).sup(&cut[2]);
        let centre = (lo + hi) * 0.5;
        let reach = (hi - lo).norm() * 0.5 + self.support_m * 3.5;
        let rest = &self.rest;
        let embedding = &mut self.embedding;
        let followed = &mut self.followed;
        self.vertex_grid
            .for_each_within(rest, &centre, reach, |v, _| {
                embedding.drop_across(v as usize, &rest[v as usize], rest_points, cut);
                // The vertex reads other points now: move it at the next follow.
                for &k in embedding.of(v as usize).0 {
                    followed[k as usize] = STALE;
                }
            });
    }

    /// Where the blade's edge (from its back P' to its tip P) meets the current surface.
    pub fn contact(&mut self, blade: &Blade) -> SurfaceContact {
        let (p, q) = (blade.back, blade.tip);
        Self::collect_crossings(
            &self.bvh,
            &self.mesh,
            &self.kinds,
            &p,
            &q,
            &mut self.crossings,
        );
        // A closed surface: the tip is inside iff the edge crossed it an odd number of times.
        let tip_inside = if self.crossings.is_empty() {
            self.point_inside(&q)
        } else {
            self.crossings.len() % 2 == 1
        };
        match self.crossings.first() {
            Some(&Crossing {
                s, triangle, bary, ..
            }) => {
                let normal = self
                    .mesh
                    .doubled_area_normal(triangle)
                    .try_normalize(1e-300)
                    .unwrap_or_else(Vec3::z);
                let exit = match self.crossings.get(1) {
                    Some(out) if !tip_inside => Some(p + (q - p) * out.s),
                    _ => None,
                };
                SurfaceContact {
                    tip_inside,
                    entry: Some(p + (q - p) * s),
                    entry_triangle: Some((triangle, bary)),
                    normal,
                    exit,
                }
            }
            None => SurfaceContact {
                tip_inside,
                entry: None,
                entry_triangle: None,
                normal: Vec3::z(),
                exit: None,
            },
        }
    }

    /// Where the segment p→q first goes into the envelope (skin and lids): the triangle,
    /// its barycentrics and the point; `scratch` is the caller's (no allocation while it
    /// has room).
    pub fn first_entry(
        &self,
        p: &Vec3,
        q: &Vec3,
        scratch: &mut Vec<Crossing>,
    ) -> Option<(usize, [f64; 3], Vec3)> {
        Self::collect_crossings(&self.bvh, &self.mesh, &self.kinds, p, q, scratch);
        let hit = scratch
            .iter()
            .find(|c| c.entering)
            .map(|c| (c.triangle, c.bary, p + (q - p) * c.s));
        scratch.clear();
        hit
    }

    /// The crossings of the segment p→q with the envelope (skin and lids; wound walls are
    /// inside it and the blade passes them), merged and in order along the segment.
    fn collect_crossings(
        bvh: &TriangleBvh,
        mesh: &TriMesh,
        kinds: &[FaceKind],
        p: &Vec3,
        q: &Vec3,
        crossings: &mut Vec<Crossing>,
    ) {
        crossings.clear();
        let d = q - p;
        bvh.for_each_overlapping(&p.inf(q), &p.sup(q), |t| {
            if kinds[t] != FaceKind::Wall
                && let Some((s, bary)) = segment_triangle(p, q, &mesh.corners(t))
            {
                crossings.push(Crossing {
                    s,
                    triangle: t,
                    bary,
                    entering: mesh.doubled_area_normal(t).dot(&d) < 0.0,
                });
            }
        });
        merge_crossings(crossings);
    }

    /// Whether `x` is within `margin` of the envelope (skin and lids), or of the wound walls
    /// too when `walls`.
    pub fn near(&self, x: &Vec3, margin: f64, walls: bool) -> bool {
        let d = Vec3::repeat(margin);
        let mut near = false;
        self.bvh.for_each_overlapping(&(x - d), &(x + d), |t| {
            if !near
                && (walls || self.kinds[t] != FaceKind::Wall)
                && (closest_point_on_triangle(x, &self.mesh.corners(t)) - x).norm() <= margin
            {
                near = true;
            }
        });
        near
    }

    /// Whether `x` is inside the current surface (ray parity along +z; used only when the
    /// whole blade is inside or outside).
    fn point_inside(&mut self, x: &Vec3) -> bool {
        let far = x + Vec3::new(0.0, 0.0, 10.0);
        Self::collect_crossings(
            &self.bvh,
            &self.mesh,
            &self.kinds,
            x,
            &far,
            &mut self.crossings,
        );
        let inside = self.crossings.len() % 2 == 1;
        self.crossings.clear();
        inside
    }

    /// The support radius of the model (m).
    pub fn support(&self) -> f64 {
        self.support_m
    }

    /// Kernel of the embedding (for callers that need weights consistent with it).
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Rest positions of the vertices (m).
    pub fn rest_positions(&self) -> &[Vec3] {
        &self.rest
    }

    /// The surface in rest space (what incisions are computed on).
    pub fn rest_mesh(&self) -> TriMesh {
        TriMesh::new(self.rest.clone(), self.mesh.triangles.clone())
    }

    /// The corners of the wound-wall triangles at their current positions (m), with
    /// repeats: where the incisions are, for a camera or a test to look at.
    pub fn wall_corners(&self) -> Vec<Vec3> {
        corners_of_kind(&self.mesh, &self.kinds, FaceKind::Wall).collect()
    }

    /// The drawn surface (skin and wound walls, no lids) at the current positions, with the
    /// kind of each triangle.
    pub fn drawn(&self) -> (TriMesh, Vec<FaceKind>) {
        let (triangles, kinds) = self.drawn_triangles();
        (TriMesh::new(self.mesh.positions.clone(), triangles), kinds)
    }

    /// The drawn surface in rest space: what the field carries onto the screen, so that
    /// a change of it is what moves there without the tissue moving it.
    pub fn drawn_rest(&self) -> TriMesh {
        TriMesh::new(self.rest.clone(), self.drawn_triangles().0)
    }

    /// The skin alone (no walls, no lids) in rest space.
    pub fn skin_rest(&self) -> TriMesh {
        let skin = self.triangles_where(|k| k == FaceKind::Skin).0;
        TriMesh::new(self.rest.clone(), skin)
    }

    /// The triangles drawn (skin and wound walls, no lids) and their kinds.
    fn drawn_triangles(&self) -> (Vec<[u32; 3]>, Vec<FaceKind>) {
        self.triangles_where(|k| k != FaceKind::Lid)
    }

    /// The triangles whose kind `keep` takes, and their kinds.
    fn triangles_where(&self, keep: impl Fn(FaceKind) -> bool) -> (Vec<[u32; 3]>, Vec<FaceKind>) {
        self.mesh
            .triangles
            .iter()
            .zip(&self.kinds)
            .filter(|(_, k)| keep(**k))
            .map(|(t, k)| (*t, *k))
            .unzip()
    }

    /// Replaces the surface by an incised one. `base_to_current[b]` is the current vertex
    /// that the incision's input vertex b is (vertices keep their embedding); new vertices
    /// are embedded in the points they see without crossing `sigma`; carried vertices stay
    /// where they are and the new ones are placed in the current field. `wounds` are the
    /// incised surface's (taken out of it), `index` its [`SurfaceIndex`] if the worker made
    /// it. `base_to_new` is set to the map from the incision's input vertices to the new
    /// vertices.
    #[allow(clippy::too_many_arguments)]
    pub fn replace(
        &mut self,
        incised: Incised,
        wounds: Arc<Vec<Wound>>,
        base_to_current: &[Option<u32>],
        base_to_new: &mut Vec<Option<u32>>,
        rest_points: &[Vec3],
        grid: &RestGrid,
        sigma: &SweptSurface,
        op: &MlsOperator,
        p: &[Vec3],
        mut precomputed: Option<PrecomputedRows>,
        index: Option<SurfaceIndex>,
    ) {
        let Incised {
            mut mesh,
            kinds,
            source,
            ..
        } = incised;
        let nv = mesh.positions.len();
        // The incised surface is this one's now: its rest positions copied into the kept
        // buffer, its index (shaped at rest) made now if the worker did not, and the mesh
        // moved in below with the current positions of its carried vertices.
        let index = index.unwrap_or_else(|| SurfaceIndex::of(&mesh, self.support_m));
        self.rest.clone_from(&mesh.positions);
        // The new rows go into the embedding before last (its buffers kept): carried rows
        // are copied from the current one, not gathered into a vector each.
        let mut next = std::mem::take(&mut self.next_embedding);
        next.restart(self.embedding.widened);
        base_to_new.clear();
        base_to_new.resize(base_to_current.len(), None);
        // Vertices follow the body's points only: the virtual points after them are no
        // place for a vertex (the nearest-point fallback of `row_for` could pick one).
        let body = &rest_points[..self.followed.len()];
        let carried = |v: usize| source[v].and_then(|b| base_to_current[b as usize]);
        for v in 0..nv {
            if let Some(b) = source[v] {
                base_to_new[b as usize] = Some(v as u32);
            }
            if let Some(c) = carried(v) {
                let (points, weights) = self.embedding.of(c as usize);
                next.push_row(points.iter().copied().zip(weights.iter().copied()));
                // A carried vertex keeps its row, so it stays where it is (as its points
                // last placed it: `followed` is theirs as it was).
                mesh.positions[v] = self.mesh.positions[c as usize];
                continue;
            }
            // A new vertex's row the worker computed stands unless Σ has since grown
            // across it (`PrecomputedRows::take`); otherwise it is found here.
            let x = self.rest[v];
            let ready = (precomputed.as_mut())
                .and_then(|pre| pre.take(v, &x, body, &sigma.triangles, &sigma.boxes));
            if let Some(row) = ready {
                next.push_row(row.iter().copied());
                continue;
            }
            let blockers = Blockers {
                triangles: &sigma.triangles,
                boxes: &sigma.boxes,
            };
            let (within, row) = &mut self.row_scratch;
            SurfaceEmbedding::row_into(&x, body, grid, &self.kernel, blockers, within, row);
            next.push_row(row.iter().copied());
        }
        self.next_embedding = std::mem::replace(&mut self.embedding, next);
        self.mesh = mesh;
        self.kinds = kinds;
        self.wounds = wounds;
        self.rebuild_indices(rest_points.len(), index.vertex_triangles, index.vertex_grid);
        // The new vertices are placed in the field.
        (self.vertex_list).extend((0..nv).filter(|&v| carried(v).is_none()).map(|v| v as u32));
        self.place_listed(op, rest_points, p, Threads::One);
        // The hierarchy (shaped over the rest positions) is refitted once to where the
        // vertices are, not leaf by leaf.
        self.bvh = index.bvh;
        self.bvh.refit_to(&self.mesh);
    }

    /// Adjacency (`vertex_triangles`, `vertex_grid` of the current mesh, and the points'
    /// vertices from the embedding) and scratch sized for the current mesh.
    fn rebuild_indices(&mut self, points: usize, vertex_triangles: Rows, vertex_grid: RestGrid) {
        let nv = self.mesh.positions.len();
        let nt = self.mesh.triangles.len();
        self.vertex_triangles = vertex_triangles;
        let emb = &self.embedding;
        self.point_vertices.refill(
            points,
            (0..nv).flat_map(|v| emb.of(v).0.iter().map(move |&k| (k, v as u32))),
        );
        self.vertex_grid = vertex_grid;
        // (Cleared and refilled in the kept buffers: no allocation while they have room.)
        self.vertex_flag.clear();
        self.vertex_flag.resize(nv, false);
        self.vertex_list.clear();
        self.triangle_flag.clear();
        self.triangle_flag.resize(nt, false);
        self.triangle_list.clear();
    }

    /// Whether vertex `v`'s embedding crosses `cut` (for tests).
    pub fn follows_across(&self, v: usize, rest_points: &[Vec3], cut: &[Vec3; 3]) -> bool {
        let (points, weights) = self.embedding.of(v);
        points.iter().zip(weights).any(|(&k, &w)| {
            w > 0.0 && segment_meets_triangle(&self.rest[v], &rest_points[k as usize], cut)
        })
    }
}

/// `out[i] = each(&items[i])` for every item, the two halves on `threads` (`out` keeps
/// its room: no allocation while it has some).
fn in_two_parts<T: Sync, R: Send + Copy + Default>(
    threads: Threads,
    items: &[T],
    out: &mut Vec<R>,
    each: impl Fn(&T) -> R + Sync,
) {
    out.clear();
    out.resize(items.len(), R::default());
    let half = items.len() / 2;
    let (items_a, items_b) = items.split_at(half);
    let (out_a, out_b) = out.split_at_mut(half);
    let fill = |items: &[T], out: &mut [R]| {
        for (o, item) in out.iter_mut().zip(items) {
            *o = each(item);
        }
    };
    threads.both(|| fill(items_a, out_a), || fill(items_b, out_b));
}

/// Intersection of the segment p→q with a triangle: the parameter along the segment and the
/// barycentric coordinates, or `None`.
fn segment_triangle(p: &Vec3, q: &Vec3, tri: &[Vec3; 3]) -> Option<(f64, [f64; 3])> {
    line_triangle(p, &(q - p), tri).filter(|(t, _)| (0.0..=1.0).contains(t))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(s: f64, entering: bool) -> Crossing {
        Crossing {
            s,
            triangle: 0,
            bary: [1.0 / 3.0; 3],
            entering,
        }
    }

    #[test]
    fn a_crossing_through_a_shared_edge_or_vertex_counts_once() {
        // Through an edge (two triangles) going in, out through a vertex (five triangles).
        let mut c = vec![hit(0.5, true), hit(0.2, true), hit(0.2 + 1e-13, true)];
        c.extend((0..5).map(|k| hit(0.8 + k as f64 * 1e-14, false)));
        merge_crossings(&mut c);
        assert_eq!(c.len(), 3);
        assert!(c[0].entering && (c[0].s - 0.2).abs() < 1e-12);
        assert!(c[1].entering && c[1].s == 0.5);
        assert!(!c[2].entering);
    }

    #[test]
    fn a_touch_on_a_silhouette_edge_is_no_crossing() {
        let mut c = vec![hit(0.4, true), hit(0.4, false)];
        merge_crossings(&mut c);
        assert!(c.is_empty());
    }

    #[test]
    fn distinct_crossings_are_kept_in_order() {
        let mut c = vec![hit(0.9, false), hit(0.1, true)];
        merge_crossings(&mut c);
        assert_eq!(c.len(), 2);
        assert!(c[0].s < c[1].s);
    }
}
