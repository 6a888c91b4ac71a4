//! One simulation tick, from the tool pose to the surface the renderers draw.
//!
//! ```text
//!   tool pose ─► surface contact (BVH on the current surface)          [surface]
//!             ─► cutting stage: force, Σ, visibility, affected region  [internal]
//!             ─► solver step on the awake points                       [internal]
//!             ─► surface follows the points that moved                 [surface]
//! ```
//!
//! Only what the scene uses is built: a scene without cutting has no cutting stage, no tool
//! contact and no force model, and integrates every point. Timing is the caller's business:
//! the pipeline reports stage boundaries to a [`StageObserver`] and never reads a clock.

pub mod blade_motion;
pub mod cutting;
pub mod incision;
pub mod recut;
pub mod script;
pub mod steady_motion;
pub mod surface;
pub mod virtual_points;

use crate::cut::{Blade, IncisionParams, ToolPose};
use crate::force::{CutForce, CutPhase, LocalForceModel};
use crate::geometry::TriMesh;
use crate::math::Vec3;
use crate::model::{Neighbourhoods, RestGrid};
use crate::scene::{BuiltScene, SceneSpec};
use crate::solver::{Solver, SolverConfig, StepReport};

pub use cutting::{Classification, CutTick, CuttingStage};
pub use incision::{IncisionStats, IncisionTracker};
pub use recut::{InlineRecuts, RECUT_HANDOVER_TICKS, RecutJob, RecutResult, RecutRunner};
pub use script::{CSV_HEADER, CutScript, Keyframe, ScriptError, vertical_extent};
pub use surface::{CurrentSurface, SurfaceContact};
pub use virtual_points::{VirtualPointStats, VirtualPoints};

/// Simulated time per simulation tick (s): the station's simulation thread runs at 1 kHz,
/// and the offline runs and the real-time sampling rule plan for the same tick.
pub const SIMULATION_TICK_S: f64 = 1e-3;

use incision::IncisionInputs;
use virtual_points::{PlacementInputs, VIRTUAL_NODE_CAPACITY};

/// Virtual points placed at most per tick after a re-mesh: each changes the MLS rows of the
/// dozen points it joins (instrumented on the cerebroma: 2.4 ms for the 19 a mid-stroke
/// re-mesh added, 7 ms for the 82 of the stroke's end), so they are spread over the ticks
/// that follow.
pub const NODES_PER_TICK: usize = 8;

/// The two halves of a tick that Table 1 of the paper reports separately.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// Surface work: blade contact, incision, vertices following the points.
    Surface,
    /// Interior work: force model, cut surface, visibility, MLS rows, integration.
    Internal,
}

/// Told when a stage starts and ends; the caller measures time with it.
pub trait StageObserver {
    /// `stage` starts.
    fn enter(&mut self, _stage: Stage) {}
    /// `stage` ends.
    fn leave(&mut self, _stage: Stage) {}
}

/// An observer that ignores everything.
#[derive(Debug, Default, Clone, Copy)]
pub struct Unobserved;

impl StageObserver for Unobserved {}

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
}

/// A running scene.
pub struct Simulation {
    spec: SceneSpec,
    solver: Solver,
    neighbours: Neighbourhoods,
    grid: RestGrid,
    surface: CurrentSurface,
    cutting: Option<CuttingStage>,
    incisions: Option<IncisionTracker>,
    virtual_points: Option<VirtualPoints>,
    /// Scratch for the points whose lists virtual points changed.
    vp_changed: Vec<u32>,
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
}

impl Simulation {
    /// Starts a built scene at rest.
    pub fn new(scene: &BuiltScene) -> Self {
        let spec = scene.spec.clone();
        let model = &scene.model;
        let config = SolverConfig::for_scene(&spec.features, &spec.material, &spec.solver);
        let n = model.points.len();
        // Virtual points are spare nodes after the body's points (virtual_points.rs).
        let spare = if spec.features.cutting && spec.features.virtual_points {
            VIRTUAL_NODE_CAPACITY
        } else {
            0
        };
        let neighbours = model.neighbours.with_spare_lists(spare);
        let mut solver = if spare > 0 {
            Solver::for_model_with_spare_nodes(model, &spec.material, config, &neighbours, spare)
        } else {
            Solver::for_model(model, &spec.material, config)
        };
        let virtual_points = (spare > 0)
            .then(|| VirtualPoints::new(n, spare, model.lattice.spacing, model.kernel.support_m));
        let cutting = spec.features.cutting.then(|| {
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
        }
        let incisions = spec.features.cutting.then(|| {
            IncisionTracker::new(
                model.surface.mean_edge_length(),
                IncisionParams::default(),
                model,
            )
        });
        Self {
            incisions,
            virtual_points,
            vp_changed: Vec::with_capacity(4096),
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
        }
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
    pub fn set_stiffness_factor(&mut self, factor: f64) {
        self.solver
            .set_youngs_modulus(self.spec.material.youngs_modulus_pa * factor);
        if let Some(stage) = &mut self.cutting {
            stage.set_stiffness_factor(factor);
        }
    }

    /// The tool's pose for the next tick; `None` takes the tool away, and so does a pose
    /// that is not [sound](ToolPose::is_sound) (the callers check theirs; a non-finite
    /// pose must not reach the contact and the force model whatever the caller). The blade
    /// follows it from where it was at most at [`blade_motion::MAX_BLADE_SPEED_M_PER_S`]; a
    /// tool taken away appears where it is next put (one dropped as unsound goes on from where
    /// it was).
    pub fn set_tool(&mut self, pose: Option<ToolPose>) {
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

    /// Advances by `dt` seconds.
    pub fn tick(&mut self, dt: f64, observer: &mut dyn StageObserver) -> TickReport {
        self.blade_pose = self.next_blade_pose(dt);
        if self.blade_pose.is_some() {
            self.resume_blade = None;
        }
        let blade = self
            .blade_pose
            .map(|pose| Blade::at(&pose, &self.spec.tool));
        let mut cut = None;
        let mut remeshed = false;
        if let Some(stage) = &mut self.cutting {
            observer.enter(Stage::Surface);
            let contact = match &blade {
                Some(b) => self.surface.contact(b),
                None => SurfaceContact::none(),
            };
            observer.leave(Stage::Surface);
            observer.enter(Stage::Internal);
            let tick = stage.advance(
                self.time_s + dt,
                blade.as_ref(),
                &contact,
                &self.surface,
                &mut self.solver,
                &mut self.neighbours,
                &self.grid,
            );
            if let (Some(vp), Some(edge)) = (&mut self.virtual_points, tick.edge_rest) {
                self.vp_changed.clear();
                vp.release_near(
                    &edge,
                    stage.affected_radius(),
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
            observer.leave(Stage::Internal);
            cut = Some(tick);
        }
        observer.enter(Stage::Internal);
        let solver = self.solver.step(dt);
        observer.leave(Stage::Internal);
        observer.enter(Stage::Surface);
        if let (Some(stage), Some(tick)) = (&self.cutting, &cut) {
            for t in tick.new_sigma.clone() {
                self.surface
                    .cut_embedding(&stage.sigma.triangles[t], self.solver.rest());
            }
            if let Some(tracker) = &mut self.incisions {
                let edge = tick
                    .edge_rest
                    .filter(|_| tick.force.phase == CutPhase::Cutting);
                remeshed = tracker.update(
                    edge,
                    stage.direction(),
                    tick.withdrawing,
                    tick.slit_rest,
                    &mut self.surface,
                    &IncisionInputs::of(&self.solver, &self.grid, &stage.sigma),
                );
            }
            self.place_virtual_points(remeshed, tick.edge_rest, NODES_PER_TICK);
        }
        let moved = if self.cutting.is_some() {
            self.solver.active_points()
        } else {
            &self.all_points
        };
        let vertices_moved = self.surface.follow(
            self.solver.operator(),
            self.solver.rest(),
            self.solver.positions(),
            moved,
        );
        observer.leave(Stage::Surface);
        self.time_s += dt;
        let tool_force_n = match (&cut, &blade) {
            (Some(t), Some(b)) => {
                // Free, the force's direction is zero and so is the model's stiffness.
                let force = bounded(&t.force, self.spec.force.max_force_n);
                self.local_model = force.local_model(b.tip);
                force.force_n
            }
            _ => Vec3::zeros(),
        };
        TickReport {
            time_s: self.time_s,
            cut,
            tool_force_n,
            // The body's points (virtual points are kinematic nodes, not integrated).
            active_points: {
                let body = self.solver.material_points() as u32;
                self.solver
                    .active_points()
                    .iter()
                    .filter(|&&i| i < body)
                    .count()
            },
            vertices_moved,
            remeshed,
            solver,
        }
    }

    /// Places virtual points on the walls of the surface, none within the affected radius
    /// of the blade's `edge`: after a re-mesh (`remeshed`) it first keeps, releases and
    /// chooses sites ([`VirtualPoints::remeshed`]), and either way places at most `limit`
    /// of the nodes still waiting ([`VirtualPoints::place_pending`]).
    fn place_virtual_points(&mut self, remeshed: bool, edge: Option<[Vec3; 2]>, limit: usize) {
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
                limit,
            );
        } else {
            vp.place_pending(
                &inputs,
                &mut self.solver,
                &mut self.neighbours,
                changed,
                limit,
            );
        }
        refit_changed(changed, &mut self.solver, &self.neighbours, stage);
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
            &IncisionInputs::of(&self.solver, &self.grid, &stage.sigma),
        );
        self.place_virtual_points(remeshed, None, usize::MAX);
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
    pub fn incision_tracker(&self) -> Option<&IncisionTracker> {
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
        f.stiffness_n_per_m = 0.0;
        f.stored_energy_j = 0.0;
    } else if m > max_n {
        let s = max_n / m;
        f.force_n *= s;
        f.magnitude_n *= s;
        f.stiffness_n_per_m *= s;
        f.stored_energy_j *= s;
    }
    f
}

/// The points whose neighbour lists virtual points changed (`changed`, any order, repeats)
/// get new MLS rows and are woken to relax to their new fits; nothing when none changed.
fn refit_changed(
    changed: &mut Vec<u32>,
    solver: &mut Solver,
    neighbours: &Neighbourhoods,
    stage: &mut CuttingStage,
) {
    if changed.is_empty() {
        return;
    }
    changed.sort_unstable();
    changed.dedup();
    solver.topology_changed(changed, neighbours);
    for &i in changed.iter() {
        stage.wake_point(i);
    }
}
