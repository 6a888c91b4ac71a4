//! A scripted cut, run tick by tick and measured: shared by `scalpel cut` and the cutting
//! benchmarks (Table 1, scaling).

use std::time::Instant;

use scalpel_sim::force::CutPhase;
use scalpel_sim::geometry::topology::check_surface;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{CutScript, Half, Simulation, Stage, StageClock};
use scalpel_sim::scene::BuiltScene;
use scalpel_sim::solver::{DivergenceReason, SolverEvent, SubstepKeepingMass, WholeStepMass};
use serde::Serialize;

use crate::wound_watch::{SurfaceWatch, lip_gap_m};

/// Time per tick (s): the haptic rate.
pub const TICK_S: f64 = scalpel_sim::pipeline::SIMULATION_TICK_S;

/// One tick of a run.
#[derive(Debug, Clone, Serialize)]
pub struct TickRow {
    /// Time at the end of the tick (s).
    pub t_s: f64,
    /// Blade tip (m).
    pub tip_m: [f64; 3],
    /// Distance the tip has travelled since the start (m).
    pub travel_m: f64,
    /// Force regime.
    pub phase: CutPhase,
    /// The blade is in the tissue.
    pub in_tissue: bool,
    /// Depth of the edge below the entry (m).
    pub depth_m: f64,
    /// Force on the tool (N).
    pub force_n: [f64; 3],
    /// Its magnitude (N).
    pub force_mag_n: f64,
    /// While pressing, what the eq. 19 loading curve the tissue's force replaced would
    /// have been (N): kept for comparison (docs/BENCHMARKS.md).
    pub formula_n: Option<f64>,
    /// The blade moves mostly across its edge (a stroke, not a plunge or pull-out).
    pub stroking: bool,
    /// Surface stage time (ms).
    pub surface_ms: f64,
    /// Internal stage time (ms).
    pub internal_ms: f64,
    /// Each stage's time (ms), in [`Stage::ALL`]'s order.
    pub stage_ms: [f64; Stage::ALL.len()],
    /// Points integrated.
    pub active_points: usize,
    /// The solver could not stabilise the tick (state restored, velocities zeroed).
    pub diverged: bool,
    /// Times the solver's guard rolled the tick back and retried it.
    pub rollbacks: u32,
    /// Explicit sub-steps of the tick's last attempt.
    pub substeps: u32,
    /// The sub-steps the explicit mode plans (what it relaxes back to).
    pub planned_substeps: u32,
    /// The crack front jumped by fracture this tick (`[force] fracture_by_energy`).
    pub fractured: bool,
    /// Re-cut work done on the worker for this tick (ms): the re-cuts that landed in it, as
    /// the worker timed them (0 with re-cuts inline, whose time is in `surface_ms`).
    pub recut_worker_ms: f64,
    /// While cutting, how far the blade's entry is from the drawn incision (mm, rest
    /// space): the nearest top of a wound's wall columns, or with no wound yet, where the
    /// stroke entered.
    pub lip_lag_mm: Option<f64>,
    /// When the drawn surface changed this tick (a re-cut landed, a wound deepened), how
    /// far what was drawn moved without the field moving it (mm; `wound_watch::Jump`).
    pub surface_jump_mm: Option<f64>,
    /// ... and how far from it new surface (walls growing with the crack) appeared (mm).
    pub surface_growth_mm: Option<f64>,
    /// While cutting, the lips' gap where the blade enters the tissue (mm, current
    /// positions, at the nearest wall column within a spacing; 0 where no wound is drawn
    /// there yet).
    pub gap_at_blade_mm: Option<f64>,
    /// The same where the blade's entry was a second earlier ...
    pub gap_after_1s_mm: Option<f64>,
    /// ... and two seconds earlier: at the default 5 mm/s, 10 mm behind the edge, past the
    /// blade's 8 mm width (a second behind, its flats still hold the lips apart).
    pub gap_after_2s_mm: Option<f64>,
}

/// Ticks in a second at 1 kHz: how far back `gap_after_1s_mm` looks.
const TICKS_PER_S: usize = 1000;

/// The wall clock the simulation times its stages with.
pub struct WallClock(Instant);

impl Default for WallClock {
    fn default() -> Self {
        Self(Instant::now())
    }
}

impl StageClock for WallClock {
    fn now_s(&mut self) -> f64 {
        self.0.elapsed().as_secs_f64()
    }
}

/// Why the solver's guard rolled ticks back or gave them up, over a run.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct GuardCounts {
    /// Attempts rolled back for a non-finite value ...
    pub non_finite: usize,
    /// ... for energy growing past the work put in ...
    pub energy_growth: usize,
    /// ... for a point moving more than 0.3 spacings in a sub-step.
    pub speed: usize,
    /// Ticks given up (restored, at rest).
    pub diverged: usize,
    /// The first tick rolled back or given up (0-based), if any.
    pub first_tick: Option<usize>,
}

impl GuardCounts {
    fn note(&mut self, tick: usize, event: &SolverEvent) {
        let reason = match event {
            SolverEvent::Rollback { reason, .. } => reason,
            SolverEvent::Diverged { .. } => {
                self.diverged += 1;
                self.first_tick.get_or_insert(tick);
                return;
            }
            _ => return,
        };
        self.first_tick.get_or_insert(tick);
        match reason {
            DivergenceReason::NonFinite => self.non_finite += 1,
            DivergenceReason::EnergyGrowth => self.energy_growth += 1,
            DivergenceReason::Speed => self.speed += 1,
        }
    }
}

/// The drawn surface at one tick of a run (current positions), kept for renders.
pub struct SurfaceSnapshot {
    /// The tick (0-based) it is the surface after.
    pub tick: usize,
    /// Skin and walls, no lids.
    pub mesh: scalpel_sim::geometry::TriMesh,
    /// What each triangle is.
    pub kinds: Vec<scalpel_sim::cut::FaceKind>,
}

/// A finished run.
pub struct CutRun {
    /// Every tick.
    pub rows: Vec<TickRow>,
    /// The drawn surface every `snapshot_every` ticks and after the last (none when 0).
    pub snapshots: Vec<SurfaceSnapshot>,
    /// The solver guard's rollbacks by reason.
    pub guard: GuardCounts,
    /// The simulation at the end.
    pub sim: Simulation,
}

/// Runs `script` on `scene` at 1 kHz; `tick` is told the progress (done, total). With
/// `threads` = 2 the run is on a thread of its own that joins a two-thread pool as a
/// station's simulation thread does (`scalpel_server::sim_pool`): the same bits, the
/// force evaluation's second part on the worker.
pub fn run_cut(
    scene: &BuiltScene,
    script: &CutScript,
    threads: usize,
    snapshot_every: usize,
    tick: impl FnMut(usize, usize) + Send,
) -> anyhow::Result<CutRun> {
    if threads <= 1 {
        return Ok(run_cut_here(scene, script, None, snapshot_every, tick));
    }
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("simulation".into())
            .spawn_scoped(scope, || {
                let plan = scalpel_server::sim_pool::PoolPlan {
                    threads,
                    worker_cpus: Vec::new(),
                    fifo_priority: 0,
                    nice: 0,
                };
                let pool = scalpel_server::sim_pool::join_new_pool(&plan, || {})
                    .map_err(anyhow::Error::msg)?;
                Ok(run_cut_here(
                    scene,
                    script,
                    pool.map(|p| p.pool),
                    snapshot_every,
                    tick,
                ))
            })?
            .join()
            .map_err(|_| anyhow::anyhow!("the cut's thread panicked"))?
    })
}

/// [`run_cut`] on the calling thread, with the pool it has joined (if any).
fn run_cut_here(
    scene: &BuiltScene,
    script: &CutScript,
    pool: Option<std::sync::Arc<rayon::ThreadPool>>,
    snapshot_every: usize,
    mut tick: impl FnMut(usize, usize),
) -> CutRun {
    let mut sim = Simulation::new(scene);
    // Re-cuts on a worker, as at a station (their time is the worker's, not the tick's).
    scalpel_server::recut_worker::attach(&mut sim);
    if let Some(pool) = pool {
        sim.use_pool(pool);
    }
    sim.prepare(TICK_S);
    let ticks = script.tick_count(TICK_S);
    let mut rows = Vec::with_capacity(ticks);
    let mut travel = 0.0;
    let mut last_tip: Option<Vec3> = None;
    let mut clock = WallClock::default();
    let worker_s = |sim: &Simulation| sim.incisions().map_or(0.0, |s| s.worker_s);
    let mut stroke_entry: Option<Vec3> = None;
    let mut guard = GuardCounts::default();
    let mut watch = SurfaceWatch::new(&sim);
    let mut snapshots = Vec::new();
    let keep = |k: usize, sim: &Simulation, snapshots: &mut Vec<SurfaceSnapshot>| {
        let (mesh, kinds) = sim.current_surface().drawn();
        snapshots.push(SurfaceSnapshot {
            tick: k,
            mesh,
            kinds,
        });
    };
    let mut entries: Vec<Option<Vec3>> = Vec::with_capacity(ticks);
    let spacing = scene.model.lattice.spacing;
    for k in 0..ticks {
        sim.handle_tool_pose(Some(script.pose_at(k as f64 * TICK_S)));
        let worker_before = worker_s(&sim);
        let report = sim.tick(TICK_S, &mut clock);
        while let Some(event) = sim.poll_event() {
            guard.note(k, &event);
        }
        // Where the blade went: a script's tip is checked against the blade's speed, but it
        // may turn faster than the blade follows.
        let pose = sim.blade_pose().expect("the tool was put");
        if let Some(last) = last_tip {
            travel += (pose.tip_m - last).norm();
        }
        last_tip = Some(pose.tip_m);
        let edge = pose.orientation * Vec3::z();
        let direction = sim.cutting().map_or(Vec3::zeros(), |c| c.direction());
        let cut = report.cut.as_ref();
        let entry_rest = cut
            .filter(|c| c.in_tissue && c.force.phase == CutPhase::Cutting)
            .and_then(|c| c.edge_rest)
            .map(|[_, entry]| entry);
        if cut.is_none_or(|c| !c.in_tissue) {
            stroke_entry = None;
        } else if stroke_entry.is_none() {
            stroke_entry = entry_rest;
        }
        let lip_lag_mm = entry_rest.map(|at| lip_lag(&sim, at, stroke_entry) * 1e3);
        let jump = watch.jump(&sim);
        // What the eye sees at that place: no wound drawn within a spacing is intact skin.
        let gap_mm = |at: Vec3| lip_gap_m(&sim, at, spacing).unwrap_or(0.0) * 1e3;
        let gap_at_blade_mm = entry_rest.map(gap_mm);
        let gap_after = |seconds: usize| {
            k.checked_sub(seconds * TICKS_PER_S)
                .and_then(|then| entries[then])
                .map(gap_mm)
        };
        let (gap_after_1s_mm, gap_after_2s_mm) = (gap_after(1), gap_after(2));
        entries.push(entry_rest);
        rows.push(TickRow {
            t_s: report.time_s,
            tip_m: pose.tip_m.into(),
            travel_m: travel,
            phase: cut.map_or(CutPhase::Free, |c| c.force.phase),
            in_tissue: cut.is_some_and(|c| c.in_tissue),
            depth_m: cut.map_or(0.0, |c| c.depth_m),
            force_n: report.tool_force_n.into(),
            force_mag_n: report.tool_force_n.norm(),
            formula_n: cut
                .filter(|c| c.force.phase == CutPhase::Loading)
                .map(|c| c.force.magnitude_n),
            stroking: direction.norm() > 0.0
                && direction.dot(&edge).abs() < 0.5
                && !cut.is_some_and(|c| c.withdrawing),
            surface_ms: report.stages.half(Half::Surface) * 1e3,
            internal_ms: report.stages.half(Half::Internal) * 1e3,
            stage_ms: Stage::ALL.map(|st| report.stages.of(st) * 1e3),
            active_points: report.active_points,
            diverged: report.solver.diverged,
            rollbacks: report.solver.rollbacks,
            substeps: report.solver.substeps,
            planned_substeps: sim.solver().planned_substeps(),
            fractured: cut.is_some_and(|c| c.fractured),
            recut_worker_ms: (worker_s(&sim) - worker_before) * 1e3,
            lip_lag_mm,
            surface_jump_mm: jump.map(|j| j.moved_m * 1e3),
            surface_growth_mm: jump.map(|j| j.grown_m * 1e3),
            gap_at_blade_mm,
            gap_after_1s_mm,
            gap_after_2s_mm,
        });
        if snapshot_every > 0 && k % snapshot_every == 0 {
            keep(k, &sim, &mut snapshots);
        }
        tick(k + 1, ticks);
    }
    // A script that ends within a re-cut's hand-over of the blade leaving: its output is
    // the finished incision (its worker time the last tick's).
    let worker_before = worker_s(&sim);
    sim.settle_incision();
    let settled_jump = watch.jump(&sim);
    if let Some(last) = rows.last_mut() {
        last.recut_worker_ms += (worker_s(&sim) - worker_before) * 1e3;
        if let Some(jump) = settled_jump {
            let most = |was: Option<f64>, now: f64| Some(was.map_or(now, |j| j.max(now)));
            last.surface_jump_mm = most(last.surface_jump_mm, jump.moved_m * 1e3);
            last.surface_growth_mm = most(last.surface_growth_mm, jump.grown_m * 1e3);
        }
    }
    if snapshot_every > 0 {
        keep(ticks.saturating_sub(1), &sim, &mut snapshots);
    }
    CutRun {
        rows,
        snapshots,
        guard,
        sim,
    }
}

/// How far `entry` (rest) is from the drawn incision: the nearest top of any wound's wall
/// columns, or with no wound yet, `stroke_entry` (m).
fn lip_lag(sim: &Simulation, entry: Vec3, stroke_entry: Option<Vec3>) -> f64 {
    let wounds = &sim.current_surface().wounds;
    let nearest = wounds
        .iter()
        .flat_map(|w| w.columns.iter())
        .map(|c| (c.top - entry).norm())
        .fold(f64::INFINITY, f64::min);
    if nearest.is_finite() {
        nearest
    } else {
        stroke_entry.map_or(0.0, |s| (s - entry).norm())
    }
}

pub use crate::stats::Quantiles;

/// The figures of a run (the JSON of `scalpel cut`).
#[derive(Debug, Clone, Serialize)]
pub struct CutMetrics {
    /// Ticks run.
    pub steps: usize,
    /// Ticks with the blade in the tissue: the "cut steps" the timings are taken over.
    pub cut_steps: usize,
    /// Surface stage per cut step (ms).
    pub surface_ms: Quantiles,
    /// Internal stage per cut step (ms).
    pub internal_ms: Quantiles,
    /// Both stages on the simulation's thread per cut step (ms).
    pub on_thread_ms: Quantiles,
    /// All of a cut step's work, like for like with the paper's single thread (ms): both
    /// stages plus the re-cut worker's time for the re-cuts that landed in the step.
    pub total_ms: Quantiles,
    /// The re-cut worker's time over the run (ms).
    pub recut_worker_ms: f64,
    /// All the work per cut step on average (ms): both stages and the worker's re-cuts,
    /// spread over the cut steps.
    pub work_per_cut_step_ms: f64,
    /// While stroking, how far the blade's entry is from the drawn incision (mm, rest):
    /// median and largest.
    pub lip_lag_mm: Option<LipLag>,
    /// Each stage of the tick (`Stage::name`), over the same ticks (ms).
    pub stages_ms: std::collections::BTreeMap<&'static str, Quantiles>,
    /// Largest turn between consecutive lip segments (degrees).
    pub lip_max_turn_deg: Option<f64>,
    /// Smallest angle of the remeshed triangles (degrees).
    pub min_angle_deg: Option<f64>,
    /// Deepest wound wall at the end (mm, along the wall's columns).
    pub wall_depth_mm: Option<f64>,
    /// Widest half-opening of a wound's lips in rest space at the end (mm): what the
    /// incision drew, before the field moved it.
    pub rest_opening_mm: Option<f64>,
    /// The lips' gap in the field (current positions, mm): where the blade enters and
    /// where it entered a second before, medians over the cutting ticks (0 where no wound
    /// is drawn yet).
    pub opening_mm: Option<Opening>,
    /// The largest jump of the drawn surface that the field did not make, over the run (mm):
    /// how far what was drawn moved when a re-cut landed (`wound_watch::Jump`).
    pub max_vertex_jump_mm: Option<f64>,
    /// The farthest from the drawn surface that new surface appeared in one frame (mm): a
    /// wound's walls growing with the crack, or a wound opened at once.
    pub max_surface_growth_mm: Option<f64>,
    /// Ticks in which the drawn surface jumped more than 0.5 mm (issue 41's bound).
    pub vertex_jumps_over_half_mm: usize,
    /// The drawn surface is closed at the end.
    pub closed: bool,
    /// ... and edge- and vertex-manifold.
    pub manifold: bool,
    /// ... and consistently oriented.
    pub oriented: bool,
    /// Largest force on the tool (N).
    pub peak_force_n: f64,
    /// Mean force while stroking after rupture (N).
    pub steady_force_n: f64,
    /// Ripple amplitude about the moving mean while stroking (N).
    pub ripple_n: f64,
    /// Depth while stroking, mean (mm).
    pub steady_depth_mm: f64,
    /// The steady force per millimetre of depth (N/mm): J_c's 0.19 on the liver plus the
    /// friction's share.
    pub steady_force_per_depth_n_per_mm: f64,
    /// The friction the force model adds at the steady depth (N): the share above.
    pub steady_friction_n: f64,
    /// The deformation–fracture cycles while stroking (fracture by energy only).
    pub sawtooth: Option<Sawtooth>,
    /// Incisions opened on the surface.
    pub incisions: usize,
    /// Incision runs refused (surface left as it was).
    pub incisions_refused: usize,
    /// Why the last refused run was refused.
    pub incision_refusal: Option<String>,
    /// Re-cuts not ready when due: ticks that waited for the re-cut worker (late ticks in
    /// a station; the run's results are the same either way).
    pub late_recuts: usize,
    /// Neighbour pairs the cut removed.
    pub pairs_removed: usize,
    /// Triangles of the cut surface Σ.
    pub sigma_triangles: usize,
    /// Most points integrated in any tick, and the total.
    pub max_active_points: usize,
    /// Points classified left and right of the blade plane (level set φ) along the cut.
    pub left_points: usize,
    /// See `left_points`.
    pub right_points: usize,
    /// Interior points.
    pub points: usize,
    /// Surface triangles before and after (drawn: skin and walls).
    pub triangles_before: usize,
    /// Drawn triangles at the end.
    pub triangles_after: usize,
    /// The solver diverged in some tick (state restored).
    pub diverged_ticks: usize,
    /// Ticks the solver's guard rolled back (and retried with more sub-steps).
    pub rollback_ticks: usize,
    /// The guard's rollbacks by reason, and the first tick it acted in.
    pub guard: GuardCounts,
    /// Most explicit sub-steps in one tick.
    pub substeps_max: u32,
    /// The mass floor the uncut body was given for whole sub-steps, if any.
    pub whole_step_mass: Option<WholeStepMass>,
    /// Mass given to cut points to keep the planned sub-steps through the cuts.
    pub substep_keeping_mass: SubstepKeepingMass,
}

/// The sub-steps per tick and, when the uncut body was given a mass floor for them or cut
/// points mass to keep them, how (one line's worth, for the reports).
pub fn describe_substeps(
    most: u32,
    floor: Option<&WholeStepMass>,
    kept: &SubstepKeepingMass,
) -> String {
    let mut line = format!("≤ {most} sub-step(s) per tick");
    if let Some(w) = floor {
        line += &format!(
            " (planned {} → {} by a mass floor of {:.2} of a lattice cell on {} points: +{:.2} g, {:.2} % of the body)",
            w.substeps_before,
            w.substeps_after,
            w.floor_of_cell,
            w.points,
            w.added_kg * 1e3,
            w.fraction * 100.0
        );
    }
    if kept.most_points > 0 {
        line += &format!(
            "; kept through the cuts by up to +{:.3} g on {} cut point(s) (+{:.3} g on {} at the end)",
            kept.most_kg * 1e3,
            kept.most_points,
            kept.added_kg * 1e3,
            kept.points
        );
    }
    line
}

/// How far the drawn incision trails the blade (mm).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct LipLag {
    /// Median over the steady stroke's ticks.
    pub p50: f64,
    /// Largest.
    pub max: f64,
}

/// The deformation–fracture cycles of a steady stroke (cutting-physics.md §3).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Sawtooth {
    /// Fracture events (runs of ticks the front jumped) per 10 mm of travel.
    pub drops_per_10mm: f64,
    /// Mean fall of the force at an event: the highest over the ticks before it to the
    /// lowest over the ticks after (N).
    pub mean_drop_n: f64,
    /// Mean slope of the force against travel from an event's low to the next event's
    /// high: the tissue's "local effective modulus" (N/mm).
    pub loading_slope_n_per_mm: f64,
}

/// The friction the scene's force model adds at `depth_m` (N).
fn friction_at(scene: &BuiltScene, depth_m: f64) -> f64 {
    scalpel_sim::force::CuttingForceModel::new(&scene.spec.force, false).friction(depth_m)
}

/// Ticks either side of a fracture event its high and low are looked for over.
const EVENT_TICKS: usize = 50;

/// The sawtooth of `steady` (rows in order), `None` without two fracture events.
fn sawtooth(steady: &[&TickRow]) -> Option<Sawtooth> {
    // Each event's first tick.
    let events: Vec<usize> = (0..steady.len())
        .filter(|&i| steady[i].fractured && (i == 0 || !steady[i - 1].fractured))
        .collect();
    if events.len() < 2 {
        return None;
    }
    let travel = steady.last()?.travel_m - steady.first()?.travel_m;
    let high = |i: usize| {
        let from = i.saturating_sub(EVENT_TICKS);
        (from..=i).max_by(|&a, &b| steady[a].force_mag_n.total_cmp(&steady[b].force_mag_n))
    };
    let low = |i: usize| {
        let to = (i + EVENT_TICKS).min(steady.len() - 1);
        (i..=to).min_by(|&a, &b| steady[a].force_mag_n.total_cmp(&steady[b].force_mag_n))
    };
    let (mut drops, mut slopes) = (Vec::new(), Vec::new());
    for (k, &e) in events.iter().enumerate() {
        let (Some(h), Some(l)) = (high(e), low(e)) else {
            continue;
        };
        drops.push(steady[h].force_mag_n - steady[l].force_mag_n);
        if let Some(next) = events.get(k + 1).and_then(|&n| high(n)).filter(|&n| n > l) {
            let rise = steady[next].force_mag_n - steady[l].force_mag_n;
            let run = (steady[next].travel_m - steady[l].travel_m) * 1e3;
            if run > 0.0 {
                slopes.push(rise / run);
            }
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    Some(Sawtooth {
        drops_per_10mm: events.len() as f64 / (travel / 0.01).max(1e-9),
        mean_drop_n: mean(&drops),
        loading_slope_n_per_mm: mean(&slopes),
    })
}

/// The lips' gap in the field (mm).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Opening {
    /// Where the blade enters, median over the cutting ticks.
    pub at_blade: Option<f64>,
    /// A second after the blade's entry passed, median ...
    pub after_1s: Option<f64>,
    /// ... and two seconds after.
    pub after_2s: Option<f64>,
}

/// The opening over `rows`, `None` when no tick measured it.
fn opening_of(rows: &[TickRow]) -> Option<Opening> {
    let median = |v: Vec<f64>| Quantiles::of(&v).map(|q| q.p50);
    let at_blade = median(rows.iter().filter_map(|r| r.gap_at_blade_mm).collect());
    let after_1s = median(rows.iter().filter_map(|r| r.gap_after_1s_mm).collect());
    let after_2s = median(rows.iter().filter_map(|r| r.gap_after_2s_mm).collect());
    (at_blade.is_some() || after_1s.is_some()).then_some(Opening {
        at_blade,
        after_1s,
        after_2s,
    })
}

/// The lip lag over `steady`, `None` when no tick measured it.
fn lip_lag_of(steady: &[&TickRow]) -> Option<LipLag> {
    let lags: Vec<f64> = steady.iter().filter_map(|r| r.lip_lag_mm).collect();
    let q = Quantiles::of(&lags)?;
    Some(LipLag {
        p50: q.p50,
        max: q.max,
    })
}

/// Metrics of a run; `wavelength_m` is the ripple wavelength (for the moving mean).
pub fn metrics(scene: &BuiltScene, run: &CutRun, wavelength_m: f64) -> CutMetrics {
    let cut_rows: Vec<&TickRow> = run.rows.iter().filter(|r| r.in_tissue).collect();
    let surface: Vec<f64> = cut_rows.iter().map(|r| r.surface_ms).collect();
    let internal: Vec<f64> = cut_rows.iter().map(|r| r.internal_ms).collect();
    let on_thread: Vec<f64> = cut_rows
        .iter()
        .map(|r| r.surface_ms + r.internal_ms)
        .collect();
    // Like for like with the paper's single thread: the re-cut worker's time is added to
    // the tick it landed in, as an inline re-cut would have cost it. Over every tick: a
    // re-cut may land after the blade has left.
    let worker_total: f64 = run.rows.iter().map(|r| r.recut_worker_ms).sum();
    let total: Vec<f64> = cut_rows
        .iter()
        .map(|r| r.surface_ms + r.internal_ms + r.recut_worker_ms)
        .collect();
    let work_per_cut_step =
        (on_thread.iter().sum::<f64>() + worker_total) / cut_rows.len().max(1) as f64;
    // Steady cutting: stroking after rupture, past the first wavelength.
    let rupture_travel = run
        .rows
        .iter()
        .find(|r| r.phase == CutPhase::Cutting)
        .map(|r| r.travel_m);
    let steady: Vec<&TickRow> = run
        .rows
        .iter()
        .filter(|r| {
            r.phase == CutPhase::Cutting
                && r.stroking
                && rupture_travel.is_some_and(|t0| r.travel_m > t0 + wavelength_m)
        })
        .collect();
    let mean = |v: &[f64]| {
        if v.is_empty() {
            0.0
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let steady_force = mean(&steady.iter().map(|r| r.force_mag_n).collect::<Vec<_>>());
    let steady_depth = mean(&steady.iter().map(|r| r.depth_m).collect::<Vec<_>>());
    // Ripple: RMS of the force about its moving mean over one wavelength of travel, as the
    // amplitude of a sine (× √2).
    let mut sq = 0.0;
    let mut lo = 0;
    let mut hi = 0;
    let mut window = 0.0;
    for (i, r) in steady.iter().enumerate() {
        while hi < steady.len() && steady[hi].travel_m <= r.travel_m + 0.5 * wavelength_m {
            window += steady[hi].force_mag_n;
            hi += 1;
        }
        while steady[lo].travel_m < r.travel_m - 0.5 * wavelength_m {
            window -= steady[lo].force_mag_n;
            lo += 1;
        }
        let local = window / (hi - lo) as f64;
        let _ = i;
        sq += (r.force_mag_n - local).powi(2);
    }
    let ripple = if steady.is_empty() {
        0.0
    } else {
        (sq / steady.len() as f64).sqrt() * std::f64::consts::SQRT_2
    };
    let sim = &run.sim;
    let (drawn, _) = sim.current_surface().drawn();
    let check = check_surface(&drawn.triangles, drawn.positions.len());
    let incisions = sim.incisions().cloned().unwrap_or_default();
    let opened = incisions.incisions > 0;
    CutMetrics {
        steps: run.rows.len(),
        cut_steps: cut_rows.len(),
        surface_ms: Quantiles::or_zero(&surface),
        internal_ms: Quantiles::or_zero(&internal),
        on_thread_ms: Quantiles::or_zero(&on_thread),
        total_ms: Quantiles::or_zero(&total),
        recut_worker_ms: worker_total,
        work_per_cut_step_ms: work_per_cut_step,
        lip_lag_mm: lip_lag_of(&steady),
        stages_ms: Stage::ALL
            .iter()
            .enumerate()
            .map(|(k, st)| {
                let v: Vec<f64> = cut_rows.iter().map(|r| r.stage_ms[k]).collect();
                (st.name(), Quantiles::or_zero(&v))
            })
            .collect(),
        lip_max_turn_deg: opened.then_some(incisions.lip_max_turn_deg),
        min_angle_deg: opened.then_some(incisions.min_angle_deg),
        wall_depth_mm: opened.then(|| {
            let wounds = &sim.current_surface().wounds;
            wounds.iter().map(|w| w.depth_m()).fold(0.0, f64::max) * 1e3
        }),
        rest_opening_mm: opened.then(|| {
            let wounds = &sim.current_surface().wounds;
            wounds.iter().map(|w| w.opening_m).fold(0.0, f64::max) * 1e3
        }),
        opening_mm: opening_of(&run.rows),
        max_vertex_jump_mm: run
            .rows
            .iter()
            .filter_map(|r| r.surface_jump_mm)
            .reduce(f64::max),
        max_surface_growth_mm: run
            .rows
            .iter()
            .filter_map(|r| r.surface_growth_mm)
            .reduce(f64::max),
        vertex_jumps_over_half_mm: run
            .rows
            .iter()
            .filter(|r| r.surface_jump_mm.is_some_and(|j| j > 0.5))
            .count(),
        closed: check.closed,
        manifold: check.manifold,
        oriented: check.oriented,
        peak_force_n: run.rows.iter().map(|r| r.force_mag_n).fold(0.0, f64::max),
        steady_force_n: steady_force,
        ripple_n: ripple,
        steady_depth_mm: steady_depth * 1e3,
        steady_force_per_depth_n_per_mm: if steady_depth > 0.0 {
            steady_force / (steady_depth * 1e3)
        } else {
            0.0
        },
        steady_friction_n: friction_at(scene, steady_depth),
        sawtooth: sawtooth(&steady),
        incisions: incisions.incisions,
        incisions_refused: incisions.refused,
        incision_refusal: incisions.last_refusal.clone(),
        late_recuts: incisions.late_recuts,
        pairs_removed: sim.cutting().map_or(0, |c| c.pairs_removed_total),
        sigma_triangles: sim.cutting().map_or(0, |c| c.sigma.triangles.len()),
        max_active_points: run.rows.iter().map(|r| r.active_points).max().unwrap_or(0),
        left_points: sim.cutting().map_or(0, |c| c.classification().left),
        right_points: sim.cutting().map_or(0, |c| c.classification().right),
        points: scene.model.points.len(),
        triangles_before: scene.model.surface.triangles.len(),
        triangles_after: drawn.triangles.len(),
        diverged_ticks: run.rows.iter().filter(|r| r.diverged).count(),
        rollback_ticks: run.rows.iter().filter(|r| r.rollbacks > 0).count(),
        guard: run.guard,
        substeps_max: run.rows.iter().map(|r| r.substeps).max().unwrap_or(0),
        whole_step_mass: sim.solver().whole_step_mass(),
        substep_keeping_mass: sim.solver().substep_keeping_mass(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(travel_m: f64, force: f64, fractured: bool) -> TickRow {
        TickRow {
            t_s: 0.0,
            tip_m: [0.0; 3],
            travel_m,
            phase: CutPhase::Cutting,
            in_tissue: true,
            depth_m: 0.01,
            force_n: [force, 0.0, 0.0],
            force_mag_n: force,
            formula_n: None,
            stroking: true,
            surface_ms: 0.0,
            internal_ms: 0.0,
            recut_worker_ms: 0.0,
            lip_lag_mm: None,
            surface_jump_mm: None,
            surface_growth_mm: None,
            gap_at_blade_mm: None,
            gap_after_1s_mm: None,
            gap_after_2s_mm: None,
            stage_ms: [0.0; Stage::ALL.len()],
            active_points: 0,
            diverged: false,
            rollbacks: 0,
            substeps: 1,
            planned_substeps: 1,
            fractured,
        }
    }

    /// A sawtooth loading at 0.5 N/mm from 1 to 2 N over 2 mm, falling back to 1 N at each
    /// fracture: 5 events per 10 mm, drops of 1 N, the slope 0.5 N/mm.
    #[test]
    fn the_guard_is_counted_by_reason_from_its_first_tick() {
        let mut g = GuardCounts::default();
        let rollback = |reason| SolverEvent::Rollback {
            tick: 0,
            reason,
            detected_at_substep: 0,
            substeps: 8,
        };
        g.note(
            3,
            &SolverEvent::TimeStep {
                tick: 0,
                dt_crit_s: 1e-3,
                substeps: 1,
            },
        );
        assert!(g.first_tick.is_none());
        g.note(7, &rollback(DivergenceReason::Speed));
        g.note(7, &rollback(DivergenceReason::Speed));
        g.note(9, &rollback(DivergenceReason::EnergyGrowth));
        g.note(
            9,
            &SolverEvent::Diverged {
                tick: 0,
                reason: DivergenceReason::NonFinite,
            },
        );
        assert_eq!(
            (
                g.speed,
                g.energy_growth,
                g.non_finite,
                g.diverged,
                g.first_tick
            ),
            (2, 1, 0, 1, Some(7))
        );
    }

    #[test]
    fn the_sawtooth_of_a_known_force() {
        let mut rows = Vec::new();
        for k in 0..4000 {
            let travel = k as f64 * 1e-5;
            let phase = k % 200;
            rows.push(row(travel, 1.0 + phase as f64 / 200.0, phase == 0 && k > 0));
        }
        let steady: Vec<&TickRow> = rows.iter().collect();
        let t = sawtooth(&steady).expect("events");
        assert!((t.drops_per_10mm - 19.0 / 4.0).abs() < 0.1, "{t:?}");
        assert!((t.mean_drop_n - 0.995).abs() < 0.01, "{t:?}");
        assert!((t.loading_slope_n_per_mm - 0.5).abs() < 0.01, "{t:?}");
        let none: Vec<&TickRow> = rows.iter().filter(|r| !r.fractured).collect();
        assert!(sawtooth(&none).is_none());
    }
}
