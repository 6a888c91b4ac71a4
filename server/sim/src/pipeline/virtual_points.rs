//! Virtual points (paper §5, physics.md §5.3): kinematic MLS nodes on the wound walls.
//!
//! A cut leaves the points next to it with half a neighbourhood: their moment matrices lose
//! rank on the cut side (planar points, orphans in slivers) and nothing ties the wall the
//! renderer draws to the field behind it. Virtual points are nodes placed on the walls,
//! about one lattice spacing apart: they join the neighbourhoods of the interior points
//! within h on their own side of the cut (never across Σ), so those points' MLS fits are
//! supported on the cut side again — a boundary condition imposed through MLS, which is
//! what the paper means by treating them as boundary points. They have no volume (no
//! stress of their own) and are not integrated: each is slaved to the interior points it
//! is joined to, its displacement in every sub-step the MLS interpolation of theirs, and
//! handing the force on it back to them (`solver::slaves`). So a node moves
//! with the tissue of its wall as the wall vertex does (both are interpolations of the same
//! points) but, unlike a node moved to its wall vertex once a tick, closes no lagged loop:
//! that one pumped energy into the walls over a few wounds, until the solver's guard
//! rolled every tick back (docs/CUTTING-DECISIONS.md, "Virtual points slaved to the points they join").
//!
//! They sit on the walls as the incision draws them (closed in rest space: on Σ within a
//! hairline), a twentieth of a spacing inside the tissue, so the field they carry is the
//! one the wall already follows: they support the fit without driving the opening. A point
//! they would leave full rank by a hair does without them ([`MOST_CONDITION`]).
//!
//! The incision is re-meshed every few millimetres of a stroke, and every re-mesh renumbers
//! the surface; the nodes that still stand on the new walls are kept, the others released,
//! and new ones placed where the wound grew (a topology change, off the per-tick path).
//! Between re-meshes a tick releases the nodes a pair of which the new Σ cut, and those
//! within a support of the blade's edge.

use serde::Serialize;

use crate::cut::{FaceKind, SweptSurface};
use crate::geometry::predicates::{distance_sq_to_segment, segment_meets_triangle};
use crate::math::Vec3;
use crate::mls::operator::PointRank;
use crate::model::{Neighbourhoods, RestGrid};
use crate::solver::Solver;

use super::surface::CurrentSurface;

/// How many nodes one call may place: at most `nodes`, and no more once they have changed
/// the lists of `rows` points (each changed point takes a new MLS row in the same tick).
#[derive(Debug, Clone, Copy)]
pub struct PlaceBudget {
    /// Nodes at most.
    pub nodes: usize,
    /// Points with changed lists after which no node more is placed.
    pub rows: usize,
}

impl PlaceBudget {
    /// Every node waiting (the end of an offline run).
    pub const ALL: Self = Self {
        nodes: usize::MAX,
        rows: usize::MAX,
    };
}

/// Nodes available to a simulation (placed ones are re-used at every re-mesh).
pub const VIRTUAL_NODE_CAPACITY: usize = 1024;
/// Nodes are placed at least this many lattice spacings apart.
const MIN_SEPARATION_SPACINGS: f64 = 0.75;
/// ... and this many spacings inside the tissue from their wall (physics.md §5.3).
const INSET_SPACINGS: f64 = 0.05;
/// A placed node stays through a re-mesh while the new walls have a vertex within this many
/// spacings of it (it is placed [`INSET_SPACINGS`] from one; a re-cut moves the lips by a
/// few hundredths of a spacing, more while the path is short).
const KEEP_SPACINGS: f64 = 0.3;

/// A point whose fit its nodes leave conditioned worse than this (σ_max / σ_min of its
/// moment matrix; 1 inside the lattice, 2–3 at the surface) is not joined to them. On a
/// closed incision the walls lie on Σ, and a node on one can be nearly in the plane a cut
/// point's remaining neighbours span: full rank by a hair, its fit takes the unsampled
/// direction at 1/σ_min, stiff across it by up to 600/3 times (the cerebroma's session: a
/// rollback and 5 × the sub-steps; docs/CUTTING-DECISIONS.md, "The incision closed in rest
/// space").
const MOST_CONDITION: f64 = 20.0;

/// Figures of the virtual points, for reports and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct VirtualPointStats {
    /// Nodes on the walls now.
    pub placed: usize,
    /// Of those, nodes kept from the placement before (the rest are new).
    pub kept: usize,
    /// Neighbour pairs between them and interior points.
    pub pairs: usize,
    /// Wall sites of the last re-mesh left without a node (capacity reached, or no
    /// interior point in reach).
    pub not_placed: usize,
    /// Times the nodes were placed (once per re-mesh).
    pub placements: usize,
}

#[derive(Debug, Clone, Copy)]
struct Node {
    /// Solver index.
    node: u32,
    /// The wall vertex it was placed on.
    vertex: u32,
    /// Rest offset from the vertex into the tissue.
    inset: Vec3,
}

/// What placing nodes reads.
pub struct PlacementInputs<'a> {
    /// The re-meshed surface whose walls they go on.
    pub surface: &'a CurrentSurface,
    /// The cut surface Σ they must not see across.
    pub sigma: &'a SweptSurface,
    /// The blade's rest edge and the radius around it no node goes within.
    pub clear: Option<([Vec3; 2], f64)>,
    /// The grid of the body's points.
    pub grid: &'a RestGrid,
}

impl PlacementInputs<'_> {
    /// Whether `x` lies within the blade's clearance, if there is one.
    fn cleared(&self, x: &Vec3) -> bool {
        self.clear.is_some_and(|(edge, radius)| {
            distance_sq_to_segment(x, &edge[0], &edge[1]) < radius * radius
        })
    }
}

/// The virtual points of a simulation.
pub struct VirtualPoints {
    first: usize,
    capacity: usize,
    nodes: Vec<Node>,
    /// Wall sites (vertex, outward normal) of the current surface chosen at its re-mesh and
    /// not placed yet, in placement order ([`Self::place_pending`]).
    pending: Vec<(u32, Vec3)>,
    spacing_m: f64,
    support_m: f64,
    /// Scratch of [`Self::place_pending`], sized once: placing runs on the simulation
    /// thread, a few nodes a tick.
    scratch: PlacementScratch,
    /// The walls' sites as of the last re-mesh, kept for their buffers.
    walls: Option<WallVertices>,
    /// Figures so far.
    pub stats: VirtualPointStats,
}

/// What placing a node works in: which node slots are taken (releasing borrows these flags
/// for the nodes the new Σ cut), the triangles of Σ near the node (indices) and the points
/// it sees.
#[derive(Debug, Default)]
struct PlacementScratch {
    used: Vec<bool>,
    near_sigma: Vec<u32>,
    candidates: Vec<u32>,
}

/// Room for the points one node sees and the cut triangles near it; more only grows these.
const PLACEMENT_ROOM: usize = 512;

impl VirtualPoints {
    /// Nodes `first..first + capacity` of the solver, for a lattice of `spacing_m` and
    /// support `support_m`.
    pub fn new(first: usize, capacity: usize, spacing_m: f64, support_m: f64) -> Self {
        Self {
            first,
            capacity,
            nodes: Vec::with_capacity(capacity),
            pending: Vec::with_capacity(WALL_ROOM),
            spacing_m,
            support_m,
            walls: Some(WallVertices::with_room()),
            scratch: PlacementScratch {
                used: vec![false; capacity],
                near_sigma: Vec::with_capacity(PLACEMENT_ROOM),
                candidates: Vec::with_capacity(PLACEMENT_ROOM),
            },
            stats: VirtualPointStats::default(),
        }
    }

    /// Solver indices of the placed nodes.
    pub fn nodes(&self) -> impl Iterator<Item = u32> + '_ {
        self.nodes.iter().map(|n| n.node)
    }

    /// The wall vertex node `k` (in placement order) was placed on, and its rest inset.
    pub fn site(&self, k: usize) -> (u32, u32, Vec3) {
        let n = self.nodes[k];
        (n.node, n.vertex, n.inset)
    }

    /// Releases the nodes in `cut` (any order; others are ignored) and those within a
    /// support of the blade's rest `edge`, if it is in the tissue. A pair of a node in `cut` was cut by the
    /// new Σ: its masters are split (its pairs are cut, its interpolation is not). Near
    /// the edge the blade dents and cuts the tissue a node interpolates; kept there, the
    /// tumour scan's session rolled a tick back (docs/CUTTING-DECISIONS.md, "The liver
    /// station's own late ticks"). The next placement puts nodes back once the blade has
    /// gone. Changed lists are appended to `changed`.
    pub fn release_at_blade(
        &mut self,
        edge: Option<[Vec3; 2]>,
        cut: impl Iterator<Item = u32>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        changed: &mut Vec<u32>,
    ) {
        // The cut nodes flagged in the placement's slot flags (refilled when it runs).
        let mut flagged = std::mem::take(&mut self.scratch.used);
        flagged.fill(false);
        let (first, radius) = (self.first, self.support_m);
        for c in cut {
            if let Some(f) = (c as usize)
                .checked_sub(first)
                .and_then(|k| flagged.get_mut(k))
            {
                *f = true;
            }
        }
        // A node one of whose masters the cut has left with no fit follows a point no
        // longer tied to the body (one that falls away under gravity: the shoulder's
        // hesitant trainee dragged a node 2.6 m down, and the wall's points with it).
        for n in &self.nodes {
            if solver
                .masters_of(n.node as usize)
                .any(|m| is_orphan(solver, m))
            {
                flagged[n.node as usize - first] = true;
            }
        }
        self.retain(solver, neighbours, changed, |node, at| {
            let close =
                edge.is_some_and(|[a, b]| distance_sq_to_segment(at, &a, &b) < radius * radius);
            !close && !flagged[node.node as usize - first]
        });
        self.scratch.used = flagged;
    }

    /// Keeps the nodes `keep(node, rest position)` says to (it may move the node's record
    /// to its new wall vertex) and releases the others; their changed lists are appended to
    /// `changed`.
    fn retain(
        &mut self,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        changed: &mut Vec<u32>,
        mut keep: impl FnMut(&mut Node, &Vec3) -> bool,
    ) {
        let mut k = 0;
        while k < self.nodes.len() {
            let at = solver.rest()[self.nodes[k].node as usize];
            if keep(&mut self.nodes[k], &at) {
                k += 1;
            } else {
                release(self.nodes[k].node, solver, neighbours, changed);
                self.nodes.swap_remove(k);
            }
        }
        self.stats.placed = self.nodes.len();
    }

    /// After a re-mesh: keeps the nodes that still stand on the walls of the surface,
    /// releases the others, and chooses where new ones go: wall sites outside the blade's
    /// clearance. As many of those as `budget` allows are placed now, the rest by
    /// [`Self::place_pending`] in the ticks that follow. A node stays, untouched, while the
    /// new walls still have a vertex within [`KEEP_SPACINGS`] of it (and the blade does not
    /// clear that vertex); new ones go to the walls' sites left at least
    /// [`MIN_SEPARATION_SPACINGS`] from every node. The points whose neighbour lists
    /// changed are appended to `changed` (then [`Solver::topology_changed`]).
    ///
    /// Keeping nodes is what makes a re-mesh cost what the wound gained, not what it is: a
    /// re-cut moves the lips along the whole path by a few hundredths of a spacing, and
    /// placing every node again made the cerebroma's landing ticks grow with the wound
    /// (docs/CUTTING-DECISIONS.md, "Virtual points kept across re-meshes"). A kept node's pairs are
    /// still valid: a node a pair of which the growing Σ cuts is released in that tick
    /// ([`Self::release_at_blade`]).
    pub fn remeshed(
        &mut self,
        inputs: &PlacementInputs<'_>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        changed: &mut Vec<u32>,
        budget: PlaceBudget,
    ) {
        // (Out of `self` while `retain` borrows it; put back below.)
        let mut walls = self
            .walls
            .take()
            .expect("the walls are kept between re-meshes");
        walls.refill(inputs.surface);
        let keep_within = KEEP_SPACINGS * self.spacing_m;
        self.retain(solver, neighbours, changed, |node, at| {
            let Some(k) = walls.nearest(at, keep_within) else {
                return false;
            };
            let vertex_at = walls.positions[k];
            if inputs.cleared(&vertex_at) {
                return false;
            }
            walls.taken[k] = true;
            node.vertex = walls.sites[k].0;
            node.inset = at - vertex_at;
            true
        });
        self.stats.kept = self.nodes.len();
        self.stats.not_placed = 0;
        self.stats.placements += 1;
        self.pending.clear();
        let separation = MIN_SEPARATION_SPACINGS * self.spacing_m;
        for k in 0..walls.sites.len() {
            // Sites are picked greedily in vertex order, kept nodes first; a site the blade
            // clears still holds its place (as when every node was placed anew).
            if walls.taken_within(k, separation) {
                continue;
            }
            walls.taken[k] = true;
            if !inputs.cleared(&walls.positions[k]) {
                self.pending.push(walls.sites[k]);
            }
        }
        self.walls = Some(walls);
        // Placed from the end of the list: keep the vertex order.
        self.pending.reverse();
        self.place_pending(inputs, solver, neighbours, changed, budget);
    }

    /// Whether sites chosen at the last re-mesh still wait for their nodes.
    pub fn has_pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Places as many as `budget` allows of the nodes the last re-mesh chose sites for,
    /// skipping sites the blade has come near since; changed lists are appended to
    /// `changed`. Spread over ticks because each node changes the MLS rows of the points it
    /// joins: the end of the cerebroma's stroke placed 80 at once, 7 ms with their rows, in
    /// one tick.
    /// Nothing waiting, it returns at once (it is called every tick).
    pub fn place_pending(
        &mut self,
        inputs: &PlacementInputs<'_>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        changed: &mut Vec<u32>,
        budget: PlaceBudget,
    ) {
        if self.pending.is_empty() {
            return;
        }
        let PlacementInputs {
            surface,
            sigma,
            grid,
            ..
        } = inputs;
        let rest = surface.rest_positions();
        // The lowest free node indices, in order, for the new nodes.
        let PlacementScratch {
            used,
            near_sigma,
            candidates,
        } = &mut self.scratch;
        used.fill(false);
        for n in &self.nodes {
            used[n.node as usize - self.first] = true;
        }
        let first = self.first;
        let mut free = (0..self.capacity)
            .filter(|&slot| !used[slot])
            .map(|slot| (first + slot) as u32);
        let h = self.support_m;
        let rows_before = changed.len();
        for _ in 0..budget.nodes {
            if changed.len() - rows_before >= budget.rows {
                break;
            }
            let Some((vertex, outward)) = self.pending.pop() else {
                break;
            };
            let at = rest[vertex as usize];
            if inputs.cleared(&at) {
                continue;
            }
            let Some(node) = free.next() else {
                self.stats.not_placed += 1;
                continue;
            };
            let inset = -outward * (INSET_SPACINGS * self.spacing_m);
            let x = at + inset;
            // Only the cut triangles within h of the node can hide a point from it.
            near_sigma.clear();
            near_sigma.extend(
                (sigma.boxes.iter().enumerate())
                    .filter(|(_, b)| b.expanded(h).contains(&x))
                    .map(|(t, _)| t as u32),
            );
            candidates.clear();
            let rest_points = solver.rest();
            grid.for_each_within(rest_points, &x, h, |i, _| {
                let seen = !near_sigma.iter().any(|&t| {
                    segment_meets_triangle(
                        &x,
                        &rest_points[i as usize],
                        &sigma.triangles[t as usize],
                    )
                });
                // A point the cut has left with no fit is not tied to the body: a node
                // slaved to it would follow it wherever it drifts.
                if seen && !is_orphan(solver, i) {
                    candidates.push(i);
                }
            });
            let mut connected = 0;
            for &i in candidates.iter() {
                if neighbours.add(i as usize, node).is_err() {
                    continue;
                }
                if neighbours.add(node as usize, i).is_err() {
                    neighbours.remove(i as usize, node);
                    break;
                }
                changed.push(i);
                connected += 1;
            }
            // Its masters are the points it is joined to (its fits' points: every force
            // on it comes from their rows).
            if connected == 0 || !solver.slave_node(node as usize, x, neighbours.of(node as usize))
            {
                release(node, solver, neighbours, changed);
                self.stats.not_placed += 1;
                continue;
            }
            changed.push(node);
            self.nodes.push(Node {
                node,
                vertex,
                inset,
            });
        }
        self.stats.placed = self.nodes.len();
        self.stats.pairs = (self.nodes.iter())
            .map(|n| neighbours.of(n.node as usize).len())
            .sum();
    }

    /// Takes the nodes away from the points among `changed` (refitted) whose fit they left
    /// conditioned worse than [`MOST_CONDITION`], and releases a node left with no point;
    /// the points and nodes whose lists changed go to `again` (to refit).
    pub fn unjoin_ill_conditioned(
        &mut self,
        changed: &[u32],
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        again: &mut Vec<u32>,
    ) {
        let first = self.first as u32;
        for &i in changed {
            if i >= first {
                continue;
            }
            let term = solver.operator().point(i as usize);
            if !matches!(term.rank, PointRank::Full) || term.condition <= MOST_CONDITION {
                continue;
            }
            while let Some(&node) = neighbours
                .of(i as usize)
                .iter()
                .rev()
                .find(|&&j| j >= first)
            {
                neighbours.remove(i as usize, node);
                neighbours.remove(node as usize, i);
                again.push(node);
            }
            again.push(i);
        }
        if again.is_empty() {
            return;
        }
        let mut k = 0;
        while k < self.nodes.len() {
            let node = self.nodes[k].node;
            if neighbours.of(node as usize).is_empty() {
                release(node, solver, neighbours, again);
                self.nodes.swap_remove(k);
                self.stats.not_placed += 1;
            } else {
                k += 1;
            }
        }
        self.stats.placed = self.nodes.len();
    }
}

/// Whether point `i` has no fit (an orphan: too few neighbours left to span space).
fn is_orphan(solver: &Solver, i: u32) -> bool {
    matches!(solver.operator().point(i as usize).rank, PointRank::Orphan)
}

/// Takes node `node` out of every neighbourhood and unties it.
fn release(
    node: u32,
    solver: &mut Solver,
    neighbours: &mut Neighbourhoods,
    changed: &mut Vec<u32>,
) {
    solver.free_node(node as usize);
    let i = node as usize;
    while let Some(&j) = neighbours.of(i).last() {
        neighbours.remove(j as usize, node);
        neighbours.remove(i, j);
        changed.push(j);
    }
    changed.push(node);
}

/// The wall vertices of a surface (rest space), with the outward unit normal of the wall
/// around each, binned for "which is nearest", and which of them hold a node. Kept by
/// [`VirtualPoints`] and refilled at each re-mesh in the same buffers.
struct WallVertices {
    /// (vertex, outward normal), in vertex order.
    sites: Vec<(u32, Vec3)>,
    /// `sites[k]`'s rest position; `grid` bins these.
    positions: Vec<Vec3>,
    grid: RestGrid,
    /// Whether `sites[k]` holds a node (kept or to be placed).
    taken: Vec<bool>,
    /// Scratch: the wall normal summed at every surface vertex.
    normal: Vec<Vec3>,
}

/// Wall sites and surface vertices [`WallVertices`] has room for before it grows.
const WALL_ROOM: usize = 4096;
const SURFACE_VERTEX_ROOM: usize = 16384;
/// Cells of the wall sites' grid it has room for: a box around the walls of 25 supports
/// a side (16384 = 25.4³).
const GRID_CELL_ROOM: usize = 16384;

impl WallVertices {
    fn with_room() -> Self {
        let mut grid = RestGrid::build(&[], 1.0);
        grid.reserve(GRID_CELL_ROOM, WALL_ROOM);
        Self {
            sites: Vec::with_capacity(WALL_ROOM),
            positions: Vec::with_capacity(WALL_ROOM),
            grid,
            taken: Vec::with_capacity(WALL_ROOM),
            normal: Vec::with_capacity(SURFACE_VERTEX_ROOM),
        }
    }

    /// The wall vertices of `surface`, in place of the last surface's.
    fn refill(&mut self, surface: &CurrentSurface) {
        let rest = surface.rest_positions();
        let normal = &mut self.normal;
        normal.clear();
        normal.resize(rest.len(), Vec3::zeros());
        for (tri, kind) in surface.mesh.triangles.iter().zip(&surface.kinds) {
            if *kind != FaceKind::Wall {
                continue;
            }
            let [a, b, c] = tri.map(|v| rest[v as usize]);
            let n = (b - a).cross(&(c - a));
            for &v in tri {
                normal[v as usize] += n;
            }
        }
        self.sites.clear();
        self.sites.extend(
            (normal.iter().enumerate())
                .filter_map(|(v, n)| Some((v as u32, n.try_normalize(1e-300)?))),
        );
        self.positions.clear();
        (self.positions).extend(self.sites.iter().map(|(v, _)| rest[*v as usize]));
        (self.grid).rebin(&self.positions, surface.support().max(1e-6));
        self.taken.clear();
        self.taken.resize(self.sites.len(), false);
    }

    /// The site nearest `x` within `radius`, if any (the lowest vertex of equals).
    fn nearest(&self, x: &Vec3, radius: f64) -> Option<usize> {
        let mut best: Option<(f64, usize)> = None;
        self.grid
            .for_each_within(&self.positions, x, radius, |k, d2| {
                let k = k as usize;
                if best.is_none_or(|(b, bk)| d2 < b || (d2 == b && k < bk)) {
                    best = Some((d2, k));
                }
            });
        best.map(|(_, k)| k)
    }

    /// Whether a site closer than `radius` to site `k` holds a node.
    fn taken_within(&self, k: usize, radius: f64) -> bool {
        let mut taken = false;
        self.grid
            .for_each_within(&self.positions, &self.positions[k], radius, |j, _| {
                taken |= self.taken[j as usize];
            });
        taken
    }
}
