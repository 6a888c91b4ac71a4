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
//! the surface; the nodes are then released and placed again on the new walls (a topology
//! change, off the per-tick path). Between re-meshes a tick releases the nodes the blade
//! comes within R_aff of.

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

/// Figures of the virtual points, for reports and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct VirtualPointStats {
    /// Nodes on the walls now.
    pub placed: usize,
    /// Neighbour pairs between them and interior points.
    pub pairs: usize,
    /// Wall sites left without a node (capacity reached, or no interior point in reach).
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

    /// Releases every node and places new ones on the walls of `surface`, but not within
    /// `clear` = (edge, radius) of the blade; the points whose neighbour lists changed are
    /// appended to `changed` (then [`Solver::topology_changed`]).
    #[allow(clippy::too_many_arguments)]
    pub fn place(
        &mut self,
        surface: &CurrentSurface,
        sigma: &SweptSurface,
        clear: Option<([Vec3; 2], f64)>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        grid: &RestGrid,
        changed: &mut Vec<u32>,
    ) {
        for n in self.nodes.drain(..) {
            release(n.node, solver, neighbours, changed);
        }
        let mut sites = wall_sites(surface, MIN_SEPARATION_SPACINGS * self.spacing_m);
        if let Some((edge, radius)) = clear {
            let rest = surface.rest_positions();
            sites.retain(|(v, _)| {
                distance_sq_to_segment(&rest[*v as usize], &edge[0], &edge[1]) >= radius * radius
            });
        }
        let h = self.support_m;
        let mut pairs = 0;
        let mut not_placed = 0;
        let mut candidates = Vec::new();
        let mut near_sigma: Vec<&[Vec3; 3]> = Vec::new();
        for (vertex, outward) in sites {
            if self.nodes.len() == self.capacity {
                not_placed += 1;
                continue;
            }
            let node = (self.first + self.nodes.len()) as u32;
            let inset = -outward * (INSET_SPACINGS * self.spacing_m);
            let x = surface.rest_positions()[vertex as usize] + inset;
            // Only the cut triangles within h of the node can hide a point from it.
            near_sigma.clear();
            near_sigma.extend(
                (sigma.triangles.iter().zip(&sigma.boxes))
                    .filter(|(_, b)| b.expanded(h).contains(&x))
                    .map(|(t, _)| t),
            );
            candidates.clear();
            let rest = solver.rest();
            grid.for_each_within(rest, &x, h, |i, _| {
                let seen = !near_sigma
                    .iter()
                    .any(|t| segment_meets_triangle(&x, &rest[i as usize], t));
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
                not_placed += 1;
                continue;
            }
            pairs += connected;
            changed.push(node);
            self.nodes.push(Node {
                node,
                vertex,
                inset,
            });
        }
        self.stats = VirtualPointStats {
            placed: self.nodes.len(),
            pairs,
            not_placed,
            placements: self.stats.placements + 1,
        };
    }
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

/// Wall vertices at least `separation` apart (rest space, in vertex order), each with the
/// outward unit normal of the wall around it.
fn wall_sites(surface: &CurrentSurface, separation: f64) -> Vec<(u32, Vec3)> {
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
    let mut sites: Vec<(u32, Vec3)> = Vec::new();
    let min2 = separation * separation;
    for (v, n) in normal.iter().enumerate() {
        let Some(n) = n.try_normalize(1e-300) else {
            continue;
        };
        let x = rest[v];
        if sites
            .iter()
            .all(|(s, _)| (rest[*s as usize] - x).norm_squared() >= min2)
        {
            sites.push((v as u32, n));
        }
    }
    sites
}
