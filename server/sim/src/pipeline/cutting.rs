//! The internal cut and the tool force (paper §4, physics.md §4 and §6).
//!
//! Per tick, with the blade's contact on the current surface:
//!
//! 1. The entry point is mapped to rest space through the displacement field of the points
//!    around it, the tip hangs below it along the edge.
//! 2. The force model advances (loading, rupture, cutting with ripple).
//! 3. After rupture, the immersed edge sweeps Σ in rest space; every new triangle of Σ
//!    removes the neighbour pairs it separates, and only the points whose lists changed get
//!    new MLS rows.
//! 4. The cutting-affected region (physics.md §4.4): points within `R_aff = 3h` of the edge
//!    wake up and are integrated; points away from the tool that have come to rest fall
//!    asleep and are frozen where they are, so they hold the active region like a halo.
//!    Everything else costs nothing per tick.
//! 5. Before rupture the blade dents the capsule (a patch under it follows the blade, and
//!    relaxes after rupture);
//!    while cutting, the friction is felt at the tool only. (Dragging the tissue with it was
//!    tried: a force spread over the few cells along the edge shears them inside out on
//!    fine lattices of soft organs, and the surface sinks with the blade.)

use std::ops::Range;

use crate::cut::{Blade, SweptSurface, visit_crossing_pairs};
use crate::force::{BladeContact, CutForce, CutPhase, CuttingForceModel};
use crate::geometry::predicates::{closest_point_on_triangle, distance_sq_to_segment};
use crate::math::{Aabb, Vec3};
use crate::model::{Kernel, Neighbourhoods, RestGrid};
use crate::scene::{ForceSpec, ToolSpec};
use crate::solver::Solver;

use super::steady_motion::SteadyMotion;
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
/// The blade's direction of motion is averaged over about this much travel (m).
const DIRECTION_TRAVEL_M: f64 = 0.0005;
/// Samples along the edge for the share of it that is in uncut tissue.
const FRESH_SAMPLES: usize = 16;
/// Σ triangles near the edge considered at most per tick (scratch capacity); past it, all.
const MAX_PROBE_CANDIDATES: usize = 4096;
/// The depth reading changes at most this fast (m/s) beyond the blade's own motion along
/// its edge: the dent relaxes at about 30 mm/s, the tissue around a cut moves slower.
const DEPTH_SLEW_M_PER_S: f64 = 0.05;
/// Fixed-point iterations mapping a current position to rest space.
const REST_MAP_ITERATIONS: usize = 3;

/// The level-set classification of the points (physics.md §4.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Classification {
    /// Points in the cutting-affected region now (integrated).
    pub affected: usize,
    /// Points not integrated (never reached, or asleep).
    pub unaffected: usize,
    /// Points classified left of the blade plane (φ > 0).
    pub left: usize,
    /// Points classified right of it (φ < 0).
    pub right: usize,
}

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
    /// The blade opens no new cut (friction only): it is pulling back along its edge, or
    /// moving back along the cut it made.
    pub withdrawing: bool,
    /// Pushed in point first, the slit its flat opened at the surface (rest space, from the
    /// edge's entry to the blade's back), when Σ grew by it this tick.
    pub slit_rest: Option<Vec3>,
}

/// The dent is a smooth patch this many rupture displacements wide (at least one support
/// radius): a one-point dent deeper than the lattice spacing would invert the cells around
/// it on fine models, while the physical dent spreads over the blade's contact.
const DENT_RADIUS_PER_RUPTURE_DISPLACEMENT: f64 = 2.0;

/// After rupture the dent relaxes over this time (s) as the crack opens under the blade,
/// rather than springing back at once: a sudden release of a soft organ's stored dent
/// throws the points around the fresh crack inside out.
const DENT_RELEASE_S: f64 = 0.1;
/// Most points in the dent patch (preallocated: the tick does not allocate). A patch of
/// radius 2h holds about 270 lattice points, half of them inside a flat surface.
const MAX_DENT_POINTS: usize = 256;

/// Most pairs in the transparency zone at once (preallocated); beyond it a crossing pair is
/// cut at once, as with hard visibility. A front 20 mm long on a 1 mm lattice has about 2000.
const MAX_TRANSPARENT_PAIRS: usize = 8192;

/// A neighbour pair whose rest segment crosses Σ near the crack front (physics.md §4.3).
#[derive(Debug, Clone, Copy, PartialEq)]
struct TransparentPair {
    i: u32,
    j: u32,
    /// Where the segment crosses Σ (rest).
    crossing: Vec3,
    /// The distance added in the kernel now (m).
    extra_m: f64,
}

/// A point the blade presses down before the capsule ruptures: it follows the tip by
/// `weight` of the tip's travel since the press began.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pressed {
    point: u32,
    start_position: Vec3,
    weight: f64,
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
    /// The entry of the last tick with the edge through the surface (current, rest), and
    /// where the edge came out again if it went right through.
    last_entry: Option<(Vec3, Vec3, Option<Vec3>)>,
    last_now_s: Option<f64>,
    /// Tip position when the dent began, and the dented points.
    press_start: Option<Vec3>,
    /// The tip's travel since the press began, and when the release began.
    press_travel: Vec3,
    release_start_s: Option<f64>,
    pressed: Vec<Pressed>,
    dent_radius_m: f64,
    /// Rest centre and radius of the dent patch being held.
    dent_patch: (Vec3, f64),
    /// The tip as far as cutting is concerned: a device's noise and a tremor held still
    /// move it not at all.
    steady: SteadyMotion,
    /// Where it was when Σ last grew.
    last_sweep_at: Option<Vec3>,
    /// The blade's recent steady displacements, each weighed down by the travel since (m):
    /// its direction is `direction`.
    recent_motion: Vec3,
    direction: Vec3,
    awake: Vec<bool>,
    /// Side of each point relative to the blade plane (+1 left, −1 right, 0 unknown).
    side: Vec<i8>,
    last_near: Vec<u64>,
    awake_list: Vec<u32>,
    active_dirty: bool,
    tick: u64,
    changed: Vec<u32>,
    changed_flag: Vec<bool>,
    candidates: Vec<u32>,
    /// Σ triangles near the edge, for the share of it in uncut tissue.
    probe_candidates: Vec<u32>,
    /// κ of the crack-front transparency (0: hard visibility).
    transparency: f64,
    /// Pairs across Σ near the current front, fading out.
    transparent: Vec<TransparentPair>,
    /// Pairs of body points removed since the start (virtual points' pairs not counted).
    pub pairs_removed_total: usize,
    material_points: usize,
}

/// What the blade's edge is read from.
struct Reading<'a> {
    blade: Option<&'a Blade>,
    contact: &'a SurfaceContact,
    surface: &'a CurrentSurface,
    solver: &'a Solver,
    grid: &'a RestGrid,
}

/// What a tick's sweep added to Σ.
struct Sweep {
    new_sigma: Range<usize>,
    slit_rest: Option<Vec3>,
    plunge_normal: Option<Vec3>,
}

impl CuttingStage {
    /// A stage for `n` points (the body's `material_points` first, then any virtual
    /// nodes) with the scene's tool and force parameters.
    pub fn new(
        n: usize,
        material_points: usize,
        kernel: Kernel,
        spacing_m: f64,
        tool: ToolSpec,
        force: &ForceSpec,
        ripple: bool,
    ) -> Self {
        Self {
            tool,
            force: CuttingForceModel::new(force, ripple),
            sigma: SweptSurface::with_room(),
            kernel,
            spacing_m,
            r_aff: AFFECTED_SUPPORTS * kernel.support_m,
            exit_margin_m: EXIT_MARGIN_M.max(0.1 * kernel.support_m),
            last_sweep: None,
            last_mark: None,
            last_tip: None,
            last_edge: None,
            last_depth_m: 0.0,
            last_entry: None,
            last_now_s: None,
            press_start: None,
            press_travel: Vec3::zeros(),
            release_start_s: None,
            pressed: Vec::with_capacity(MAX_DENT_POINTS),
            dent_patch: (Vec3::zeros(), 0.0),
            dent_radius_m: (DENT_RADIUS_PER_RUPTURE_DISPLACEMENT * force.rupture_displacement_m)
                .max(kernel.support_m),
            steady: SteadyMotion::new(force.motion_deadband_m),
            last_sweep_at: None,
            recent_motion: Vec3::zeros(),
            direction: Vec3::zeros(),
            awake: vec![false; n],
            side: vec![0; n],
            last_near: vec![0; n],
            awake_list: Vec::with_capacity(n),
            active_dirty: true,
            tick: 0,
            changed: Vec::with_capacity(1024),
            changed_flag: vec![false; n],
            candidates: Vec::with_capacity(4096),
            probe_candidates: Vec::with_capacity(MAX_PROBE_CANDIDATES),
            transparency: force.crack_transparency,
            transparent: Vec::with_capacity(MAX_TRANSPARENT_PAIRS),
            pairs_removed_total: 0,
            material_points,
        }
    }

    /// Scales the tissue's stiffness in the force model (1: the scene's).
    pub fn set_stiffness_factor(&mut self, factor: f64) {
        self.force.set_stiffness_factor(factor);
    }

    /// Radius of the cutting-affected region around the blade (m).
    pub fn affected_radius(&self) -> f64 {
        self.r_aff
    }

    /// Advances the stage by one tick at time `now_s`. The solver's active set, topology
    /// and external loads are updated; the solver itself is stepped by the caller. In order:
    /// is the blade in the tissue, how it moved, its edge in rest space, the force, Σ grown
    /// by its sweep, the pairs Σ cuts, the affected region, the tissue pressed.
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
        let phase_before = self.force.phase();
        let in_tissue = self.in_tissue(blade, contact, surface, phase_before);
        let last_tip = self.last_tip;
        let dt = self.last_now_s.map_or(0.0, |t| (now_s - t).max(0.0));
        self.last_now_s = Some(now_s);
        let (motion, steady) = self.follow_motion(blade, dt);
        let reading = Reading {
            blade,
            contact,
            surface,
            solver,
            grid,
        };
        let (depth_m, edge_rest) =
            self.edge_in_rest(&reading, in_tissue, phase_before, last_tip, dt);
        let in_existing_cut = match (self.force.phase(), edge_rest) {
            (CutPhase::Free, Some([tip, entry])) => {
                self.near_sigma(&entry) || self.near_sigma(&tip)
            }
            _ => false,
        };
        // The fracture term is the work of opening new crack: J_c × the new crack's width
        // per unit of motion. Moving back along its cut the blade opens nothing (friction
        // only); a second, deeper pass along a cut opens only what lies below the first; a
        // raked blade opens its vertical depth. Moving mostly toward its own back, it slides
        // out of its cut.
        let crack = match (phase_before, edge_rest) {
            (CutPhase::Cutting, Some([tip, entry])) => self.crack_share(tip, entry),
            _ => 1.0,
        };
        let retracing = phase_before == CutPhase::Cutting && crack == 0.0;
        let withdrawing = retracing || blade.is_some_and(|b| self.direction.dot(&b.edge) > 0.7);
        // The force acts against the averaged motion; shortened while it turns round, so
        // that on a reversal the resistance passes through zero over about half a
        // millimetre instead of flipping by twice its size in one tick (a 90° corner keeps
        // at least 0.71 of the length: no dip).
        let heading = self.recent_motion / (0.5 * DIRECTION_TRAVEL_M);
        let heading = heading / heading.norm().max(1.0);
        let force = self.force.update(
            now_s,
            &BladeContact {
                in_tissue,
                depth_m,
                motion_m: motion,
                steady_motion_m: steady,
                direction: heading,
                in_existing_cut,
                withdrawing,
                crack_share: crack,
            },
        );
        let sweep = self.grow_sigma(&force, edge_rest, blade, retracing, withdrawing);
        let pairs_removed = self.cut_pairs(sweep.new_sigma.clone(), solver, neighbours, grid);
        self.update_region(edge_rest, sweep.plunge_normal, solver, grid);
        self.press_tissue(now_s, &force, blade, edge_rest, solver, grid);
        CutTick {
            force,
            in_tissue,
            depth_m,
            edge_rest,
            new_sigma: sweep.new_sigma,
            pairs_removed,
            points_changed: self.changed.len(),
            withdrawing,
            slit_rest: sweep.slit_rest,
        }
    }

    /// Whether the blade is in the tissue. Hysteresis: once in contact, the surface around
    /// the blade moves with it (the dent follows the tip, then relaxes and the lips part),
    /// so a tip a hair outside the surface is still pressing or in its cut, and a tip in its
    /// own open wound (between the walls) is still cutting. It leaves only when clearly out.
    fn in_tissue(
        &self,
        blade: Option<&Blade>,
        contact: &SurfaceContact,
        surface: &CurrentSurface,
        phase_before: CutPhase,
    ) -> bool {
        match (blade, phase_before) {
            (None, _) => false,
            (Some(_), _) if contact.immersed() => true,
            (Some(_), CutPhase::Free) => false,
            (Some(b), CutPhase::Loading) => surface.near(&b.tip, self.exit_margin_m, false),
            (Some(b), CutPhase::Cutting) => {
                surface.near(&b.tip, self.exit_margin_m, true) || self.in_own_wound(b)
            }
        }
    }

    /// The blade's motion this tick and its steady part (the device's noise filtered out),
    /// and the direction of the averaged motion (`self.direction`).
    fn follow_motion(&mut self, blade: Option<&Blade>, dt: f64) -> (Vec3, Vec3) {
        let mut motion = Vec3::zeros();
        let mut steady = Vec3::zeros();
        if let Some(b) = blade {
            if let Some(last) = self.last_tip {
                motion = b.tip - last;
            }
            // A real device's position is never still, and read tick by tick its noise is
            // millimetres of travel a second in every direction: the resistance would turn
            // round every tick and the crack advance while the blade is held.
            steady = self.steady.update(b.tip, dt);
            // Averaged over the last DIRECTION_TRAVEL_M of travel: the force turns with
            // the path, not in one tick at a corner of it. Summing displacements (not
            // blending unit vectors, which never turn when the blade reverses exactly)
            // makes it flip after about 0.7 × that travel back.
            let decay = DIRECTION_TRAVEL_M / (DIRECTION_TRAVEL_M + steady.norm());
            self.recent_motion = self.recent_motion * decay + steady;
            if let Some(dir) = self.recent_motion.try_normalize(1e-12) {
                self.direction = dir;
            }
            self.last_tip = Some(b.tip);
        } else {
            // A tool that comes back starts with no motion history.
            self.last_tip = None;
            self.steady.reset();
            self.recent_motion = Vec3::zeros();
            self.direction = Vec3::zeros();
        }
        (motion, steady)
    }

    /// The blade's depth and its edge in rest space (tip, entry), read off the surface it
    /// crossed, held or slewed where that reading is an artefact. The entry maps through the
    /// displacement field; the tip hangs below it along the current edge (the tissue around
    /// a cut is not dragged by the blade, so the rigid offset is accurate, and it does not
    /// jump when the nearest points change sides of the cut).
    fn edge_in_rest(
        &mut self,
        r: &Reading,
        in_tissue: bool,
        phase_before: CutPhase,
        last_tip: Option<Vec3>,
        dt: f64,
    ) -> (f64, Option<[Vec3; 2]>) {
        let (blade, contact) = (r.blade, r.contact);
        let mut depth_m = 0.0;
        let mut edge_rest = None;
        if let (true, Some(b)) = (in_tissue, blade) {
            match (contact.entry, contact.entry_triangle) {
                (Some(entry), Some((t, bary))) if contact.immersed() => {
                    // Through the smooth displacement field of the points around it: the
                    // crossed triangle's own rest map jumps with every sliver of the
                    // deformed surface the edge happens to pierce.
                    let guess = r.surface.rest_point(t, bary);
                    let entry_rest = self.rest_of(&entry, &guess, r.solver, r.grid);
                    // A blade right through a thin part is in it up to where it comes out.
                    let inner = contact.exit.unwrap_or(b.tip);
                    depth_m = (inner - entry).norm();
                    edge_rest = Some([entry_rest + (inner - entry), entry_rest]);
                    self.last_entry = Some((entry, entry_rest, contact.exit));
                }
                // Just outside, in the cut's hysteresis band: the tip is in the open wound
                // (the lips have parted around the blade). The depth is still measured from
                // the last entry, so it neither drops to zero while the blade goes on down
                // the wound nor jumps back when the tip touches its floor; lifted above
                // the entry it is zero.
                _ if !contact.tip_inside => match self.last_entry {
                    // Pressing, the dent follows the tip: it is at the surface.
                    _ if phase_before == CutPhase::Loading => edge_rest = self.last_edge,
                    Some((entry, entry_rest, exit)) => {
                        let up = b.edge;
                        // Through a thin part, no deeper than where the edge came out.
                        let floor = exit.map_or(f64::INFINITY, |x| (entry - x).dot(&up));
                        depth_m = (entry - b.tip).dot(&up).clamp(0.0, floor.max(0.0));
                        edge_rest = Some([entry_rest - up * depth_m, entry_rest]);
                    }
                    None => edge_rest = self.last_edge,
                },
                // Buried blade (no crossing along the edge): hold the last edge.
                _ => {
                    if let Some(last) = self.last_edge {
                        edge_rest = Some(last);
                        depth_m = self.last_depth_m;
                    }
                }
            }
        }
        if !in_tissue {
            self.last_entry = None;
        }
        if in_tissue
            && phase_before == CutPhase::Cutting
            && let Some((b, last_tip)) = blade.zip(last_tip)
        {
            // The depth is read off a discrete, deforming surface: as the dent relaxes, the
            // lips part and lids appear, the crossing can hop from one sheet to another.
            // A true change comes from the blade moving along its edge, or the tissue
            // moving, at tissue speeds; anything faster is an artefact of the reading, and
            // would be felt as a kick.
            let along = (b.tip - last_tip).dot(&b.edge).abs();
            let limit = along + DEPTH_SLEW_M_PER_S * dt;
            depth_m = self.last_depth_m + (depth_m - self.last_depth_m).clamp(-limit, limit);
        }
        self.last_edge = edge_rest;
        self.last_depth_m = depth_m;
        (depth_m, edge_rest)
    }

    /// Σ grown by the blade's sweep while it cuts: the new triangles, the slit its flat
    /// opened going in point first, and that flat's normal.
    fn grow_sigma(
        &mut self,
        force: &CutForce,
        edge_rest: Option<[Vec3; 2]>,
        blade: Option<&Blade>,
        retracing: bool,
        withdrawing: bool,
    ) -> Sweep {
        let sigma_before = self.sigma.triangles.len();
        let mut slit_rest = None;
        // While the blade goes in point first, the normal of its flat: the plane that parts
        // left from right when the motion, along the edge, defines none.
        let mut plunge_normal = None;
        match (force.phase, edge_rest) {
            (CutPhase::Cutting, Some([tip, entry])) => {
                // Σ reaches a quarter spacing above the surface, so that no pair or surface
                // vertex near the top sees across it through rounding.
                let up = (entry - tip).try_normalize(1e-12).unwrap_or_else(Vec3::z);
                let edge = [tip, entry + up * (0.25 * self.spacing_m)];
                // Going in point first (within 60° of it), the edge sweeps nothing; the
                // blade's flat slits the tissue behind it.
                let flat = blade
                    .filter(|_| self.direction.dot(&up) < -0.5)
                    .and_then(|b| {
                        (b.toward_back - up * b.toward_back.dot(&up)).try_normalize(1e-6)
                    });
                // Left is on the left of a blade cutting edge first (toward −back).
                plunge_normal = flat.map(|back| back.cross(&up));
                let at = self.steady.position();
                match self.last_sweep {
                    // Moving back along its cut the blade is on Σ: the sweep goes on from
                    // here when it cuts again (from where it was, one straight quad would
                    // cut the chord of a curved cut).
                    _ if retracing => (self.last_sweep, self.last_sweep_at) = (Some(edge), at),
                    // Pulling out opens nothing new; the sweep resumes from where it
                    // stopped.
                    _ if withdrawing => {}
                    None => (self.last_sweep, self.last_sweep_at) = (Some(edge), at),
                    // The edge jitters with the device's noise, and would sweep Σ to and
                    // fro around a held blade: the blade must also have moved steadily.
                    Some(last) => {
                        if self.moved_enough(&last, &edge)
                            && self.moved_steadily_since(self.last_sweep_at)
                        {
                            self.sigma.add_sweep(last[0], last[1], edge[0], edge[1]);
                            if let Some(back) = flat {
                                let width = self.tool.blade_width_m;
                                self.sigma.add_blade_flat(edge[0], edge[1], back, width);
                                slit_rest = Some(back * (entry - tip).norm().min(width));
                            }
                            (self.last_sweep, self.last_sweep_at) = (Some(edge), at);
                        }
                    }
                }
            }
            _ => (self.last_sweep, self.last_sweep_at) = (None, None),
        }
        Sweep {
            new_sigma: sigma_before..self.sigma.triangles.len(),
            slit_rest,
            plunge_normal,
        }
    }

    /// The pairs the new Σ triangles cross cut (or, near the front, faded out), and the
    /// points whose rows changed refitted and woken (`apply_topology`). Returns the pairs
    /// removed.
    fn cut_pairs(
        &mut self,
        new_sigma: Range<usize>,
        solver: &mut Solver,
        neighbours: &mut Neighbourhoods,
        grid: &RestGrid,
    ) -> usize {
        let mut pairs_removed = 0;
        self.changed.clear();
        let fade_m = 0.5 * self.transparency * self.kernel.support_m;
        let material = self.material_points as u32;
        let mut body_pairs_removed = 0;
        let front = self.last_sweep;
        for t in new_sigma.clone() {
            let (transparent, changed) = (&mut self.transparent, &mut self.changed);
            visit_crossing_pairs(
                &self.sigma.triangles[t],
                solver.rest(),
                grid,
                neighbours,
                self.kernel.support_m,
                &mut self.candidates,
                |neighbours, i, j, crossing| {
                    // Near the front a body pair fades out as the blade moves on (below);
                    // a virtual point's pair is cut at once (the node is released anyway),
                    // and so is one crossing as far behind the edge as a pair is faded out
                    // (the back of a stab's slit, up to a blade width behind it).
                    let body = i < material && j < material;
                    let behind = front.is_some_and(|[a, b]| {
                        distance_sq_to_segment(&crossing, &a, &b) >= fade_m * fade_m
                    });
                    if body && fade_m > 0.0 && !behind && transparent.len() < MAX_TRANSPARENT_PAIRS
                    {
                        if !transparent.iter().any(|p| p.i == i && p.j == j) {
                            transparent.push(TransparentPair {
                                i,
                                j,
                                crossing,
                                extra_m: 0.0,
                            });
                        }
                        return false;
                    }
                    neighbours.remove(i as usize, j);
                    neighbours.remove(j as usize, i);
                    changed.extend([i, j]);
                    pairs_removed += 1;
                    body_pairs_removed += usize::from(body);
                    true
                },
            );
        }
        // The front moved: fade the pairs within its reach. Pairs left by an earlier
        // stroke, out of reach, keep the weight they have (a finished incision's crack tip
        // stays partly connected) until a front comes by again.
        if let (Some(front), false) = (self.last_sweep, new_sigma.is_empty()) {
            let faded = self.fade_transparent_pairs(&front, solver.rest(), neighbours);
            pairs_removed += faded;
            body_pairs_removed += faded;
        }
        // Unique changed points, in the order first seen, refitted and all of them awake.
        let mut write = 0;
        for r in 0..self.changed.len() {
            let i = self.changed[r];
            if !std::mem::replace(&mut self.changed_flag[i as usize], true) {
                self.changed[write] = i;
                write += 1;
            }
        }
        self.changed.truncate(write);
        for &i in &self.changed {
            self.changed_flag[i as usize] = false;
        }
        let changed = std::mem::take(&mut self.changed);
        super::apply_topology(&changed, solver, neighbours, |i| self.wake(i));
        self.changed = changed;
        self.pairs_removed_total += body_pairs_removed;
        pairs_removed
    }

    /// The affected region: the points around the blade's edge woken (again once it has
    /// moved, or a while has passed), the quiet ones put to sleep, the solver's active set
    /// updated.
    fn update_region(
        &mut self,
        edge_rest: Option<[Vec3; 2]>,
        plunge_normal: Option<Vec3>,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        if let Some(edge) = edge_rest {
            let due = match self.last_mark {
                None => true,
                Some((last, at)) => {
                    self.moved_enough(&last, &edge) || self.tick - at >= REMARK_AFTER_TICKS
                }
            };
            if due {
                self.mark_affected(&edge, plunge_normal, solver.rest(), grid);
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
    }

    /// The rest position X with X + u(X) = x, u the kernel-weighted displacement of the
    /// points around X, by fixed-point iteration from `guess`.
    fn rest_of(&self, x: &Vec3, guess: &Vec3, solver: &Solver, grid: &RestGrid) -> Vec3 {
        let (rest, p) = (solver.rest(), solver.positions());
        let h = self.kernel.support_m;
        let mut at = *guess;
        for _ in 0..REST_MAP_ITERATIONS {
            let (mut u, mut total) = (Vec3::zeros(), 0.0);
            grid.for_each_within(rest, &at, h, |i, d2| {
                let w = self.kernel.weight_sq(d2);
                u += (p[i as usize] - rest[i as usize]) * w;
                total += w;
            });
            if total <= 0.0 {
                break;
            }
            at = x - u / total;
        }
        at
    }

    /// Whether the blade's tip is down in the wound it has cut (below the last entry and
    /// under it, within the exit margin): the lips have parted around the blade there, so
    /// no surface is near the tip, yet it is in the tissue.
    fn in_own_wound(&self, b: &Blade) -> bool {
        self.last_entry.is_some_and(|(entry, ..)| {
            let d = entry - b.tip;
            let below = d.dot(&b.edge);
            // The tip below the entry, the back above it: the edge spans the surface.
            below > 0.0
                && (entry - b.back).dot(&b.edge) < 0.0
                && (d - b.edge * below).norm() <= self.exit_margin_m
        })
    }

    /// Transparency near the crack front (physics.md §4.3, Organ et al. 1996): a pair that
    /// crosses Σ at distance d_s from the front (the blade's edge) weighs as if it were
    /// h·(2d_s/κh)² farther apart, so it fades out over κh/2 of travel instead of switching
    /// off in one tick — hard visibility makes a spurious discontinuity ahead of the crack
    /// and the points there jerk as their pairs switch off one by one. Fully faded pairs are
    /// removed; the rest get their new weight. Returns the pairs removed.
    fn fade_transparent_pairs(
        &mut self,
        front: &[Vec3; 2],
        rest: &[Vec3],
        neighbours: &mut Neighbourhoods,
    ) -> usize {
        let h = self.kernel.support_m;
        let kappa_h = self.transparency * h;
        // A pair is faded out by the time the front is κh/2 past its crossing; one farther
        // away than that (and a support radius more) belongs to another front.
        let reach = 0.5 * kappa_h + h;
        let mut removed = 0;
        let mut r = 0;
        while r < self.transparent.len() {
            let pair = self.transparent[r];
            let (i, j) = (pair.i as usize, pair.j);
            let d_s = distance_sq_to_segment(&pair.crossing, &front[0], &front[1]).sqrt();
            if d_s > reach {
                r += 1;
                continue;
            }
            // Only ever more transparent: a front that turns back does not re-join a pair.
            let extra = (h * (2.0 * d_s / kappa_h).powi(2)).max(pair.extra_m);
            if (rest[i] - rest[j as usize]).norm() + extra >= h {
                // Faded out: the pair is cut.
                neighbours.remove(i, j);
                neighbours.remove(j as usize, pair.i);
                removed += 1;
                self.transparent.swap_remove(r);
                self.changed.extend([pair.i, j]);
                continue;
            }
            // Rows are rebuilt only when the weight moved by more than rounding.
            if extra - pair.extra_m > 1e-9 * h {
                neighbours.set_extra(i, j, extra);
                self.transparent[r].extra_m = extra;
                self.changed.extend([pair.i, j]);
            }
            r += 1;
        }
        removed
    }

    /// Pairs across the cut near its front, still partly connected.
    pub fn transparent_pairs(&self) -> usize {
        self.transparent.len()
    }

    fn moved_enough(&self, last: &[Vec3; 2], edge: &[Vec3; 2]) -> bool {
        let step = SWEEP_FRACTION_OF_SPACING * self.spacing_m;
        (edge[0] - last[0]).norm() >= step || (edge[1] - last[1]).norm() >= step
    }

    /// Whether the blade's steady point has moved a sweep step since it was at `from`.
    fn moved_steadily_since(&self, from: Option<Vec3>) -> bool {
        let step = SWEEP_FRACTION_OF_SPACING * self.spacing_m;
        match (self.steady.position(), from) {
            (Some(at), Some(from)) => (at - from).norm() >= step,
            _ => true,
        }
    }

    /// Whether `x` (rest) lies on Σ, within the blade's thickness and a quarter spacing.
    fn near_sigma(&self, x: &Vec3) -> bool {
        self.sigma
            .triangles
            .iter()
            .any(|tri| self.near_triangle(x, tri))
    }

    /// How much new crack the blade opens per unit of its motion, as a share of its depth
    /// (0–1): what its edge sweeps and what its tip slits, added in quadrature (a pointed
    /// blade, whose slit narrows to the tip, would open about the larger, a rectangular one
    /// their sum; in between, a corner from plunging to cutting forward neither dips nor
    /// bulges).
    ///
    /// * The edge, moving across itself, sweeps its depth × the sine of its angle to the
    ///   motion — a raked blade (a scalpel held at 45°) cuts the vertical depth, not the
    ///   length of edge in the tissue — times the share of it in uncut tissue: the edge is
    ///   moved ahead by two in-plane tolerances and sampled.
    /// * The tip, moving tip first, slits the tissue ahead of it as wide as the blade is
    ///   in it — its depth, at most the blade's width (a blade whose tip tapers at about
    ///   45°) — × the cosine, if the point two in-plane tolerances ahead of it is uncut.
    ///
    /// A point is cut already if it lies on a part of Σ that runs along the motion, within
    /// the contact tolerance across that part (a hand does not retrace a cut exactly) but
    /// within the in-plane tolerance of its extent, so that the end of a cut, or the floor
    /// of a shallower one, is found to within about a millimetre. (Forward, the samples are
    /// ahead of Σ's front, which is at most a sweep step behind the edge. An older cut the
    /// blade crosses faces the motion and does not count.)
    fn crack_share(&mut self, tip: Vec3, entry: Vec3) -> f64 {
        let h = self.direction;
        // Not moved yet (a tool that appeared in the tissue): nothing to look ahead along.
        let (Some(along_edge), false) = ((entry - tip).try_normalize(1e-12), h == Vec3::zeros())
        else {
            return 1.0;
        };
        let cos = along_edge.dot(&h);
        let across = h - along_edge * cos;
        let sin = across.norm();
        let tip_first = (-cos).max(0.0);
        let reach = 2.0 * self.sigma_plane_tolerance();
        let (a, b) = if sin > 1e-3 {
            let ahead = across * (reach / sin);
            (tip + ahead, entry + ahead)
        } else {
            (tip, tip)
        };
        let probe = tip + h * reach;
        // The Σ triangles near the moved edge and the tip's probe, once (Σ only grows over
        // a session); past the scratch's capacity, all of them.
        let pad = self.sigma_tolerance() + self.sigma_plane_tolerance();
        let region = Aabb::around([&a, &b, &probe]).expanded(pad);
        self.probe_candidates.clear();
        let mut overflow = false;
        for (t, b) in self.sigma.boxes.iter().enumerate() {
            if b.overlaps(&region) {
                if self.probe_candidates.len() == MAX_PROBE_CANDIDATES {
                    overflow = true;
                    break;
                }
                self.probe_candidates.push(t as u32);
            }
        }
        let cut = |x: &Vec3, along: &Vec3| {
            let on = |tri: &[Vec3; 3]| self.on_triangle_along(x, tri, along);
            if overflow {
                self.sigma.triangles.iter().any(on)
            } else {
                self.probe_candidates
                    .iter()
                    .any(|&t| on(&self.sigma.triangles[t as usize]))
            }
        };
        let edge = if sin > 1e-3 {
            let fresh = (0..FRESH_SAMPLES)
                .filter(|&k| {
                    !cut(
                        &(a + (b - a) * ((k as f64 + 0.5) / FRESH_SAMPLES as f64)),
                        &across,
                    )
                })
                .count();
            sin * fresh as f64 / FRESH_SAMPLES as f64
        } else {
            0.0
        };
        let slit = if tip_first > 0.0 && !cut(&probe, &h) {
            (self.tool.blade_width_m / (entry - tip).norm()).min(1.0) * tip_first
        } else {
            0.0
        };
        edge.hypot(slit).min(1.0)
    }

    /// Whether `x` (rest) is on `tri`, a part of Σ running along `direction`: within the
    /// contact tolerance of its plane and the in-plane tolerance of its extent.
    fn on_triangle_along(&self, x: &Vec3, tri: &[Vec3; 3], direction: &Vec3) -> bool {
        let n = (tri[1] - tri[0]).cross(&(tri[2] - tri[0]));
        let n_len = n.norm();
        if n.dot(direction).abs() >= 0.5 * n_len * direction.norm() {
            return false;
        }
        let off = x - closest_point_on_triangle(x, tri);
        let normal = off.dot(&n) / n_len;
        let in_plane = (off - n * (normal / n_len)).norm();
        normal.abs() <= self.sigma_tolerance() && in_plane <= self.sigma_plane_tolerance()
    }

    /// Whether `x` (rest) is within the contact tolerance of `tri`: the box test first.
    fn near_triangle(&self, x: &Vec3, tri: &[Vec3; 3]) -> bool {
        let tol = self.sigma_tolerance();
        Aabb::around(tri).expanded(tol).contains(x)
            && (closest_point_on_triangle(x, tri) - x).norm() <= tol
    }

    /// Contact tolerance: the blade's thickness and a quarter spacing.
    fn sigma_tolerance(&self) -> f64 {
        self.tool.blade_thickness_m + 0.25 * self.spacing_m
    }

    /// Tolerance within Σ's plane, where its extent ends (the end of a cut, the floor of a
    /// shallow one): the blade's thickness and a twentieth of a spacing, for the rest map's
    /// wobble between passes and the kinks of a curved sweep.
    fn sigma_plane_tolerance(&self) -> f64 {
        self.tool.blade_thickness_m + 0.05 * self.spacing_m
    }

    /// Integrates point `i` from the next tick on (it falls asleep again once at rest and
    /// out of the tool's reach).
    pub fn wake_point(&mut self, i: u32) {
        self.wake(i);
    }

    fn wake(&mut self, i: u32) {
        self.last_near[i as usize] = self.tick;
        if !std::mem::replace(&mut self.awake[i as usize], true) {
            self.awake_list.push(i);
            self.active_dirty = true;
        }
    }

    /// Wakes every point within R_aff of the rest edge; `plunge_normal` is the blade's
    /// flat's while it goes in point first.
    fn mark_affected(
        &mut self,
        edge: &[Vec3; 2],
        plunge_normal: Option<Vec3>,
        rest: &[Vec3],
        grid: &RestGrid,
    ) {
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
        // Left/right (physics.md §4.4): the sign of φ(X) = n_b·(X − P), n_b the blade
        // plane's normal, up the edge × the way it moves (+ is the left hand of someone
        // looking along the cut with the edge pointing up), while the blade moves across
        // its edge; plunging, the plane of its flat; lifting leaves the plane undefined
        // (pulling back would flip it).
        let up = (edge[1] - edge[0])
            .try_normalize(1e-12)
            .unwrap_or_else(Vec3::z);
        let across = up.cross(&self.direction);
        let normal = (across.norm() > 0.5 && self.direction.dot(&up) <= 0.7)
            .then(|| across.normalize())
            .or(plunge_normal);
        for r in 0..self.candidates.len() {
            let i = self.candidates[r];
            self.wake(i);
            if let Some(n) = normal {
                let phi = n.dot(&(rest[i as usize] - edge[0]));
                if phi.abs() > 1e-9 * self.spacing_m {
                    self.side[i as usize] = if phi > 0.0 { 1 } else { -1 };
                }
            }
        }
    }

    /// The level-set classification so far: points integrated now (cutting-affected) and
    /// not, and of the points ever in the affected region, those left and right of the
    /// blade plane when last marked.
    pub fn classification(&self) -> Classification {
        // Nodes after the body's points (virtual points) are not classified.
        let material = self.material_points;
        let affected = self
            .awake_list
            .iter()
            .filter(|&&i| (i as usize) < material)
            .count();
        Classification {
            affected,
            unaffected: material - affected,
            left: self.side.iter().filter(|&&s| s > 0).count(),
            right: self.side.iter().filter(|&&s| s < 0).count(),
        }
    }

    /// Side of point `i`: +1 left of the blade plane, −1 right, 0 never classified.
    pub fn side(&self, i: usize) -> i8 {
        self.side[i]
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

    /// Before rupture the blade dents the capsule: the points under the tip follow the blade
    /// (displacement control; the device force comes from the measured loading curve,
    /// which a linear-elastic organ this soft could not reproduce), the nearest fully and
    /// the others of the patch with a smooth fall-off. The dent relaxes over
    /// [`DENT_RELEASE_S`] after rupture or when the blade leaves.
    fn press_tissue(
        &mut self,
        now_s: f64,
        force: &CutForce,
        blade: Option<&Blade>,
        edge: Option<[Vec3; 2]>,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let pressing = force.phase == CutPhase::Loading;
        match (pressing, self.press_start, blade, edge) {
            (true, None, Some(b), Some(edge)) => {
                let rest = solver.rest();
                let radius = self.dent_radius_m;
                let mut nearest: Option<(f64, u32)> = None;
                grid.for_each_within(rest, &edge[0], 2.0 * self.kernel.support_m, |k, d2| {
                    if nearest.is_none_or(|(d, _)| d2 < d) {
                        nearest = Some((d2, k));
                    }
                });
                let Some((_, centre)) = nearest else { return };
                let c = rest[centre as usize];
                let radius = radius_holding(grid, rest, &c, radius, MAX_DENT_POINTS);
                let positions = solver.positions();
                let pressed = &mut self.pressed;
                pressed.clear();
                grid.for_each_within(rest, &c, radius, |k, d2| {
                    let q = 1.0 - d2 / (radius * radius);
                    if q > 0.0 && pressed.len() < MAX_DENT_POINTS {
                        pressed.push(Pressed {
                            point: k,
                            start_position: positions[k as usize],
                            weight: if k == centre { 1.0 } else { q * q },
                        });
                    }
                });
                for r in 0..self.pressed.len() {
                    let k = self.pressed[r].point;
                    self.wake(k);
                    solver.fix(k as usize, [true; 3]);
                }
                self.press_start = Some(b.tip);
                self.press_travel = Vec3::zeros();
                self.release_start_s = None;
                self.dent_patch = (c, radius);
                self.wake_around_dent(solver.rest(), grid);
            }
            (true, Some(start), Some(b), _) if self.release_start_s.is_none() => {
                // The dent goes in with the blade and back up with it, never out past
                // where the blade touched; sideways it follows (a slide ruptures the
                // capsule within the rupture displacement).
                let travel = b.tip - start;
                let into = travel.dot(&force.direction);
                self.press_travel = travel + force.direction * (into.max(0.0) - into);
                self.hold_dent(1.0, solver);
                self.wake_around_dent(solver.rest(), grid);
            }
            (_, Some(_), _, _) => {
                let since = *self.release_start_s.get_or_insert(now_s);
                let left = 1.0 - (now_s - since) / DENT_RELEASE_S;
                if left > 0.0 {
                    self.hold_dent(left, solver);
                    self.wake_around_dent(solver.rest(), grid);
                } else {
                    for p in &self.pressed {
                        solver.fix(p.point as usize, [false; 3]);
                    }
                    self.pressed.clear();
                    self.press_start = None;
                    self.release_start_s = None;
                }
            }
            _ => {}
        }
    }

    /// Keeps the points within one support radius of the dent patch integrated while it is
    /// held. The affected region around the edge (3 support radii) does not cover a patch two
    /// rupture displacements wide on a fine lattice, and the points left asleep beside it
    /// stayed where they were, taking the patch's whole strain at its rim: on the 12 mm
    /// tumour scan they sprang out inverted, at 1.7 m/s, when rupture woke them.
    fn wake_around_dent(&mut self, rest: &[Vec3], grid: &RestGrid) {
        let (c, radius) = self.dent_patch;
        let reach = radius + self.kernel.support_m;
        grid.for_each_within(rest, &c, reach, |k, _| self.wake(k));
    }

    /// Holds the dented points at `fraction` of the dent.
    fn hold_dent(&mut self, fraction: f64, solver: &mut Solver) {
        let travel = self.press_travel * fraction;
        for p in &self.pressed {
            self.last_near[p.point as usize] = self.tick;
            solver.set_target(p.point as usize, p.start_position + travel * p.weight);
        }
    }

    /// Unit direction of the blade's recent motion, averaged over about half a millimetre
    /// of travel (zero before it has moved, and again after the tool is gone).
    pub fn direction(&self) -> Vec3 {
        self.direction
    }

    /// Points integrated now.
    pub fn awake_points(&self) -> &[u32] {
        &self.awake_list
    }
}

/// The largest radius up to `radius` whose ball about `c` holds at most `most` points: the
/// dent patch of a small organ sampled finely would hold more than its preallocated slots,
/// and cutting the patch off in the grid's order left free points among pressed ones,
/// dragged inside out. Shrinks by the cube root of the excess (a few grid queries, once per
/// press; no allocation).
fn radius_holding(grid: &RestGrid, rest: &[Vec3], c: &Vec3, radius: f64, most: usize) -> f64 {
    let mut r = radius;
    for _ in 0..8 {
        let mut inside = 0usize;
        grid.for_each_within(rest, c, r, |_, d2| {
            if d2 < r * r {
                inside += 1;
            }
        });
        if inside <= most {
            return r;
        }
        r *= 0.97 * (most as f64 / inside as f64).cbrt();
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lattice of 1 mm spacing, 21³ points: a ball of 6 mm radius holds about 900.
    fn lattice() -> (Vec<Vec3>, RestGrid) {
        let mut rest = Vec::new();
        for z in 0..21 {
            for y in 0..21 {
                for x in 0..21 {
                    rest.push(Vec3::new(x as f64, y as f64, z as f64) * 1e-3);
                }
            }
        }
        let grid = RestGrid::build(&rest, 2e-3);
        (rest, grid)
    }

    fn held(grid: &RestGrid, rest: &[Vec3], c: &Vec3, r: f64) -> usize {
        let mut n = 0;
        grid.for_each_within(rest, c, r, |_, d2| n += usize::from(d2 < r * r));
        n
    }

    /// The dent patch is a whole ball: a radius whose ball holds more points than the slots
    /// shrinks until it holds at most that many (not much fewer), and one that fits is kept.
    #[test]
    fn a_dent_patch_too_large_for_its_slots_shrinks_to_a_whole_ball() {
        let (rest, grid) = lattice();
        let c = Vec3::new(10.0, 10.0, 20.0) * 1e-3; // on a face: half a ball inside
        let r = radius_holding(&grid, &rest, &c, 6e-3, MAX_DENT_POINTS);
        let n = held(&grid, &rest, &c, r);
        println!("radius 6 → {:.2} mm holding {n} points", r * 1e3);
        assert!(held(&grid, &rest, &c, 6e-3) > MAX_DENT_POINTS);
        assert!((MAX_DENT_POINTS / 2..=MAX_DENT_POINTS).contains(&n), "{n}");
        assert!(r < 6e-3 && r > 3e-3, "{r}");
        assert_eq!(
            radius_holding(&grid, &rest, &c, 2e-3, MAX_DENT_POINTS),
            2e-3
        );
    }
}
