//! Time integration of the meshless body (physics.md §2).
//!
//! Four modes:
//! * **Explicit** (default): symplectic Euler with automatic sub-stepping. The stable step
//!   `dt_crit = 2/ω_max` comes from power iteration on M⁻¹K at run time (and again after a
//!   topology change); a tick of length `dt` takes `⌈dt / (safety·dt_crit)⌉` sub-steps.
//! * **Projective** (stiff mode): projective dynamics with a prefactored sparse Cholesky
//!   (see `projective`); stable at 1 ms ticks whatever the stiffness or ν.
//! * **Implicit**: one Newton step of backward Euler per tick over the awake region, a
//!   conjugate-gradient solve on the exact tangent (Jacobi-preconditioned by default) and a
//!   line search (see `implicit`); its iterations grow far more slowly than the explicit
//!   sub-steps as the lattice gets finer.
//! * **QuasiStatic**: every tick solves static equilibrium by Newton's method with
//!   preconditioned conjugate gradients; for validation.
//!
//! A guard watches every explicit sub-step (non-finite values, energy growth beyond the work
//! put in, speed). On divergence the tick is rolled back to its start and retried with twice
//! the sub-steps; if that keeps failing the start state is kept with velocities zeroed.
//! Positions that leave the solver are always finite.
//!
//! Call order: `new` → (`fix`, `set_external_force`, `set_target`)* → `step(dt)` per tick →
//! `poll_event` until `None`. `step` does not allocate after the first call.

pub mod blade;
pub mod contact;
mod contact_set;
mod crack_sink;
pub mod embedded;
pub mod events;
mod explicit;
pub mod held;
mod implicit;
mod implicit_coarse;
mod kept_substeps;
#[cfg(feature = "parallel")]
pub(crate) mod on_pool;
mod projective;
mod projective_contact;
mod slaves;
mod state;
mod statics;
mod timestep;
mod topology;
mod whole_substeps;

use serde::Serialize;

pub use events::{DivergenceReason, EventQueue, SolverEvent, StepReport};
pub use implicit::ImplicitPreconditioner;
pub use kept_substeps::SubstepKeepingMass;
pub use statics::StaticReport;
pub use whole_substeps::WholeStepMass;

use crate::math::{Mat3, Vec3};
use crate::mls::Prestress;
use crate::mls::forces::{EvalSet, ForceScratch, ForceStats, Threads, add_elastic_forces};
use crate::mls::operator::{LatticeOffsets, PointRank, RankCounts};
use crate::mls::{ElasticModel, ElasticParams, Lame, MlsOperator};
use crate::model::{CoupledModel, Kernel, Neighbourhoods};
use crate::scene::Material;
use slaves::Slaves;

/// How ticks are integrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolverMode {
    /// Symplectic Euler with sub-steps from dt_crit.
    #[default]
    Explicit,
    /// Projective dynamics (stiff materials).
    Projective,
    /// Static equilibrium each tick.
    QuasiStatic,
    /// Linearly implicit Euler, one preconditioned CG solve per tick (see `implicit`).
    Implicit,
}

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SolverConfig {
    /// Integration mode.
    pub mode: SolverMode,
    /// Constitutive law.
    pub model: ElasticModel,
    /// Hourglass coefficient α.
    pub hourglass_alpha: f64,
    /// Volume-term stiffness k_v (Pa), 0 for none.
    pub volume_k_pa: f64,
    /// Clamp F's singular values to [0.2, 5] when det F leaves that range (inversion
    /// fallback, physics.md §2.5). On by default.
    pub clamp_inversion: bool,
    /// Strain-stiffening β of the material (`ElasticParams::stiffening`).
    pub stiffening: f64,
    /// Mass-proportional damping γ (1/s).
    pub damping_per_s: f64,
    /// Gravity (m/s²).
    pub gravity: Vec3,
    /// Explicit sub-step as a fraction of dt_crit (physics.md §2.2 recommends 0.5).
    pub safety: f64,
    /// Force this explicit sub-step (s) instead of the computed one (the guard still acts).
    pub dt_override_s: Option<f64>,
    /// Rollbacks allowed per tick before giving up. Each doubles the sub-steps, so five
    /// reach 32× the planned count (enough for a step ten times dt_crit, the stability
    /// matrix's case) at a worst-case cost of 63× a tick's; a blow-up that persists past
    /// that is no time-step problem, and more doublings only stall the simulation thread
    /// (ten reached 65 536 sub-steps: 3.8 s for one tick of the liver, docs/CUTTING.md).
    pub max_rollbacks: u32,
    /// Power iterations for ω_max.
    pub power_iterations: u32,
    /// Mass the body may be given (a fraction of its own) so that ticks take a whole
    /// sub-step fewer (see `whole_substeps`) and keep that count through cuts (see
    /// `kept_substeps`); 0 for none.
    pub mass_scaling_budget: f64,
    /// Local/global iterations per projective step.
    pub projective_iterations: u32,
    /// Relative residual at which a static solve stops.
    pub static_tolerance: f64,
    /// The implicit mode's preconditioner.
    pub implicit_preconditioner: ImplicitPreconditioner,
    /// The implicit mode's CG stops when the step's error energy is within this squared of
    /// the tick's kinetic or stored energy, whichever is larger (see `implicit`).
    pub implicit_tolerance: f64,
    /// Most CG iterations an implicit tick takes.
    pub implicit_max_iterations: u32,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            mode: SolverMode::Explicit,
            model: ElasticModel::StVK,
            // Low end of physics.md's 0.05–0.1: α = 0.1 makes a 5-points-across beam 2.5 %
            // stiffer in bending (see docs/BENCHMARKS.md); 0.05 still stops checkerboards.
            hourglass_alpha: 0.05,
            volume_k_pa: 0.0,
            clamp_inversion: true,
            stiffening: 0.0,
            damping_per_s: 10.0,
            gravity: Vec3::zeros(),
            safety: 0.5,
            dt_override_s: None,
            max_rollbacks: 5,
            power_iterations: 30,
            mass_scaling_budget: 0.01,
            projective_iterations: 10,
            static_tolerance: 1e-9,
            implicit_preconditioner: ImplicitPreconditioner::Jacobi,
            implicit_tolerance: 3e-4,
            implicit_max_iterations: 200,
        }
    }
}

impl SolverConfig {
    /// The configuration a scene asks for: projective dynamics when it declares `stiff_mode`,
    /// else its `[solver] integrator`,
    /// Müller's volume term (k_v = λ, the upper end physics.md §1.8 recommends) when it
    /// declares `volume_term`, the material's damping, its mass scaling budget; everything
    /// else default.
    pub fn for_scene(
        features: &crate::scene::Features,
        material: &Material,
        solver: &crate::scene::SolverSpec,
    ) -> Self {
        let lame = Lame::from_young_poisson(material.youngs_modulus_pa, material.poisson_ratio);
        Self {
            mode: match (features.stiff_mode, solver.integrator) {
                (true, _) => SolverMode::Projective,
                (false, crate::scene::Integrator::Explicit) => SolverMode::Explicit,
                (false, crate::scene::Integrator::Implicit) => SolverMode::Implicit,
            },
            volume_k_pa: if features.volume_term {
                lame.lambda
            } else {
                0.0
            },
            damping_per_s: material.damping_per_s,
            stiffening: material.stiffening,
            mass_scaling_budget: solver.mass_scaling_budget,
            ..Self::default()
        }
    }
}

/// Most sub-steps a tick may take.
pub const MAX_SUBSTEPS: u32 = 1 << 16;

/// After a cut, no point's fit may raise its ω² estimate above this many times the largest
/// in the uncut body: the points of a fit the cut left degenerate get mass instead (see
/// [`Solver::topology_changed`]). 2 lets a cut shorten the stable step by up to √2.
pub const OMEGA_SQ_CAP_OVER_UNCUT: f64 = 2.0;

/// The simulated body and everything needed to advance it.
pub struct Solver {
    /// The caller's pool for the force evaluation's halves (`use_pool`).
    #[cfg(feature = "parallel")]
    pool: Option<std::sync::Arc<rayon::ThreadPool>>,
    config: SolverConfig,
    params: ElasticParams,
    op: MlsOperator,
    kernel: Kernel,
    spacing_m: f64,
    rest: Vec<Vec3>,
    volume: Vec<f64>,
    mass: Vec<f64>,
    /// The masses as built; `mass` is at least these (selective mass scaling after cuts).
    base_mass: Vec<f64>,
    /// Per point: the ω² its own fit (row) gives the points in it, with their built masses
    /// (see `fit_omega_sq_of`); filled with the first dt_crit. Over the cap with slaved
    /// nodes in it, raised to leave their masters' terms their share (`topology_changed`).
    fit_omega_sq: Vec<f64>,
    /// The largest fit ω² a cut may leave before mass is added (set with the first dt_crit).
    omega_sq_cap: Option<f64>,
    /// Whether the uncut body's masses were (or can no longer be) scaled to whole sub-steps.
    whole_steps_tried: bool,
    /// What that scaling added.
    whole_step_mass: Option<WholeStepMass>,
    /// Mass given to cut points to keep the planned sub-steps (`kept_substeps`).
    kept: kept_substeps::KeptSubsteps,
    /// Per point: the ω² a fit over the cap asks of it through the slaved nodes it masters
    /// (a slaved node's forces are handed back to its masters), 0 for none; the points
    /// with one listed in `through_slaves_list`.
    through_slaves: Vec<f64>,
    through_slaves_list: Vec<u32>,
    p: Vec<Vec3>,
    v: Vec<Vec3>,
    fixed: Vec<[bool; 3]>,
    target: Vec<Vec3>,
    external: Vec<Vec3>,
    /// What holds the body through its surface (attachments, a tray); `None` for nothing.
    held: Option<held::Held>,
    /// The held vertices' forces on the points, this sub-step (zero where none reach).
    held_force: Vec<Vec3>,
    /// A rigid tool pressed into the body (static solves), if any.
    contact: Option<contact::ToolContact>,
    /// The tool's forces on the points (zero where no sample reaches).
    contact_force: Vec<Vec3>,
    /// The blade as a kinematic body in the explicit tick, for scenes that cut.
    blade: Option<blade::BladeBody>,
    /// The blade's lips' forces on the points, this sub-step (zero where none reach).
    lip_force: Vec<Vec3>,
    /// What the crack takes from the tissue when its front jumps.
    crack_sink: crack_sink::CrackSink,
    /// Residual tension in the surface layer (`[material] prestrain`); empty for none.
    prestress: Prestress,
    force: Vec<Vec3>,
    force_scratch: ForceScratch,
    /// Points the explicit mode integrates (all, unless `set_active` restricted them).
    active_list: Vec<u32>,
    /// The previous active list while a new one is set (buffer reuse).
    retired: Vec<u32>,
    /// The active points with a fixed dof, listed for a tick's sub-steps (room for every
    /// point: filled without allocating).
    fixed_active: Vec<u32>,
    is_active: Vec<bool>,
    /// Evaluation set for a restricted active list; `None` when every point is active.
    eval_set: Option<EvalSet>,
    snap_p: Vec<Vec3>,
    snap_v: Vec<Vec3>,
    scratch: [Vec<Vec3>; 5],
    precond: Vec<f64>,
    dt_crit: Option<f64>,
    substeps: u32,
    planned_substeps: u32,
    calm_ticks: u32,
    /// The material's stiffening: the largest factor on a point's tangent at the last tick,
    /// and at the last estimate of dt_crit (1: none).
    max_stiffening: f64,
    stiffening_at_estimate: f64,
    substeps_for_dt: f64,
    /// λ_max(M⁻¹K) / max_i(D_i/m_i) at the last power iteration: turns the local diagonal
    /// bound into a ω² estimate after cuts.
    omega_calibration: Option<f64>,
    touched_buf: Vec<u32>,
    touched_flag: Vec<bool>,
    events: EventQueue,
    tick: u64,
    clamping: bool,
    last: StepReport,
    last_stats: Option<ForceStats>,
    projective: Option<projective::Projective>,
    implicit: Option<implicit::Implicit>,
    /// Points of the body; nodes after them (virtual points) are kinematic.
    material_points: usize,
    /// Spare nodes tied to body points (virtual points, see `slaves`).
    slaves: Slaves,
    /// The active list and the slaved nodes next to it: what the evaluation set is built
    /// for (a slaved node's fits must all be evaluated for the force it hands back).
    eval_seed: Vec<u32>,
}

impl Solver {
    /// A solver for a built model with a scene material.
    pub fn for_model(model: &CoupledModel, material: &Material, config: SolverConfig) -> Self {
        Self::for_model_with_spare_nodes(model, material, config, &model.neighbours, 0)
    }

    /// A solver for `model` with `spare` nodes after its points, for virtual points
    /// (physics.md §5.3): without volume (no stress of their own), never integrated, and
    /// nobody's neighbour until tied to body points with [`Solver::slave_node`].
    /// `neighbours` must be the model's lists with `spare` empty lists after them.
    pub fn for_model_with_spare_nodes(
        model: &CoupledModel,
        material: &Material,
        config: SolverConfig,
        neighbours: &Neighbourhoods,
        spare: usize,
    ) -> Self {
        let mut config = config;
        config.damping_per_s = material.damping_per_s;
        let n = model.points.len();
        assert_eq!(
            neighbours.len(),
            n + spare,
            "neighbour lists for the spare nodes"
        );
        let centre = model.points.rest.iter().sum::<Vec3>() / n.max(1) as f64;
        let mean_mass = model.points.mass_kg.iter().sum::<f64>() / n.max(1) as f64;
        let mut rest = model.points.rest.clone();
        rest.resize(n + spare, centre);
        let mut volume = model.points.volume_m3.clone();
        volume.resize(n + spare, 0.0);
        let mut mass = model.points.mass_kg.clone();
        // Never integrated (all dofs fixed); a mass keeps M⁻¹ finite where it appears.
        mass.resize(n + spare, mean_mass);
        let mut solver = Self::new(
            &rest,
            &volume,
            &mass,
            neighbours,
            model.kernel,
            model.lattice.spacing,
            Some(LatticeOffsets {
                coords: model.points.lattice_coords.clone(),
                spacing: model.lattice.spacing,
            }),
            material.youngs_modulus_pa,
            material.poisson_ratio,
            config,
        );
        for i in n..n + spare {
            solver.fixed[i] = [true; 3];
        }
        solver.material_points = n;
        solver.slaves = Slaves::new(n, spare, neighbours.capacity());
        solver
    }

    /// The body points spare node `i` is slaved to (none when it is free).
    pub fn masters_of(&self, i: usize) -> impl Iterator<Item = u32> + '_ {
        self.slaves.masters_of(i).iter().map(|&(k, _)| k)
    }

    /// Puts spare node `i` at `rest` and ties it to the body points `masters` (its
    /// neighbours, which are the caller's: then [`Solver::topology_changed`]): in every
    /// sub-step its displacement is the MLS interpolation of theirs at `rest` (linear
    /// precision, or their kernel-weighted mean where that extrapolates), and the force on
    /// it goes back to them (`slaves`). Returns false, leaving the node free, if no master
    /// is within the support of `rest`.
    pub fn slave_node(&mut self, i: usize, rest: Vec3, masters: &[u32]) -> bool {
        assert!(
            i >= self.material_points,
            "point {i} is material, not a spare node"
        );
        assert!(
            masters.iter().all(|&k| (k as usize) < self.material_points),
            "node {i} slaved to a node"
        );
        if !self
            .slaves
            .fit(i, rest, masters, &mut self.rest, &self.kernel)
        {
            return false;
        }
        self.v[i] = Vec3::zeros();
        self.fixed[i] = [true; 3];
        self.slaves.interpolate(&mut self.p);
        self.target[i] = self.p[i];
        if std::mem::replace(&mut self.is_active[i], false) {
            self.active_list.retain(|&a| a as usize != i);
        }
        true
    }

    /// Unties spare node `i` (after its neighbour pairs are gone); it stays where it is.
    pub fn free_node(&mut self, i: usize) {
        self.slaves.free(i);
    }

    /// Points of the body (the nodes after them are virtual).
    pub fn material_points(&self) -> usize {
        self.material_points
    }

    /// Rank classes of the body's points (virtual nodes left out).
    pub fn rank_counts(&self) -> RankCounts {
        self.op.rank_counts_of(0..self.material_points)
    }

    /// A solver for points at `rest` with volumes (m³), masses (kg) and neighbour lists;
    /// `lattice` (when the points come from one) makes rest offsets exact.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        rest: &[Vec3],
        volume: &[f64],
        mass: &[f64],
        neighbours: &Neighbourhoods,
        kernel: Kernel,
        spacing_m: f64,
        lattice: Option<LatticeOffsets>,
        youngs_modulus_pa: f64,
        poisson_ratio: f64,
        config: SolverConfig,
    ) -> Self {
        let n = rest.len();
        let params = ElasticParams {
            model: config.model,
            lame: Lame::from_young_poisson(youngs_modulus_pa, poisson_ratio),
            youngs_modulus_pa,
            hourglass_alpha: config.hourglass_alpha,
            volume_k: config.volume_k_pa,
            clamp_inversion: config.clamp_inversion,
            stiffening: config.stiffening,
        };
        let op = MlsOperator::build(rest, neighbours, &kernel, lattice);
        let zeros = vec![Vec3::zeros(); n];
        let mut solver = Self {
            config,
            params,
            op,
            kernel,
            spacing_m,
            rest: rest.to_vec(),
            volume: volume.to_vec(),
            mass: mass.to_vec(),
            base_mass: mass.to_vec(),
            fit_omega_sq: Vec::new(),
            omega_sq_cap: None,
            whole_steps_tried: false,
            whole_step_mass: None,
            kept: Default::default(),
            through_slaves: vec![0.0; n],
            through_slaves_list: Vec::with_capacity(n),
            p: rest.to_vec(),
            v: zeros.clone(),
            fixed: vec![[false; 3]; n],
            target: rest.to_vec(),
            external: zeros.clone(),
            held: None,
            held_force: zeros.clone(),
            contact: None,
            contact_force: zeros.clone(),
            blade: None,
            lip_force: zeros.clone(),
            crack_sink: crack_sink::CrackSink::with_room(n),
            prestress: Prestress::default(),
            force: zeros.clone(),
            force_scratch: ForceScratch::new(n).with_threads(Threads::One),
            #[cfg(feature = "parallel")]
            pool: None,
            active_list: (0..n as u32).collect(),
            retired: Vec::with_capacity(n),
            fixed_active: Vec::with_capacity(n),
            is_active: vec![true; n],
            eval_set: None,
            snap_p: zeros.clone(),
            snap_v: zeros.clone(),
            scratch: [
                zeros.clone(),
                zeros.clone(),
                zeros.clone(),
                zeros.clone(),
                zeros,
            ],
            precond: vec![0.0; n],
            dt_crit: None,
            substeps: 1,
            planned_substeps: 1,
            calm_ticks: 0,
            max_stiffening: 1.0,
            stiffening_at_estimate: 1.0,
            substeps_for_dt: 0.0,
            omega_calibration: None,
            // Each point at most once (flagged): never more than n.
            touched_buf: Vec::with_capacity(n),
            touched_flag: vec![false; n],
            events: EventQueue::default(),
            tick: 0,
            clamping: false,
            last: StepReport::default(),
            last_stats: None,
            projective: None,
            implicit: None,
            material_points: n,
            slaves: Slaves::default(),
            eval_seed: Vec::with_capacity(n),
        };
        solver.precond = statics::diagonal_stiffness(&solver.op, &solver.params, &solver.volume);
        solver.force_scratch.fit_to(&solver.op);
        solver
    }

    /// Plans ticks of `dt` now — the stable step, and on the uncut body the mass scaling to
    /// whole sub-steps (`whole_substeps`); in the implicit mode its preconditioner — so that
    /// the first tick does not pay for their power iterations or factor (tens of
    /// milliseconds each at organ scale). Optional: the first tick does it otherwise.
    pub fn prepare(&mut self, dt: f64) {
        match self.config.mode {
            SolverMode::Explicit => self.plan_substeps(dt),
            SolverMode::Implicit => self.prepare_implicit(dt),
            _ => {}
        }
    }

    /// Advances one tick of `dt` seconds. Never fails: trouble is reported in the returned
    /// report and as events, and the state stays finite.
    pub fn step(&mut self, dt: f64) -> StepReport {
        #[cfg(feature = "parallel")]
        if let Some(pool) = self.pool.clone()
            && self.force_scratch.threads() == Threads::Rayon
            && pool.current_thread_index().is_none()
        {
            // Called from outside the pool: the tick is handed in (`on_pool`). On a thread
            // of the pool (a station's simulation thread, inside `Simulation::tick`'s own
            // `on_pool`) it runs here and its joins find the pool.
            return on_pool::on_pool(&pool, || self.step_here(dt));
        }
        self.step_here(dt)
    }

    /// The explicit force evaluation's two halves run in parallel on `pool` from now on,
    /// with the same results bit for bit (the halves are summed the same way either way).
    /// The pool is the caller's: the core makes none. Called from outside the pool (offline
    /// runs, benches) a tick is handed into it; a station's simulation thread is itself the
    /// pool's thread 0 (`scalpel_server::sim_pool`), so its ticks run where they are called
    /// and only the second part's job crosses to the worker.
    #[cfg(feature = "parallel")]
    pub fn use_pool(&mut self, pool: std::sync::Arc<rayon::ThreadPool>) {
        self.pool = Some(pool);
        self.force_scratch.set_threads(Threads::Rayon);
    }

    /// Whether the next ticks use the pool given (`use_pool`): a tick too small to share
    /// runs on its caller's thread alone. The same bits either way.
    #[cfg(feature = "parallel")]
    pub fn set_parallel(&mut self, on: bool) {
        let threads = if on && self.pool.is_some() {
            Threads::Rayon
        } else {
            Threads::One
        };
        self.force_scratch.set_threads(threads);
    }

    fn step_here(&mut self, dt: f64) -> StepReport {
        self.tick += 1;
        let report = match self.config.mode {
            SolverMode::Explicit => self.tick_explicit(dt),
            SolverMode::Projective => self.tick_projective(dt),
            SolverMode::Implicit => self.tick_implicit(dt),
            SolverMode::QuasiStatic => {
                let r = self.solve_static();
                StepReport {
                    substeps: 1,
                    dt_sub_s: dt,
                    iterations: r.newton_iterations,
                    elastic_energy: r.elastic_energy,
                    diverged: !r.converged,
                    min_det_f: self.last_stats.map_or(1.0, |s| s.min_det_f),
                    ..StepReport::default()
                }
            }
        };
        self.last = report;
        report
    }

    /// The oldest unread event.
    #[must_use]
    pub fn poll_event(&mut self) -> Option<SolverEvent> {
        self.events.pop()
    }
}

/// Where [`Solver::evaluate_elastic`] writes the forces.
#[derive(Debug, Clone, Copy)]
enum ForceBuffer {
    /// The solver's force buffer.
    Force,
    /// One of the scratch buffers.
    Scratch(usize),
}

impl Solver {
    /// Zeroes the buffer and fills it with the elastic forces at the current positions.
    fn evaluate_elastic(&mut self, into: ForceBuffer) -> ForceStats {
        // Slaved nodes where their masters are now; their forces go back to them below.
        self.slaves.interpolate(&mut self.p);
        let out = match into {
            ForceBuffer::Force => &mut self.force,
            ForceBuffer::Scratch(k) => &mut self.scratch[k],
        };
        // With a restricted active set the explicit and implicit modes evaluate locally; the
        // other modes work on the whole body.
        let set = match self.config.mode {
            SolverMode::Explicit | SolverMode::Implicit => self.eval_set.as_ref(),
            _ => None,
        };
        match set {
            Some(s) => s
                .touched
                .iter()
                .for_each(|&i| out[i as usize] = Vec3::zeros()),
            None => out.iter_mut().for_each(|f| *f = Vec3::zeros()),
        }
        let mut evaluate = || {
            add_elastic_forces(
                &self.op,
                &self.params,
                &self.volume,
                Some(&self.prestress),
                &self.p,
                set,
                out,
                &mut self.force_scratch,
            )
        };
        #[cfg(feature = "parallel")]
        let stats = match &self.pool {
            // Called from outside a tick (a static solve, `elastic_forces`): into the
            // caller's pool, not rayon's global one.
            Some(pool) if pool.current_thread_index().is_none() => pool.install(evaluate),
            _ => evaluate(),
        };
        #[cfg(not(feature = "parallel"))]
        let stats = evaluate();
        self.slaves.hand_back(out);
        stats
    }
}

fn kinetic_energy(mass: &[f64], v: &[Vec3], fixed: &[[bool; 3]]) -> f64 {
    let mut e = 0.0;
    for i in 0..mass.len() {
        for a in 0..3 {
            if !fixed[i][a] {
                e += 0.5 * mass[i] * v[i][a] * v[i][a];
            }
        }
    }
    e
}

#[cfg(test)]
pub(super) mod test_support {
    use super::Solver;
    use crate::math::Vec3;

    /// Mass scaling changes inertia only: the two solvers give the same elastic forces,
    /// bit for bit, at a bent state of `rest`.
    pub fn assert_same_stiffness(a: &mut Solver, b: &mut Solver, rest: &[Vec3]) {
        let bent: Vec<Vec3> = (rest.iter())
            .map(|x| x + Vec3::new(0.02 * x.z, 0.0, -0.03 * x.x))
            .collect();
        a.set_positions(&bent);
        b.set_positions(&bent);
        assert_eq!(a.elastic_forces().0, b.elastic_forces().0);
    }

    /// From rest, point `at` pushed for 20 ticks of `dt` and let go for 180: every tick
    /// takes `substeps` sub-steps, with no rollback.
    pub fn assert_rings_down_at(s: &mut Solver, rest: &[Vec3], at: usize, dt: f64, substeps: u32) {
        s.set_positions(rest);
        s.set_external_force(at, Vec3::new(0.0, 0.0, -1e-3));
        for tick in 0..200 {
            if tick == 20 {
                s.clear_external_forces();
            }
            let report = s.step(dt);
            assert!(!report.diverged, "tick {tick}");
            assert_eq!(
                (report.rollbacks, report.substeps),
                (0, substeps),
                "tick {tick}"
            );
        }
    }
}

#[cfg(test)]
mod tests;
