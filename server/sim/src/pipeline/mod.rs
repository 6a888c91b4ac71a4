//! One simulation tick, from the tool pose to the surface the renderers draw.
//!
//! [`Simulation`] is the core's whole interface, quinn-proto style: inputs come in as
//! `handle_*` calls (the tool's pose, a stiffness change), [`Simulation::tick`] advances by
//! one fixed tick through private stages in one order, and outputs are read or polled (the
//! [`TickReport`], the local force model, [`Simulation::poll_event`], the surface a frame
//! writer copies). It reads no clock, spawns no thread and does no I/O: a stage's wall time
//! is measured with the caller's [`StageClock`], and a stroke's re-cut runs on the caller's
//! [`RecutRunner`]. The stages, in order ([`Stage`]):
//!
//! ```text
//!   the blade follows the tool at a hand's speed (blade_motion)
//!   contact           the blade against the current surface (BVH)            [surface]
//!   interior cut      force model, Σ, visibility, pairs cut, affected region  [internal]
//!   release vpoints   virtual points near the blade released, rows refitted   [internal]
//!   integrate         solver step on the awake points                         [internal]
//!   surface incision  Σ cuts the embedding; the stroke's re-cuts handed out
//!                     and landed (the drawn surface re-meshed)                [surface]
//!   place vpoints     virtual points placed on the walls, a few a tick        [surface]
//!   surface follow    the surface follows the points that moved               [surface]
//!   force model       the force bounded, the local model for the haptic loop
//! ```
//!
//! Every topology change (pairs cut by Σ, virtual points released or placed) goes through
//! one step, [`apply_topology`]. Only what the scene uses is built: a scene without cutting
//! has no contact, interior cut, incision or force model, and integrates every point.

pub mod blade_motion;
pub mod cutting;
pub mod probe;
pub mod recut;
pub mod script;
pub mod steady_motion;
pub mod stroke_tracker;
pub mod supports;
pub mod surface;
pub mod tissue_force;
pub mod virtual_points;

use crate::cut::{Blade, IncisionParams, ToolPose};
use crate::force::{CutForce, CutPhase, LocalForceModel};
use crate::geometry::TriMesh;
use crate::math::Vec3;
use crate::mls::forces::Threads;
use crate::model::{Neighbourhoods, RestGrid};
use crate::scene::{BuiltScene, SceneSpec};
use crate::solver::blade::BladeBody;
use crate::solver::{Solver, SolverEvent, StepReport};

pub use cutting::{Classification, CutTick, CuttingStage};
pub use recut::{InlineRecuts, RECUT_HANDOVER_TICKS, RecutJob, RecutResult, RecutRunner};
pub use script::{CSV_HEADER, CutScript, Keyframe, ScriptError, vertical_extent};
pub use stroke_tracker::{IncisionStats, StrokeTracker};
pub use supports::{start_surface, surface_prestress};
pub use surface::{CurrentSurface, SurfaceContact};
pub use virtual_points::{VirtualPointStats, VirtualPoints};

/// Simulated time per simulation tick (s): the station's simulation thread runs at 1 kHz,
/// and the offline runs and the real-time sampling rule plan for the same tick.
pub const SIMULATION_TICK_S: f64 = 1e-3;

/// The longest a body is given to come to rest under gravity before the first tick (s).
pub const SETTLE_MAX_S: f64 = 10.0;

use stroke_tracker::TrackerInputs;
use virtual_points::{PlaceBudget, PlacementInputs, VIRTUAL_NODE_CAPACITY};

/// Virtual points placed per tick after a re-mesh: each changes the MLS rows of the points
/// it joins (a dozen on the cerebroma, 35 on the liver), so they are spread over the ticks
/// that follow — at most 4 nodes, and none more once 32 points have new rows (instrumented:
/// the cerebroma's 19 nodes of a mid-stroke re-mesh 2.4 ms at once; the liver's 4 nodes,
/// 139 rows, 0.62 ms in one tick).
pub const PLACE_PER_TICK: PlaceBudget = PlaceBudget { nodes: 4, rows: 32 };

/// The stages of a tick, in the order they run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// The blade against the current surface.
    Contact,
    /// The cutting stage: force model, Σ, visibility, pairs cut, affected region.
    InteriorCut,
    /// Virtual points near the blade released.
    ReleaseVirtualPoints,
    /// The solver's step.
    Integrate,
    /// Σ cuts the surface's embedding; the stroke's re-cuts handed out and landed.
    SurfaceIncision,
    /// Virtual points placed on the walls.
    PlaceVirtualPoints,
    /// The surface follows the points.
    SurfaceFollow,
    /// The force bounded and the local model made.
    ForceModel,
}

impl Stage {
    /// Every stage, in tick order.
    pub const ALL: [Stage; 8] = [
        Stage::Contact,
        Stage::InteriorCut,
        Stage::ReleaseVirtualPoints,
        Stage::Integrate,
        Stage::SurfaceIncision,
        Stage::PlaceVirtualPoints,
        Stage::SurfaceFollow,
        Stage::ForceModel,
    ];

    /// Short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Contact => "contact",
            Self::InteriorCut => "interior_cut",
            Self::ReleaseVirtualPoints => "release_virtual_points",
            Self::Integrate => "integrate",
            Self::SurfaceIncision => "surface_incision",
            Self::PlaceVirtualPoints => "place_virtual_points",
            Self::SurfaceFollow => "surface_follow",
            Self::ForceModel => "force_model",
        }
    }

    /// The half of Table 1 of the paper it counts in (`None`: neither).
    pub fn half(self) -> Option<Half> {
        match self {
            Self::Contact
            | Self::SurfaceIncision
            | Self::PlaceVirtualPoints
            | Self::SurfaceFollow => Some(Half::Surface),
            Self::InteriorCut | Self::ReleaseVirtualPoints | Self::Integrate => {
                Some(Half::Internal)
            }
            Self::ForceModel => None,
        }
    }
}

/// The two halves of a tick that Table 1 of the paper reports separately.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Half {
    /// Surface work: blade contact, incision, vertices following the points.
    Surface,
    /// Interior work: force model, cut surface, visibility, MLS rows, integration.
    Internal,
}

/// The caller's clock, read at each stage's boundaries (the core reads none itself).
pub trait StageClock: Send {
    /// Seconds on any monotonic clock.
    fn now_s(&mut self) -> f64;
}

/// No clock: every stage's time is zero (the counters cost nothing).
#[derive(Debug, Default, Clone, Copy)]
pub struct NoClock;

impl StageClock for NoClock {
    fn now_s(&mut self) -> f64 {
        0.0
    }
}

/// Each stage's wall time in one tick, on the caller's clock (s).
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct StageTimes {
    seconds: [f64; Stage::ALL.len()],
}

impl StageTimes {
    /// Stage `stage`'s time (s).
    pub fn of(&self, stage: Stage) -> f64 {
        self.seconds[stage as usize]
    }

    /// The whole tick's time (s): every stage's.
    pub fn total(&self) -> f64 {
        self.seconds.iter().sum()
    }

    /// Each stage's name and time (ms), in tick order.
    pub fn ms_by_stage(&self) -> [(&'static str, f64); Stage::ALL.len()] {
        Stage::ALL.map(|s| (s.name(), self.of(s) * 1e3))
    }

    /// The time of the stages in `half` (s).
    pub fn half(&self, half: Half) -> f64 {
        Stage::ALL
            .iter()
            .filter(|s| s.half() == Some(half))
            .map(|&s| self.of(s))
            .sum()
    }
}

/// Reads the clock at each stage's end and books the time since the last reading to it.
struct Laps<'a> {
    clock: &'a mut dyn StageClock,
    last_s: f64,
    times: StageTimes,
}

impl<'a> Laps<'a> {
    fn start(clock: &'a mut dyn StageClock) -> Self {
        let last_s = clock.now_s();
        Self {
            clock,
            last_s,
            times: StageTimes::default(),
        }
    }

    fn lap(&mut self, stage: Stage) {
        let now = self.clock.now_s();
        self.times.seconds[stage as usize] += now - self.last_s;
        self.last_s = now;
    }
}

/// What happened in one tick.
#[derive(Debug, Clone, PartialEq)]
pub struct TickReport {
    /// Simulated time at the end of the tick (s).
    pub time_s: f64,
    /// The cutting stage's part, for scenes that cut and while a tool is present.
    pub cut: Option<CutTick>,
    /// Force for the device (N), bounded by the scene's `max_force_n`.
    pub tool_force_n: Vec3,
    /// Points integrated this tick.
    pub active_points: usize,
    /// Surface vertices moved this tick.
    pub vertices_moved: usize,
    /// The incision re-meshed the surface this tick (its topology changed).
    pub remeshed: bool,
    /// The solver's report.
    pub solver: StepReport,
    /// Each stage's wall time, on the caller's clock.
    pub stages: StageTimes,
}

/// A running scene.
pub struct Simulation {
    spec: SceneSpec,
    solver: Solver,
    neighbours: Neighbourhoods,
    grid: RestGrid,
    surface: CurrentSurface,
    cutting: Option<CuttingStage>,
    incisions: Option<StrokeTracker>,
    virtual_points: Option<VirtualPoints>,
    /// Scratch for the points whose lists virtual points changed.
    vp_changed: Vec<u32>,
    /// Points and nodes whose lists a placement's second look changed (room made once).
    vp_again: Vec<u32>,
    /// The pose the tool asks for ...
    tool: Option<ToolPose>,
    /// ... and where the blade is, following it at a hand's speed (blade_motion.rs).
    blade_pose: Option<ToolPose>,
    /// Where the blade was when an unsound pose took the tool away: it goes on from there
    /// (a tracker that glitches to NaN and then to a jumped position must not teleport it).
    resume_blade: Option<ToolPose>,
    time_s: f64,
    local_model: LocalForceModel,
    all_points: Vec<u32>,
    settled: Option<supports::SettleReport>,
    support_counts: supports::SupportCounts,
    tissue_force: tissue_force::TissueForce,
    /// The last tick's integrated points × passes over them (sub-steps, or an implicit
    /// tick's CG iterations and its step): what decides whether the next one shares its
    /// work ([`PARALLEL_MIN_WORK`]).
    last_work: usize,
    /// The caller lets the ticks share their work (`set_sharing`).
    sharing: bool,
    #[cfg(feature = "parallel")]
    pool: Option<std::sync::Arc<rayon::ThreadPool>>,
}

/// The least work a tick shares with a pool's other thread (integrated points × passes,
/// `StepReport::passes`): below it a join's hand-over and the other thread's wake cost more
/// than its half of the work saves (`scalpel bench table1 --threads 2`: the liver cut, ~480 awake
/// points and one sub-step, took 0.295 ms a step on two threads against 0.214 on one; the
/// shoulder and cerebroma, a few thousand, 1.45× and 1.24× faster; docs/BENCHMARKS.md).
pub const PARALLEL_MIN_WORK: usize = 2000;

impl Simulation {
    /// Starts a built scene at rest.
    pub fn new(scene: &BuiltScene) -> Self {
        let spec = scene.spec.clone();
        let model = &scene.model;
        let n = model.points.len();
        // Virtual points are spare nodes after the body's points (virtual_points.rs).
        let spare = if spec.features.cutting && spec.features.virtual_points {
            VIRTUAL_NODE_CAPACITY
        } else {
            0
        };
        let neighbours = model.neighbours.with_spare_lists(spare);
        let (mut solver, support_counts) = supports::held_solver(scene, &neighbours, spare);
        // Under gravity the body starts where it rests, before anything touches it: settled
        // once per built scene.
        let settled = supports::start_state(scene).map(|start| {
            let mut p = solver.positions().to_vec();
            p[..n].copy_from_slice(&start.positions);
            solver.set_positions(&p);
            start.report
        });
        let virtual_points = (spare > 0)
            .then(|| VirtualPoints::new(n, spare, model.lattice.spacing, model.kernel.support_m));
        let mut cutting = spec.features.cutting.then(|| {
            CuttingStage::new(
                n + spare,
                n,
                model.kernel,
                model.lattice.spacing,
                spec.tool,
                &spec.force,
                spec.features.ripple,
            )
        });
        if cutting.is_some() {
            // Nothing moves until the tool touches: no point is integrated.
            solver.set_active(&[]);
            // The blade is a body the tissue cannot enter (cutting/touch.rs).
            let upright = ToolPose {
                tip_m: Vec3::zeros(),
                orientation: nalgebra::UnitQuaternion::identity(),
            };
            let at = Blade::at(&upright, &spec.tool);
            let room = || {
                BladeBody::with_room(
                    n + spare,
                    cutting::MAX_BLADE_SAMPLES,
                    cutting::MAX_BLADE_ENTRIES,
                    cutting::slab_of(&at, &spec.tool),
                )
            };
            if let Some(stage) = &mut cutting {
                // A clone would have no room: its vectors are only as long as they are.
                stage.give_blade_room(room());
            }
            solver.set_blade(Some(room()));
        }
        let incisions = spec.features.cutting.then(|| {
            StrokeTracker::new(
                model.surface.mean_edge_length(),
                IncisionParams::closed(),
                model,
            )
        });
        let mut sim = Self {
            tissue_force: tissue_force::TissueForce::default(),
            settled,
            support_counts,
            incisions,
            virtual_points,
            vp_changed: Vec::with_capacity(4096),
            vp_again: Vec::with_capacity(4096),
            surface: CurrentSurface::new(model, spare),
            neighbours,
            grid: model.grid.clone(),
            solver,
            cutting,
            tool: None,
            blade_pose: None,
            resume_blade: None,
            time_s: 0.0,
            local_model: LocalForceModel {
                f0_n: Vec3::zeros(),
                x0_m: Vec3::zeros(),
                stiffness_n_per_m: crate::math::Mat3::zeros(),
                stored_energy_j: 0.0,
            },
            all_points: (0..n as u32).collect(),
            spec,
            last_work: 0,
            sharing: true,
            #[cfg(feature = "parallel")]
            pool: None,
        };
        if sim.settled.is_some() {
            sim.surface.follow(
                sim.solver.operator(),
                sim.solver.rest(),
                sim.solver.positions(),
                &sim.all_points,
                Threads::One,
            );
        }
        sim
    }

    /// How many points and vertices the scene's supports hold.
    pub fn supports(&self) -> supports::SupportCounts {
        self.support_counts
    }

    /// Lets the body come to rest dynamically under `gravity` (every point awake, ticks of
    /// [`SIMULATION_TICK_S`], at most [`SETTLE_MAX_S`]), from where it is: how long that
    /// takes and how far it sags (`scalpel settle`). Before any tool touches it.
    pub fn settle_under(&mut self, gravity: Vec3) -> supports::SettleReport {
        self.solver.set_gravity(gravity);
        let report = supports::settle(&mut self.solver, gravity, SIMULATION_TICK_S, SETTLE_MAX_S);
        if self.cutting.is_some() {
            self.solver.set_active(&[]);
        }
        self.surface.follow(
            self.solver.operator(),
            self.solver.rest(),
            self.solver.positions(),
            &self.all_points,
            Threads::One,
        );
        self.settled = Some(report);
        report
    }

    /// How the body came to rest under gravity before the first tick (`None` without
    /// gravity): in static equilibrium, unless [`Self::settle_under`] let it come to rest.
    pub fn settled(&self) -> Option<&supports::SettleReport> {
        self.settled.as_ref()
    }

    /// Plans ticks of `dt` before the first (see [`Solver::prepare`]): the power iterations
    /// that find the stable step and scale the uncut body's masses to whole sub-steps run
    /// here and not in the first tick.
    pub fn prepare(&mut self, dt: f64) {
        self.solver.prepare(dt);
    }

    /// Scales the tissue's stiffness to `factor` times the scene's (an instructor's fault):
    /// the solver's Young's modulus (its stable step is re-derived) and the force model's
    /// loading curve and friction. Re-derives constants: call it on a change, not per tick.
    pub fn handle_stiffness_factor(&mut self, factor: f64) {
        self.solver
            .set_youngs_modulus(self.spec.material.youngs_modulus_pa * factor);
        if let Some(stage) = &mut self.cutting {
            stage.set_stiffness_factor(factor);
            if self.settled.is_some() {
                // Under its weight the organ rests elsewhere at another stiffness: every
                // point is woken to find it (each falls asleep again once at rest). Asleep,
                // they held the old sag against the region the blade woke, which sprang
                // into or away from the blade.
                for i in 0..self.solver.material_points() as u32 {
                    stage.wake_point(i);
                }
            }
        }
    }

    /// The tool's pose for the next tick; `None` takes the tool away, and so does a pose
    /// that is not [sound](ToolPose::is_sound) (the callers check theirs; a non-finite
    /// pose must not reach the contact and the force model whatever the caller). The blade
    /// follows it from where it was at most at [`blade_motion::MAX_BLADE_SPEED_M_PER_S`]; a
    /// tool taken away appears where it is next put (one dropped as unsound goes on from where
    /// it was).
    pub fn handle_tool_pose(&mut self, pose: Option<ToolPose>) {
        self.tool = pose.filter(ToolPose::is_sound);
        self.resume_blade = match (pose, self.tool) {
            (Some(_), None) => self.blade_pose.or(self.resume_blade),
            (None, _) => None,
            (Some(_), Some(_)) => self.resume_blade,
        };
    }

    /// Where the blade is after the last tick (`None`: no tool); it lags the tool's pose only
    /// while that moves faster than a hand.
    pub fn blade_pose(&self) -> Option<ToolPose> {
        self.blade_pose
    }

    /// Where the next tick of `dt` will put the blade (the tool's pose when it moves at a
    /// hand's speed): what a frame drawn before that tick shows.
    pub fn next_blade_pose(&self, dt: f64) -> Option<ToolPose> {
        match (self.tool, self.blade_pose.or(self.resume_blade)) {
            (Some(asked), Some(at)) => Some(blade_motion::follow(
                &at,
                &asked,
                dt,
                self.spec.tool.blade_length_m,
            )),
            (asked, _) => asked,
        }
    }

    /// Advances by `dt` seconds (every caller's tick is [`SIMULATION_TICK_S`]), through the
    /// stages of the module docs in their order, timing each on `clock`.
    /// With a pool (`use_pool`) the whole tick runs on it, its other thread kept at hand
    /// through the tick for the parts of each stage.
    pub fn tick(&mut self, dt: f64, clock: &mut dyn StageClock) -> TickReport {
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pool.clone() {
            // Decided on the last tick's work (the awake region changes slowly) and the
            // caller's choice; the same bits either way.
            let parallel = self.sharing && self.can_share_next_tick();
            self.solver.set_parallel(parallel);
            if parallel {
                return crate::solver::on_pool::on_pool(&pool, || {
                    self.tick_here(dt, clock, Threads::Rayon)
                });
            }
        }
        self.tick_here(dt, clock, Threads::One)
    }

    /// The tick's stages, their parts on `threads`.
    fn tick_here(&mut self, dt: f64, clock: &mut dyn StageClock, threads: Threads) -> TickReport {
        let mut laps = Laps::start(clock);
        let blade = self.move_blade(dt);
        let contact = self.contact(&blade);
        laps.lap(Stage::Contact);
        let cut = self.interior_cut(dt, blade.as_ref(), &contact);
        laps.lap(Stage::InteriorCut);
        self.release_virtual_points(&cut);
        laps.lap(Stage::ReleaseVirtualPoints);
        let solver = self.solver.step(dt);
        laps.lap(Stage::Integrate);
        let remeshed = self.surface_incision(&cut);
        laps.lap(Stage::SurfaceIncision);
        if let Some(tick) = &cut {
            self.place_virtual_points(remeshed, tick.edge_rest, PLACE_PER_TICK);
        }
        laps.lap(Stage::PlaceVirtualPoints);
        let vertices_moved = self.surface_follow(threads);
        laps.lap(Stage::SurfaceFollow);
        self.time_s += dt;
        let tool_force_n = self.force_model(&cut, &blade);
        laps.lap(Stage::ForceModel);
        // The body's points (virtual points are kinematic nodes, not integrated).
        let active_points = {
            let body = self.solver.material_points() as u32;
            self.solver
                .active_points()
                .iter()
                .filter(|&&i| i < body)
                .count()
        };
        self.last_work = active_points * solver.passes() as usize;
        TickReport {
            time_s: self.time_s,
            cut,
            tool_force_n,
            active_points,
            vertices_moved,
            remeshed,
            solver,
            stages: laps.times,
        }
    }

    /// The blade follows the tool at a hand's speed.
    fn move_blade(&mut self, dt: f64) -> Option<Blade> {
        self.blade_pose = self.next_blade_pose(dt);
        if self.blade_pose.is_some() {
            self.resume_blade = None;
        }
        self.blade_pose
            .map(|pose| Blade::at(&pose, &self.spec.tool))
    }

    /// Stage contact: the blade against the current surface (a scene that cuts).
    fn contact(&mut self, blade: &Option<Blade>) -> SurfaceContact {
        match (&self.cutting, blade) {
            (Some(_), Some(b)) => self.surface.contact(b),
            _ => SurfaceContact::none(),
        }
    }

    /// Stage interior cut: the cutting stage's tick (a scene that cuts).
    fn interior_cut(
        &mut self,
        dt: f64,
        blade: Option<&Blade>,
        contact: &SurfaceContact,
    ) -> Option<CutTick> {
        let stage = self.cutting.as_mut()?;
        Some(stage.advance(
            self.time_s + dt,
            blade,
            contact,
            &self.surface,
            &mut self.solver,
            &mut self.neighbours,
            &self.grid,
        ))
    }

    /// Stage release virtual points: those a pair of which this tick's Σ cut, and those
    /// within a support of the blade's edge.
    fn release_virtual_points(&mut self, cut: &Option<CutTick>) {
        let (Some(vp), Some(stage), Some(tick)) =
            (&mut self.virtual_points, &mut self.cutting, cut)
        else {
            return;
        };
        self.vp_changed.clear();
        vp.release_at_blade(
            tick.edge_rest,
            stage.nodes_cut(),
            &mut self.solver,
            &mut self.neighbours,
            &mut self.vp_changed,
        );
        refit_changed(
            &mut self.vp_changed,
            &mut self.solver,
            &self.neighbours,
            stage,
        );
    }

    /// Stage surface incision: the new Σ triangles cut the surface's embedding, and the
    /// stroke's tracker samples the path, hands re-cuts out and lands them. Returns whether
    /// the surface was re-meshed.
    fn surface_incision(&mut self, cut: &Option<CutTick>) -> bool {
        let (Some(stage), Some(tick)) = (&self.cutting, cut) else {
            return false;
        };
        for t in tick.new_sigma.clone() {
            self.surface
                .cut_embedding(&stage.sigma.triangles[t], self.solver.rest());
        }
        let Some(tracker) = &mut self.incisions else {
            return false;
        };
        let edge = tick
            .edge_rest
            .filter(|_| tick.force.phase == CutPhase::Cutting);
        tracker.update(
            edge,
            stage.direction(),
            tick.withdrawing,
            tick.slit_rest,
            &mut self.surface,
            &TrackerInputs::of(&self.solver, &self.grid, &stage.sigma),
        )
    }

    /// Stage surface follow: the surface's vertices follow the points that moved (all of
    /// them in a scene that does not cut). Returns how many vertices moved.
    fn surface_follow(&mut self, threads: Threads) -> usize {
        let moved = if self.cutting.is_some() {
            self.solver.active_points()
        } else {
            &self.all_points
        };
        self.surface.follow(
            self.solver.operator(),
            self.solver.rest(),
            self.solver.positions(),
            moved,
            threads,
        )
    }

    /// Stage force model: the force on the tool, bounded, and the local model the haptic
    /// loop renders until the next tick.
    fn force_model(&mut self, cut: &Option<CutTick>, blade: &Option<Blade>) -> Vec3 {
        match (cut, blade) {
            (Some(t), Some(b)) => {
                // Free, the force's direction is zero and so is the model's stiffness.
                let by_energy = self.spec.force.fracture_by_energy;
                // Faces backing out of a press are not the blade (the force model's
                // fracture term stands for the crack they open).
                let tissue = self
                    .solver
                    .blade()
                    .filter(|body| by_energy || !body.releasing_press())
                    .map_or(Vec3::zeros(), |body| body.force_on_blade());
                let force = self
                    .tissue_force
                    .combine(&t.force, tissue, b.tip, by_energy);
                let force = bounded(&force, self.spec.force.max_force_n);
                self.local_model = force.local_model(b.tip);
                force.force_n
            }
            _ => Vec3::zeros(),
        }
    }

    /// The next thing the simulation reports (solver events: rollbacks, divergence, the
    /// time step), oldest first; `None` when there is nothing (drain it after each tick: the
    /// queue has a fixed capacity and drops what does not fit).
    #[must_use]
    pub fn poll_event(&mut self) -> Option<SolverEvent> {
        self.solver.poll_event()
    }

    /// Places virtual points on the walls of the surface, none within the affected radius
    /// of the blade's `edge`: after a re-mesh (`remeshed`) it first keeps, releases and
    /// chooses sites ([`VirtualPoints::remeshed`]), and either way places as many of the
    /// nodes still waiting as `budget` allows ([`VirtualPoints::place_pending`]).
    fn place_virtual_points(
        &mut self,
        remeshed: bool,
        edge: Option<[Vec3; 2]>,
        budget: PlaceBudget,
    ) {
        let (Some(vp), Some(stage)) = (&mut self.virtual_points, &mut self.cutting) else {
            return;
        };
        let inputs = PlacementInputs {
            surface: &self.surface,
            sigma: &stage.sigma,
            clear: edge.map(|e| (e, stage.affected_radius())),
            grid: &self.grid,
        };
        let changed = &mut self.vp_changed;
        changed.clear();
        if remeshed {
            vp.remeshed(
                &inputs,
                &mut self.solver,
                &mut self.neighbours,
                changed,
                budget,
            );
        } else {
            vp.place_pending(
                &inputs,
                &mut self.solver,
                &mut self.neighbours,
                changed,
                budget,
            );
        }
        refit_changed(changed, &mut self.solver, &self.neighbours, stage);
        // A second look: points the nodes left nearly planar do without them.
        let again = &mut self.vp_again;
        again.clear();
        vp.unjoin_ill_conditioned(changed, &mut self.solver, &mut self.neighbours, again);
        if !again.is_empty() {
            refit_changed(again, &mut self.solver, &self.neighbours, stage);
        }
    }

    /// Applies a re-cut of the incision still on its worker thread now, instead of at its
    /// tick (`RECUT_HANDOVER_TICKS` after it was asked for), and places every virtual point
    /// still waiting for its site: for the end of an offline run, so that its surface and
    /// nodes are the finished ones. Returns whether the surface changed.
    pub fn settle_incision(&mut self) -> bool {
        let (Some(tracker), Some(stage)) = (&mut self.incisions, &self.cutting) else {
            return false;
        };
        let remeshed = tracker.settle(
            &mut self.surface,
            &TrackerInputs::of(&self.solver, &self.grid, &stage.sigma),
        );
        self.place_virtual_points(remeshed, None, PlaceBudget::ALL);
        remeshed
    }

    /// The scene.
    pub fn spec(&self) -> &SceneSpec {
        &self.spec
    }

    /// Simulated time (s).
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// A 64-bit fingerprint of the state (FNV-1a over the exact bits of the time, every
    /// point's position and velocity, and the surface's vertices and triangles): two runs
    /// with the same inputs end with the same hash, bit for bit (the journal's replay
    /// checks this).
    pub fn state_hash(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |x: u64| {
            for b in x.to_le_bytes() {
                h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        eat(self.time_s.to_bits());
        for (p, v) in self.solver.positions().iter().zip(self.solver.velocities()) {
            p.iter().chain(v.iter()).for_each(|c| eat(c.to_bits()));
        }
        for x in &self.surface.mesh.positions {
            x.iter().for_each(|c| eat(c.to_bits()));
        }
        for t in &self.surface.mesh.triangles {
            t.iter().for_each(|&v| eat(u64::from(v)));
        }
        h
    }

    /// The surface as drawn now.
    pub fn surface(&self) -> &TriMesh {
        &self.surface.mesh
    }

    /// The current surface with its kinds and embedding.
    pub fn current_surface(&self) -> &CurrentSurface {
        &self.surface
    }

    /// The solver.
    pub fn solver(&self) -> &Solver {
        &self.solver
    }

    /// The neighbour lists as cut so far.
    pub fn neighbours(&self) -> &Neighbourhoods {
        &self.neighbours
    }

    /// The cutting stage, for scenes that cut.
    pub fn cutting(&self) -> Option<&CuttingStage> {
        self.cutting.as_ref()
    }

    /// The incisions so far, for scenes that cut.
    pub fn incisions(&self) -> Option<&IncisionStats> {
        self.incisions.as_ref().map(|t| &t.stats)
    }

    /// The virtual points, for cutting scenes that use them.
    pub fn virtual_points(&self) -> Option<&VirtualPoints> {
        self.virtual_points.as_ref()
    }

    /// The incision tracker, for scenes that cut.
    pub fn stroke_tracker(&self) -> Option<&StrokeTracker> {
        self.incisions.as_ref()
    }

    /// The stroke's re-cuts run on `runner` from now on (set before the first tick; without
    /// one they run on the simulation's own thread: [`InlineRecuts`]). A scene that does not
    /// cut has none to run.
    pub fn set_recut_runner(&mut self, runner: Box<dyn RecutRunner>) {
        if let Some(tracker) = &mut self.incisions {
            tracker.set_runner(runner);
        }
    }

    /// The force evaluations run their two parts in parallel on the caller's `pool` from
    /// now on, with the same results bit for bit ([`Solver::use_pool`]). A station's
    /// simulation thread is the pool's thread 0 (`use_current_thread`), so a tick hands
    /// nothing across threads but the parts' jobs.
    #[cfg(feature = "parallel")]
    pub fn use_pool(&mut self, pool: std::sync::Arc<rayon::ThreadPool>) {
        self.solver.use_pool(pool.clone());
        self.pool = Some(pool);
    }

    /// Whether the next tick may run on the pool (`use_pool`): its work is large enough
    /// ([`PARALLEL_MIN_WORK`]). It does unless the caller holds it to one thread
    /// (`set_sharing`).
    pub fn can_share_next_tick(&self) -> bool {
        #[cfg(feature = "parallel")]
        return self.pool.is_some() && self.last_work >= PARALLEL_MIN_WORK;
        #[cfg(not(feature = "parallel"))]
        false
    }

    /// Holds the ticks to the calling thread (`false`) or lets them share their work with
    /// the pool again (`true`, the default): the caller's choice from what it measures (a
    /// station whose worker is kept off its CPU waits for it). The same bits either way.
    pub fn set_sharing(&mut self, on: bool) {
        self.sharing = on;
    }

    /// The latest local force model for the haptic loop.
    pub fn local_force_model(&self) -> LocalForceModel {
        self.local_model
    }
}

/// The force scaled down (never distorted in direction) to at most `max_n`; NaN becomes zero.
fn bounded(force: &CutForce, max_n: f64) -> CutForce {
    let mut f = *force;
    let m = f.force_n.norm();
    if !m.is_finite() {
        f.force_n = Vec3::zeros();
        f.magnitude_n = 0.0;
        f.stiffness_matrix_n_per_m = crate::math::Mat3::zeros();
        f.stored_energy_j = 0.0;
    } else if m > max_n {
        let s = max_n / m;
        f.force_n *= s;
        f.magnitude_n *= s;
        f.stiffness_matrix_n_per_m *= s;
        f.stored_energy_j *= s;
    }
    f
}

/// Every topology change goes through here — pairs cut by Σ (the cutting stage), virtual
/// points released or placed: the points whose neighbour lists changed (`points`, unique)
/// get new MLS rows, and `wake` wakes each to relax to its new fit.
pub(crate) fn apply_topology(
    points: &[u32],
    solver: &mut Solver,
    neighbours: &Neighbourhoods,
    mut wake: impl FnMut(u32),
) {
    if points.is_empty() {
        return;
    }
    solver.topology_changed(points, neighbours);
    for &i in points {
        wake(i);
    }
}

/// The points whose neighbour lists virtual points changed (`changed`, any order, repeats)
/// through [`apply_topology`], sorted.
fn refit_changed(
    changed: &mut Vec<u32>,
    solver: &mut Solver,
    neighbours: &Neighbourhoods,
    stage: &mut CuttingStage,
) {
    changed.sort_unstable();
    changed.dedup();
    apply_topology(changed, solver, neighbours, |i| stage.wake_point(i));
}
