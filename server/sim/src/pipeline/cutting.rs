//! The internal cut and the tool force (paper §4, physics.md §4 and §6).
//!
//! Per tick, with the blade's contact on the current surface:
//!
//! 1. The entry point is mapped to rest space through its surface triangle, the tip hangs
//!    below it along the edge.
//! 2. The force model advances (loading, rupture, cutting with ripple).
//! 3. After rupture, the immersed edge sweeps Σ in rest space; every new triangle of Σ
//!    removes the neighbour pairs it separates, and only the points whose lists changed get
//!    new MLS rows.
//! 4. The cutting-affected region (physics.md §4.4): points within `R_aff = 3h` of the edge
//!    wake up and are integrated; points away from the tool that have come to rest fall
//!    asleep and are frozen where they are, so they hold the active region like a halo.
//!    Everything else costs nothing per tick.
//! 5. Before rupture the blade dents the capsule (the point under it follows the blade);
//!    while cutting, friction drags the points along the edge.

use std::ops::Range;

use crate::cut::{Blade, SweptSurface, cut_pairs};
use crate::force::{BladeContact, CutForce, CutPhase, CuttingForceModel};
use crate::geometry::predicates::{closest_point_on_triangle, distance_sq_to_segment};
use crate::math::Vec3;
use crate::model::{Kernel, Neighbourhoods, RestGrid};
use crate::scene::{ForceSpec, ToolSpec};
use crate::solver::Solver;

use super::surface::{CurrentSurface, SurfaceContact};

/// How far outside the surface a cutting blade must be to count as out of the tissue (m),
/// at least; a tenth of the support radius on coarse models.
const EXIT_MARGIN_M: f64 = 0.001;
/// The affected region reaches this many support radii from the edge (physics.md §4.4).
const AFFECTED_SUPPORTS: f64 = 3.0;
/// A point away from the tool sleeps once slower than this (m/s) ...
const SLEEP_SPEED_M_PER_S: f64 = 1e-4;
/// ... after this many ticks out of the tool's reach.
const SLEEP_AFTER_TICKS: u64 = 100;
/// Sleep is checked every this many ticks (each check may rebuild the active set).
const SLEEP_CHECK_EVERY: u64 = 16;
/// The blade's rest-space edge is re-swept (and the region re-marked) once it has moved this
/// fraction of the lattice spacing, or after [`REMARK_AFTER_TICKS`].
const SWEEP_FRACTION_OF_SPACING: f64 = 0.125;
const REMARK_AFTER_TICKS: u64 = 32;

/// What the cutting stage did in one tick.
#[derive(Debug, Clone, PartialEq)]
pub struct CutTick {
    /// Force on the tool.
    pub force: CutForce,
    /// The edge is in the tissue.
    pub in_tissue: bool,
    /// Depth of the edge below the entry point (m).
    pub depth_m: f64,
    /// Rest-space tip and entry, when in the tissue.
    pub edge_rest: Option<[Vec3; 2]>,
    /// Triangles of Σ added this tick.
    pub new_sigma: Range<usize>,
    /// Neighbour pairs removed this tick.
    pub pairs_removed: usize,
    /// Points whose MLS rows were recomputed this tick.
    pub points_changed: usize,
    /// The blade is pulling back along its edge (friction only, no new cut).
    pub withdrawing: bool,
}

/// The point the blade presses down before the capsule ruptures.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Press {
    point: u32,
    start_tip: Vec3,
    start_position: Vec3,
}

/// State of the cutting stage; built only for scenes that cut.
pub struct CuttingStage {
    tool: ToolSpec,
    force: CuttingForceModel,
    /// Σ in rest space.
    pub sigma: SweptSurface,
    kernel: Kernel,
    spacing_m: f64,
    r_aff: f64,
    exit_margin_m: f64,
    last_sweep: Option<[Vec3; 2]>,
    last_mark: Option<([Vec3; 2], u64)>,
    last_tip: Option<Vec3>,
    last_edge: Option<[Vec3; 2]>,
    last_depth_m: f64,
    press: Option<Press>,
    direction: Vec3,
    awake: Vec<bool>,
    last_near: Vec<u64>,
    awake_list: Vec<u32>,
    active_dirty: bool,
    tick: u64,
    changed: Vec<u32>,
    changed_flag: Vec<bool>,
    candidates: Vec<u32>,
    loaded: Vec<u32>,
    load_weights: Vec<(u32, f64)>,
    /// Pairs removed since the start.
    pub pairs_removed_total: usize,
}

impl CuttingStage {
    /// A stage for `n` points with the scene's tool and force parameters.
    pub fn new(
        n: usize,
        kernel: Kernel,
        spacing_m: f64,
        tool: ToolSpec,
        force: &ForceSpec,
        ripple: bool,
    ) -> Self {
        Self {
            tool,
            force: CuttingForceModel::new(force, ripple),
            sigma: SweptSurface::default(),
            kernel,
            spacing_m,
            r_aff: AFFECTED_SUPPORTS * kernel.support_m,
            exit_margin_m: EXIT_MARGIN_M.max(0.1 * kernel.support_m),
            last_sweep: None,
            last_mark: None,
            last_tip: None,
            last_edge: None,
            last_depth_m: 0.0,
            press: None,
            direction: Vec3::zeros(),
            awake: vec![false; n],
            last_near: vec![0; n],
            awake_list: Vec::with_capacity(n),
            active_dirty: true,
            tick: 0,
            changed: Vec::with_capacity(1024),
            changed_flag: vec![false; n],
            candidates: Vec::with_capacity(4096),
            loaded: Vec::with_capacity(256),
            load_weights: Vec::with_capacity(256),
            pairs_removed_total: 0,
        }
    }

    /// Radius of the affected region (m).
    pub fn affected_radius(&self) -> f64 {
        self.r_aff
    }

    /// Advances the stage by one tick at time `now_s`. The solver's active set, topology
    /// and external loads are updated; the solver itself is stepped by the caller.
    #[allow(clippy::too_many_arguments)]
    pub fn advance(
        &mut self,
        now_s: f64,
        blade: Option<&Blade>,
        contact: &SurfaceContact,
        surface: &CurrentSurface,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        grid: &RestGrid,
    ) -> CutTick {
        self.tick += 1;
        // Hysteresis: once the capsule is open, the surface around the blade moves with it
        // (friction drags it, the released dent springs back), so a tip a hair outside
        // the surface is still in its cut. It leaves only when clearly out.
        let in_tissue = match blade {
            None => false,
            Some(_) if contact.tip_inside => true,
            Some(b) => {
                self.force.phase() == CutPhase::Cutting && surface.near(&b.tip, self.exit_margin_m)
            }
        };
        let mut advance = 0.0;
        if let Some(b) = blade {
            if let Some(last) = self.last_tip {
                let d = b.tip - last;
                advance = d.norm();
                if let Some(dir) = d.try_normalize(1e-9) {
                    self.direction = dir;
                }
            }
            self.last_tip = Some(b.tip);
        } else {
            self.last_tip = None;
        }
        // The edge in rest space. The entry maps exactly through its surface triangle; the
        // tip hangs below it along the current edge (the tissue around a cut is only dragged
        // by friction, so the rigid offset is accurate to that drag, and it does not jump
        // when the nearest points change sides of the cut).
        let mut depth_m = 0.0;
        let mut edge_rest = None;
        if let (true, Some(b)) = (in_tissue, blade) {
            match (contact.entry, contact.entry_triangle) {
                (Some(entry), Some((t, bary))) if contact.tip_inside => {
                    let entry_rest = surface.rest_point(t, bary);
                    depth_m = (b.tip - entry).norm();
                    edge_rest = Some([entry_rest + (b.tip - entry), entry_rest]);
                }
                // Just outside, in the cut's hysteresis band: no depth, same edge.
                _ if !contact.tip_inside => edge_rest = self.last_edge,
                // Buried blade (no crossing along the edge): hold the last edge.
                _ => {
                    if let Some(last) = self.last_edge {
                        edge_rest = Some(last);
                        depth_m = self.last_depth_m;
                    }
                }
            }
        }
        self.last_edge = edge_rest;
        self.last_depth_m = depth_m;
        let in_existing_cut = match (self.force.phase(), edge_rest) {
            (CutPhase::Free, Some([tip, entry])) => {
                self.near_sigma(&entry) || self.near_sigma(&tip)
            }
            _ => false,
        };
        // Moving mostly toward its own back, the blade slides out of its cut.
        let withdrawing = blade.is_some_and(|b| self.direction.dot(&b.edge) > 0.7);
        let force = self.force.update(
            now_s,
            &BladeContact {
                in_tissue,
                depth_m,
                advance_m: advance,
                direction: self.direction,
                in_existing_cut,
                withdrawing,
            },
        );

        // Σ grows while cutting.
        let sigma_before = self.sigma.triangles.len();
        match (force.phase, edge_rest) {
            // Pulling out opens nothing new; the sweep resumes from where it stopped.
            (CutPhase::Cutting, Some(_)) if withdrawing => {}
            (CutPhase::Cutting, Some([tip, entry])) => {
                // Σ reaches a quarter spacing above the surface, so that no pair or surface
                // vertex near the top sees across it through rounding.
                let up = (entry - tip).try_normalize(1e-12).unwrap_or_else(Vec3::z);
                let edge = [tip, entry + up * (0.25 * self.spacing_m)];
                match self.last_sweep {
                    None => self.last_sweep = Some(edge),
                    Some(last) => {
                        if self.moved_enough(&last, &edge) {
                            self.sigma.add_sweep(last[0], last[1], edge[0], edge[1]);
                            self.last_sweep = Some(edge);
                        }
                    }
                }
            }
            _ => self.last_sweep = None,
        }
        let new_sigma = sigma_before..self.sigma.triangles.len();
        let mut pairs_removed = 0;
        self.changed.clear();
        for t in new_sigma.clone() {
            pairs_removed += cut_pairs(
                &self.sigma.triangles[t],
                solver.rest(),
                grid,
                neighbours,
                self.kernel.support_m,
                &mut self.changed,
                &mut self.candidates,
            );
        }
        // Unique changed points, all of them awake.
        let mut write = 0;
        for r in 0..self.changed.len() {
            let i = self.changed[r];
            if !std::mem::replace(&mut self.changed_flag[i as usize], true) {
                self.changed[write] = i;
                write += 1;
            }
        }
        self.changed.truncate(write);
        for r in 0..self.changed.len() {
            let i = self.changed[r];
            self.changed_flag[i as usize] = false;
            self.wake(i);
        }
        if !self.changed.is_empty() {
            solver.topology_changed(&self.changed, neighbours);
        }
        self.pairs_removed_total += pairs_removed;

        if let Some(edge) = edge_rest {
            let due = match self.last_mark {
                None => true,
                Some((last, at)) => {
                    self.moved_enough(&last, &edge) || self.tick - at >= REMARK_AFTER_TICKS
                }
            };
            if due {
                self.mark_affected(&edge, solver.rest(), grid);
                self.last_mark = Some((edge, self.tick));
            }
        } else {
            self.last_mark = None;
        }
        if self.tick.is_multiple_of(SLEEP_CHECK_EVERY) {
            self.put_to_sleep(solver.velocities());
        }
        if self.active_dirty {
            solver.set_active(&self.awake_list);
            self.active_dirty = false;
        }
        self.press_tissue(&force, blade, edge_rest, solver, grid);
        let friction = self.force.friction(depth_m);
        self.drag_tissue(&force, edge_rest, solver, grid, friction);
        CutTick {
            force,
            in_tissue,
            depth_m,
            edge_rest,
            new_sigma,
            pairs_removed,
            points_changed: self.changed.len(),
            withdrawing,
        }
    }

    fn moved_enough(&self, last: &[Vec3; 2], edge: &[Vec3; 2]) -> bool {
        let step = SWEEP_FRACTION_OF_SPACING * self.spacing_m;
        (edge[0] - last[0]).norm() >= step || (edge[1] - last[1]).norm() >= step
    }

    /// Whether `x` (rest) lies on Σ, within the blade's thickness and a quarter spacing.
    fn near_sigma(&self, x: &Vec3) -> bool {
        let tol = self.tool.blade_thickness_m + 0.25 * self.spacing_m;
        self.sigma.triangles.iter().any(|tri| {
            let lo = tri[0].inf(&tri[1]).inf(&tri[2]);
            let hi = tri[0].sup(&tri[1]).sup(&tri[2]);
            (0..3).all(|a| x[a] >= lo[a] - tol && x[a] <= hi[a] + tol)
                && (closest_point_on_triangle(x, tri) - x).norm() <= tol
        })
    }

    fn wake(&mut self, i: u32) {
        self.last_near[i as usize] = self.tick;
        if !std::mem::replace(&mut self.awake[i as usize], true) {
            self.awake_list.push(i);
            self.active_dirty = true;
        }
    }

    /// Wakes every point within R_aff of the rest edge.
    fn mark_affected(&mut self, edge: &[Vec3; 2], rest: &[Vec3], grid: &RestGrid) {
        let centre = (edge[0] + edge[1]) * 0.5;
        let reach = (edge[0] - edge[1]).norm() * 0.5 + self.r_aff;
        let r2 = self.r_aff * self.r_aff;
        self.candidates.clear();
        let candidates = &mut self.candidates;
        grid.for_each_within(rest, &centre, reach, |i, _| {
            if distance_sq_to_segment(&rest[i as usize], &edge[0], &edge[1]) < r2 {
                candidates.push(i);
            }
        });
        for r in 0..self.candidates.len() {
            let i = self.candidates[r];
            self.wake(i);
        }
    }

    /// Points out of the tool's reach that have come to rest stop being integrated.
    fn put_to_sleep(&mut self, v: &[Vec3]) {
        let v2 = SLEEP_SPEED_M_PER_S * SLEEP_SPEED_M_PER_S;
        let before = self.awake_list.len();
        let (tick, awake, last_near) = (self.tick, &mut self.awake, &self.last_near);
        self.awake_list.retain(|&i| {
            let i = i as usize;
            let asleep = tick - last_near[i] > SLEEP_AFTER_TICKS && v[i].norm_squared() < v2;
            if asleep {
                awake[i] = false;
            }
            !asleep
        });
        if self.awake_list.len() != before {
            self.active_dirty = true;
        }
    }

    /// Before rupture the blade dents the capsule: the point under the tip moves with the
    /// blade (displacement control; the device force comes from the measured loading curve,
    /// which a linear-elastic organ this soft could not reproduce). The dent is released at
    /// rupture or when the blade leaves.
    fn press_tissue(
        &mut self,
        force: &CutForce,
        blade: Option<&Blade>,
        edge: Option<[Vec3; 2]>,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let pressing = force.phase == CutPhase::Loading;
        match (pressing, self.press, blade, edge) {
            (true, None, Some(b), Some(edge)) => {
                let rest = solver.rest();
                let mut best: Option<(f64, u32)> = None;
                grid.for_each_within(rest, &edge[0], 2.0 * self.kernel.support_m, |k, d2| {
                    if best.is_none_or(|(d, _)| d2 < d) {
                        best = Some((d2, k));
                    }
                });
                if let Some((_, k)) = best {
                    self.wake(k);
                    solver.fix(k as usize, [true; 3]);
                    self.press = Some(Press {
                        point: k,
                        start_tip: b.tip,
                        start_position: solver.positions()[k as usize],
                    });
                }
            }
            (true, Some(press), Some(b), _) => {
                self.last_near[press.point as usize] = self.tick;
                solver.set_target(
                    press.point as usize,
                    press.start_position + (b.tip - press.start_tip),
                );
            }
            (false, Some(press), _, _) => {
                solver.fix(press.point as usize, [false; 3]);
                self.press = None;
            }
            _ => {}
        }
    }

    /// While cutting, friction drags the cut faces along with the blade: the awake points
    /// along the edge carry it, with kernel weights of their distance to the edge. (The
    /// fracture part J_c·d of the resistance is spent opening the crack at the edge, not
    /// on the bulk.)
    fn drag_tissue(
        &mut self,
        force: &CutForce,
        edge: Option<[Vec3; 2]>,
        solver: &mut Solver,
        grid: &RestGrid,
        friction_n: f64,
    ) {
        for &i in &self.loaded {
            solver.set_external_force(i as usize, Vec3::zeros());
        }
        self.loaded.clear();
        let Some(edge) = edge else { return };
        if force.phase != CutPhase::Cutting || friction_n <= 0.0 {
            return;
        }
        let rest = solver.rest();
        let h = self.kernel.support_m;
        let centre = (edge[0] + edge[1]) * 0.5;
        let reach = (edge[0] - edge[1]).norm() * 0.5 + h;
        self.load_weights.clear();
        let (weights, awake, kernel) = (&mut self.load_weights, &self.awake, &self.kernel);
        grid.for_each_within(rest, &centre, reach, |i, _| {
            if awake[i as usize] {
                let w = kernel.weight_sq(distance_sq_to_segment(
                    &rest[i as usize],
                    &edge[0],
                    &edge[1],
                ));
                if w > 0.0 {
                    weights.push((i, w));
                }
            }
        });
        let total: f64 = self.load_weights.iter().map(|(_, w)| w).sum();
        if total <= 0.0 {
            return;
        }
        let drag = self.direction * friction_n;
        for &(i, w) in &self.load_weights {
            solver.set_external_force(i as usize, drag * (w / total));
            self.loaded.push(i);
        }
    }

    /// Unit direction of the blade's latest motion (zero before it has moved).
    pub fn direction(&self) -> Vec3 {
        self.direction
    }

    /// Points integrated now.
    pub fn awake_points(&self) -> &[u32] {
        &self.awake_list
    }
}
