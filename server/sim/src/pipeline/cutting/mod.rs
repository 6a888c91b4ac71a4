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
//! 5. The blade is a body the tissue cannot enter (`touch`, `solver::blade`): surface
//!    samples around it are kept out of its slab in every sub-step, with friction. Before
//!    rupture its tip's end dents the capsule; once cutting, its flats push the lips aside
//!    (`lips`), and what meets the tip or the edge is the crack's. The force on the tool is
//!    the tissue's reaction, plus the fracture term while cutting.

use std::ops::Range;

use crate::cut::{Blade, SweptSurface, visit_crossing_pairs};
use crate::force::{BladeContact, CRUSHED_DET_F, CutForce, CutPhase, CuttingForceModel};
use crate::geometry::predicates::{closest_point_on_triangle, distance_sq_to_segment};
use crate::math::{Aabb, Vec3};
use crate::model::{Kernel, Neighbourhoods, RestGrid};
use crate::scene::{ForceSpec, ToolSpec};
use crate::solver::Solver;
use crate::solver::blade::Slab;

use super::steady_motion::SteadyMotion;
use super::surface::{CurrentSurface, SurfaceContact};

mod fracture;
mod lips;
mod region;
mod sigma;
mod spine;
mod touch;

use fracture::CrackFront;
use lips::Lips;
use sigma::TransparentPair;
use spine::SpineHold;
use touch::TouchScratch;
pub(crate) use touch::{MAX_BLADE_ENTRIES, MAX_BLADE_SAMPLES, slab_of};

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
    /// The crack front jumped this tick (a fracture event: the energy the blade stored in
    /// the tissue ahead paid for the new crack), or the spine tore the tissue it crushed.
    pub fractured: bool,
}

/// Most pairs in the transparency zone at once (preallocated); beyond it a crossing pair is
/// cut at once, as with hard visibility. A front 20 mm long on a 1 mm lattice has about 2000.
const MAX_TRANSPARENT_PAIRS: usize = 8192;

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
    /// The blade's samples' build scratch (`touch`).
    touch: TouchScratch,
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
    /// The crack front and its samples (`fracture`).
    front: CrackFront,
    /// The lips' columns (`lips`).
    lips: Lips,
    /// The spine against the tissue past it (`spine`).
    spine: SpineHold,
}

/// What the blade's edge is read from.
struct Reading<'a> {
    blade: Option<&'a Blade>,
    contact: &'a SurfaceContact,
    surface: &'a CurrentSurface,
    solver: &'a Solver,
    grid: &'a RestGrid,
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
            touch: TouchScratch::new(),
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
            front: CrackFront::default(),
            lips: Lips::new(),
            spine: SpineHold::default(),
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

    /// The virtual nodes (indices past the body's points) a pair of which this tick's Σ
    /// cut: their masters are split, so they must be released before the step.
    pub fn nodes_cut(&self) -> impl Iterator<Item = u32> + '_ {
        let material = self.material_points as u32;
        self.changed.iter().copied().filter(move |&i| i >= material)
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
        let lifting = blade.is_some_and(|b| self.direction.dot(&b.edge) > 0.7);
        // Moved back toward its spine the blade cannot cut: its spine pushes the tissue
        // past it (`spine`) until that tears.
        let backing = phase_before == CutPhase::Cutting && blade.is_some_and(|b| self.backing(b));
        let withdrawing = retracing || lifting || backing;
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
                crushed: phase_before == CutPhase::Loading && crushed_under_blade(solver),
            },
        );
        // The crack advances by energy: what the edge's samples stored in the tissue.
        let jump = if withdrawing {
            None
        } else {
            self.fracture_due(force.phase, blade, depth_m * crack, solver)
        };
        let mut sweep = self.grow_sigma(&force, edge_rest, blade, retracing, withdrawing, jump);
        // Where the spine has indented the tissue past it as far as it ruptures, it tears.
        let tear = edge_rest
            .zip(blade)
            .filter(|_| backing && self.spine_tears(solver))
            .and_then(|(edge, b)| self.tear_rest(&edge, b));
        if let Some(quad) = tear {
            self.tear_through(quad);
            sweep.new_sigma.end = self.sigma.triangles.len();
        }
        let pairs_removed = self.cut_pairs(sweep.new_sigma.clone(), solver, neighbours, grid);
        // Lifted out along its edge, the blade lets the crack front go over a time, not a
        // sample pitch at a time.
        let pace = if lifting {
            self.let_go_pace(solver)
        } else {
            0.0
        };
        if let Some(body) = solver.blade_mut() {
            body.let_go_front(pace);
        }
        self.touch_tissue(dt, &force, blade, depth_m, surface, solver, grid);
        match blade.filter(|_| force.phase == CutPhase::Cutting) {
            Some(b) => {
                let torn = tear.is_some();
                self.follow_spine(b, edge_rest, depth_m, backing, torn, solver, grid);
            }
            None => self.drop_spine(solver),
        }
        self.update_region(edge_rest, sweep.plunge_normal, solver, grid);
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
            fractured: sweep.fractured || tear.is_some(),
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

    /// Pairs across the cut near its front, still partly connected.
    pub fn transparent_pairs(&self) -> usize {
        self.transparent.len()
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

/// Whether a point the blade's held samples follow has lost more than [`CRUSHED_DET_F`] of
/// its volume. Only those: an earlier wound still awake elsewhere (a lab session's strokes)
/// is not the capsule this blade presses.
fn crushed_under_blade(solver: &Solver) -> bool {
    solver.blade().is_some_and(|b| {
        b.held_points()
            .any(|i| solver.deformation_gradient(i as usize).determinant() < CRUSHED_DET_F)
    })
}
