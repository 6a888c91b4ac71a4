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
//! rolled every tick back (docs/CUTTING.md, "Virtual points").
//!
//! They sit on the walls as the incision draws them (opened in rest space), a twentieth of
//! a spacing inside the tissue, so the field they carry is the one the wall already
//! follows: they support the fit without driving the opening.
//!
//! The incision is re-meshed every few millimetres of a stroke, and every re-mesh renumbers
//! the surface; the nodes that still stand on the new walls are kept, the others released,
//! and new ones placed where the wound grew (a topology change, off the per-tick path).
//! Between re-meshes a tick releases the nodes the blade comes within R_aff of.

use serde::Serialize;

use crate::cut::{FaceKind, SweptSurface};
use crate::geometry::predicates::{distance_sq_to_segment, segment_meets_triangle};
use crate::math::Vec3;
use crate::model::{Neighbourhoods, RestGrid};
use crate::solver::Solver;

use super::surface::CurrentSurface;

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
    /// Figures so far.
    pub stats: VirtualPointStats,
}

impl VirtualPoints {
    /// Nodes `first..first + capacity` of the solver, for a lattice of `spacing_m` and
    /// support `support_m`.
    pub fn new(first: usize, capacity: usize, spacing_m: f64, support_m: f64) -> Self {
        Self {
            first,
            capacity,
            nodes: Vec::with_capacity(capacity),
            pending: Vec::new(),
            spacing_m,
            support_m,
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

    /// Releases the nodes within `radius` of the blade's rest `edge`: the blade cuts and
    /// dents the tissue there, and the new Σ would split a node's masters on a wall the
    /// blade is re-cutting (its pairs are cut, its interpolation is not). The next
    /// placement puts nodes back once the blade has gone.
    /// Returns whether any was released; changed lists are appended to `changed`.
    pub fn release_near(
        &mut self,
        edge: &[Vec3; 2],
        radius: f64,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        changed: &mut Vec<u32>,
    ) -> bool {
        let before = self.nodes.len();
        let mut k = 0;
        while k < self.nodes.len() {
            let node = self.nodes[k].node;
            let at = solver.rest()[node as usize];
            if distance_sq_to_segment(&at, &edge[0], &edge[1]) < radius * radius {
                release(node, solver, neighbours, changed);
                self.nodes.swap_remove(k);
            } else {
                k += 1;
            }
        }
        self.stats.placed = self.nodes.len();
        self.nodes.len() != before
    }

    /// After a re-mesh: keeps the nodes that still stand on the walls of `surface`,
    /// releases the others, and chooses where new ones go: wall sites not within `clear` =
    /// (edge, radius) of the blade. At most `limit` of those are placed now, the rest by
    /// [`Self::place_pending`] in the ticks that follow. A node stays, untouched, while the
    /// new walls still have a vertex within [`KEEP_SPACINGS`] of it (and the blade does not
    /// clear that vertex); new ones go to the walls' sites left at least
    /// [`MIN_SEPARATION_SPACINGS`] from every node. The points whose neighbour lists
    /// changed are appended to `changed` (then [`Solver::topology_changed`]).
    ///
    /// Keeping nodes is what makes a re-mesh cost what the wound gained, not what it is: a
    /// re-cut moves the lips along the whole path by a few hundredths of a spacing, and
    /// placing every node again made the cerebroma's landing ticks grow with the wound
    /// (docs/CUTTING.md, "Virtual points kept across re-meshes"). A kept node's pairs are
    /// still valid: Σ grows only where the blade is, and nodes within R_aff of it are
    /// released every tick ([`Self::release_near`]).
    #[allow(clippy::too_many_arguments)]
    pub fn remeshed(
        &mut self,
        surface: &CurrentSurface,
        sigma: &SweptSurface,
        clear: Option<([Vec3; 2], f64)>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        grid: &RestGrid,
        changed: &mut Vec<u32>,
        limit: usize,
    ) {
        let rest = surface.rest_positions();
        let walls = WallVertices::of(surface);
        let separation = MIN_SEPARATION_SPACINGS * self.spacing_m;
        let mut taken = SiteGrid::new(separation);
        let mut k = 0;
        while k < self.nodes.len() {
            let n = self.nodes[k];
            let x = solver.rest()[n.node as usize];
            match walls.nearest(&x, KEEP_SPACINGS * self.spacing_m) {
                Some(v) if !cleared(clear, &rest[v as usize]) => {
                    taken.insert(rest[v as usize]);
                    self.nodes[k].vertex = v;
                    self.nodes[k].inset = x - rest[v as usize];
                    k += 1;
                }
                _ => {
                    release(n.node, solver, neighbours, changed);
                    self.nodes.swap_remove(k);
                }
            }
        }
        self.stats.kept = self.nodes.len();
        self.stats.not_placed = 0;
        self.stats.placements += 1;
        self.pending.clear();
        for &(vertex, outward) in &walls.sites {
            let at = rest[vertex as usize];
            // Sites are picked greedily in vertex order, kept nodes first; a site the blade
            // clears still holds its place (as when every node was placed anew).
            if taken.any_within(&at, separation) {
                continue;
            }
            taken.insert(at);
            if !cleared(clear, &at) {
                self.pending.push((vertex, outward));
            }
        }
        // Placed from the end of the list: keep the vertex order.
        self.pending.reverse();
        self.place_pending(
            surface, sigma, clear, solver, neighbours, grid, changed, limit,
        );
    }

    /// Whether sites chosen at the last re-mesh still wait for their nodes.
    pub fn has_pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Places up to `limit` of the nodes the last re-mesh chose sites for, skipping sites
    /// the blade (`clear`) has come near since; returns whether any was placed. Spread
    /// over ticks because each node changes the MLS rows of the dozen points it joins: the
    /// end of the cerebroma's stroke placed 80 at once, 7 ms with their rows, in one tick.
    #[allow(clippy::too_many_arguments)]
    pub fn place_pending(
        &mut self,
        surface: &CurrentSurface,
        sigma: &SweptSurface,
        clear: Option<([Vec3; 2], f64)>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        grid: &RestGrid,
        changed: &mut Vec<u32>,
        limit: usize,
    ) -> bool {
        let rest = surface.rest_positions();
        // The lowest free node indices, in order, for the new nodes.
        let mut used = vec![false; self.capacity];
        for n in &self.nodes {
            used[n.node as usize - self.first] = true;
        }
        let mut free = (0..self.capacity)
            .filter(|&slot| !used[slot])
            .map(|slot| (self.first + slot) as u32);
        let h = self.support_m;
        let mut candidates = Vec::new();
        let mut near_sigma: Vec<&[Vec3; 3]> = Vec::new();
        let mut placed_any = false;
        for _ in 0..limit {
            let Some((vertex, outward)) = self.pending.pop() else {
                break;
            };
            let at = rest[vertex as usize];
            if cleared(clear, &at) {
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
                (sigma.triangles.iter().zip(&sigma.boxes))
                    .filter(|(_, b)| b.expanded(h).contains(&x))
                    .map(|(t, _)| t),
            );
            candidates.clear();
            let rest_points = solver.rest();
            grid.for_each_within(rest_points, &x, h, |i, _| {
                let seen = !near_sigma
                    .iter()
                    .any(|t| segment_meets_triangle(&x, &rest_points[i as usize], t));
                if seen {
                    candidates.push(i);
                }
            });
            let mut connected = 0;
            for &i in &candidates {
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
            placed_any = true;
        }
        self.stats.placed = self.nodes.len();
        self.stats.pairs = (self.nodes.iter())
            .map(|n| neighbours.of(n.node as usize).len())
            .sum();
        placed_any
    }
}

/// Whether `x` lies within the blade's clearance (edge, radius), if there is one.
fn cleared(clear: Option<([Vec3; 2], f64)>, x: &Vec3) -> bool {
    clear.is_some_and(|(edge, radius)| {
        distance_sq_to_segment(x, &edge[0], &edge[1]) < radius * radius
    })
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
/// around each, binned for "which is nearest".
struct WallVertices<'a> {
    rest: &'a [Vec3],
    /// (vertex, outward normal), in vertex order.
    sites: Vec<(u32, Vec3)>,
    grid: RestGrid,
    /// `grid` bins `positions`; `sites[k]` is at `positions[k]`.
    positions: Vec<Vec3>,
}

impl<'a> WallVertices<'a> {
    fn of(surface: &'a CurrentSurface) -> Self {
        let rest = surface.rest_positions();
        let mut normal = vec![Vec3::zeros(); rest.len()];
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
        let sites: Vec<(u32, Vec3)> = (normal.iter().enumerate())
            .filter_map(|(v, n)| Some((v as u32, n.try_normalize(1e-300)?)))
            .collect();
        let positions: Vec<Vec3> = sites.iter().map(|(v, _)| rest[*v as usize]).collect();
        let cell = surface.support().max(1e-6);
        Self {
            rest,
            grid: RestGrid::build(&positions, cell),
            sites,
            positions,
        }
    }

    /// The wall vertex nearest `x` within `radius`, if any (the lowest index of equals).
    fn nearest(&self, x: &Vec3, radius: f64) -> Option<u32> {
        let mut best: Option<(f64, u32)> = None;
        self.grid
            .for_each_within(&self.positions, x, radius, |k, d2| {
                let v = self.sites[k as usize].0;
                if best.is_none_or(|(b, bv)| d2 < b || (d2 == b && v < bv)) {
                    best = Some((d2, v));
                }
            });
        debug_assert!(best.is_none_or(|(_, v)| (self.rest[v as usize] - x).norm() <= radius));
        best.map(|(_, v)| v)
    }
}

/// Sites taken so far, hashed by cells of the separation, for "is one within it".
struct SiteGrid {
    cell_m: f64,
    cells: std::collections::HashMap<[i64; 3], Vec<Vec3>>,
}

impl SiteGrid {
    fn new(cell_m: f64) -> Self {
        Self {
            cell_m: cell_m.max(1e-9),
            cells: std::collections::HashMap::new(),
        }
    }

    fn cell(&self, x: &Vec3) -> [i64; 3] {
        [0, 1, 2].map(|a| (x[a] / self.cell_m).floor() as i64)
    }

    fn insert(&mut self, x: Vec3) {
        let c = self.cell(&x);
        self.cells.entry(c).or_default().push(x);
    }

    /// Whether a site lies closer than `radius` (at most the cell size) to `x`.
    fn any_within(&self, x: &Vec3, radius: f64) -> bool {
        let c = self.cell(x);
        let r2 = radius * radius;
        (-1..=1).any(|dz| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    self.cells
                        .get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                        .is_some_and(|sites| sites.iter().any(|s| (s - x).norm_squared() < r2))
                })
            })
        })
    }
}
