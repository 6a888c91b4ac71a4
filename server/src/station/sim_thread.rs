//! The simulation thread: [`spawn_sim`] ticks the simulation on the station's 1 ms grid,
//! woken by the haptic thread, with the latest pose; it sends render frames, journals each
//! tick's input, and hands the local force model to the haptic thread and its figures to the
//! main thread. Also how it is scheduled ([`SimThread`]) and framed ([`SimFrames`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::thread::JoinHandle;

use scalpel_sim::force::CutPhase;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{Simulation, StageClock, TickReport};

use crate::faults::FaultTable;
use crate::grid_clock::GridClock;
use crate::journal::TickRecord;
use crate::realtime;
use crate::render_frames::{FrameInfo, FramePublisher};
use crate::sim_pool::{self, PoolPlan};
use crate::sim_wake::SimWake;

use super::journal_writer::SimJournal;
use super::sharing::SharingChooser;
use super::{ModelUpdate, PoseIn, SIM_TICK_S, SimStatus, station_tick};

/// The simulation thread ticks on the same 1 ms grid as the haptic thread, woken by it once
/// its tick is done (`sim_wake`), so that it takes the pose the haptic thread has just read
/// (and the frame it sends shows it) instead of one up to a millisecond old; at the latest
/// it ticks this long after the grid point (a late haptic thread, or none).
const SIM_PHASE_S: f64 = 1e-4;

/// What the frame sent before a tick reports of the tick before it.
#[derive(Debug, Clone, Copy, Default)]
struct LastTick {
    force_n: Vec3,
    cutting: bool,
    in_tissue: bool,
}

/// The simulation's figures as its thread counts them, tick by tick.
#[derive(Default)]
struct Counted {
    figures: SimStatus,
    last_tip: Option<Vec3>,
    last: LastTick,
}

impl Counted {
    /// Counts a tick (`report`), the blade's tip after it and how long it took.
    fn record(&mut self, report: &TickReport, tip: Option<Vec3>, took_ms: f64, cpu_ms: f64) {
        let figures = &mut self.figures;
        let cutting = report
            .cut
            .as_ref()
            .is_some_and(|c| c.in_tissue && c.force.phase == CutPhase::Cutting);
        // Where the blade went (a pose faster than a hand is followed at a hand's speed: the
        // cut is as long as the blade's path, not the noise's).
        if let (Some(cut), Some(tip), Some(last)) = (&report.cut, tip, self.last_tip)
            && cutting
            && !cut.withdrawing
        {
            figures.cut_length_mm += (tip - last).norm() * 1e3;
        }
        let in_tissue = report.cut.as_ref().is_some_and(|c| c.in_tissue);
        figures.entries += u64::from(in_tissue && !self.last.in_tissue);
        if cutting && !self.last.cutting {
            figures.ruptures += 1;
            // The peak is the tick before: the rupture tick's force has dropped.
            figures.rupture_force_n = self.last.force_n.norm().max(report.tool_force_n.norm());
        }
        self.last_tip = tip;
        self.last = LastTick {
            force_n: report.tool_force_n,
            cutting,
            in_tissue,
        };
        figures.ticks += 1;
        figures.sim_force_n = report.tool_force_n.norm();
        figures.active_points = report.active_points;
        figures.substeps = report.solver.substeps;
        figures.most_substeps = figures.most_substeps.max(report.solver.substeps);
        figures.max_tick_ms = figures.max_tick_ms.max(took_ms);
        figures.tick_times.record(took_ms);
        figures.late_ticks += u64::from(took_ms > SIM_TICK_S * 1e3);
        figures.late_ticks_cpu +=
            u64::from(took_ms > SIM_TICK_S * 1e3 && cpu_ms > SIM_TICK_S * 1e3);
        figures.max_tick_cpu_ms = figures.max_tick_cpu_ms.max(cpu_ms);
        if took_ms > figures.slowest_tick.wall_ms {
            let slowest = &mut figures.slowest_tick;
            slowest.tick = figures.ticks;
            slowest.wall_ms = took_ms;
            slowest.cpu_ms = cpu_ms;
            slowest.stages_ms = report.stages.ms_by_stage();
        }
    }
}

/// The stages' clock: CLOCK_MONOTONIC (read through the vDSO, tens of nanoseconds a
/// read, nine reads a tick).
struct Monotonic;

impl StageClock for Monotonic {
    fn now_s(&mut self) -> f64 {
        realtime::monotonic_s()
    }
}

/// The simulation thread's render frames.
pub(super) struct SimFrames {
    pub(super) station: String,
    /// Send a frame every this many ticks (0: never).
    pub(super) every_ticks: u64,
    /// Told whether the frame services opened.
    pub(super) opened: std::sync::mpsc::Sender<Result<(), String>>,
}

/// Simulation ticks between frames at `frame_hz` (0: no frames).
pub(super) fn frame_interval_ticks(frame_hz: f64) -> u64 {
    if frame_hz > 0.0 {
        ((1.0 / (frame_hz * SIM_TICK_S)).round() as u64).max(1)
    } else {
        0
    }
}

/// How the simulation thread is scheduled.
pub(super) struct SimThread {
    /// SCHED_FIFO priority (0: normal scheduling).
    pub(super) fifo_priority: i32,
    /// Whether to take it: [`FIFO_PENDING`] until the haptic thread says what it got — a
    /// real-time simulation must not run above a haptic thread left at normal scheduling.
    pub(super) fifo_gate: Arc<AtomicU8>,
    /// The CPUs it may run on (empty: any); the CPUs besides a pinned haptic thread's.
    pub(super) cpus: Vec<usize>,
    /// Threads for the simulation, its own included (config `realtime.sim_threads`, at
    /// most the process's CPUs), and why fewer than asked.
    pub(super) threads: (usize, Option<String>),
    /// Its worker's CPUs (empty: any).
    pub(super) worker_cpus: Vec<usize>,
    /// Its nice value and its worker's under normal scheduling (0: the process's).
    pub(super) nice: i32,
    /// Where it says how it started (for the start report), once its scheduling is known.
    pub(super) started: std::sync::mpsc::SyncSender<SimStart>,
    /// The device's stable stiffness (N/m): each local model's K is bounded by it here,
    /// off the haptic thread.
    pub(super) max_stiffness_n_per_m: f64,
    /// The lesson's scorer, when the station runs one: it reads every tick (no
    /// allocation) and its metrics go out with the figures.
    pub(super) scorer: Option<scalpel_sim::lesson::Scorer>,
}

/// Ticks between the lesson's metrics handed to the main thread (which sends them at
/// 10 Hz): a pass over the plan's samples, a few microseconds.
const LESSON_METRICS_EVERY: u64 = 10;

/// How the simulation thread started.
pub(super) struct SimStart {
    /// Whether pinning to [`SimThread::cpus`] worked.
    pub(super) pinned: Result<(), String>,
    /// The threads the simulation runs on, its own included.
    pub(super) threads: usize,
    /// What its pool could not get.
    pub(super) warnings: Vec<String>,
}

/// Joins the simulation's pool as its thread 0 and hands it to `sim` (issue 42; the worker
/// is scheduled as this thread is, at `fifo_priority`): the threads the simulation runs on
/// and what was not granted.
fn start_pool(
    sim: &mut Simulation,
    thread: &SimThread,
    fifo_priority: i32,
) -> (usize, Vec<String>) {
    let (threads, why) = thread.threads.clone();
    let mut warnings: Vec<String> = why.into_iter().collect();
    let plan = PoolPlan {
        threads,
        worker_cpus: thread.worker_cpus.clone(),
        fifo_priority,
        nice: thread.nice,
    };
    match sim_pool::join_new_pool(&plan, || {}) {
        Ok(Some(pool)) => {
            warnings.extend(pool.warnings);
            sim.use_pool(pool.pool);
            (threads, warnings)
        }
        Ok(None) => (1, warnings),
        Err(e) => {
            warnings.push(format!("{e}: the simulation runs on its own thread"));
            (1, warnings)
        }
    }
}

/// [`SimThread::fifo_gate`]: waiting for the haptic thread's scheduling.
pub(super) const FIFO_PENDING: u8 = 0;
/// [`SimThread::fifo_gate`]: take SCHED_FIFO.
pub(super) const FIFO_TAKE: u8 = 1;
/// [`SimThread::fifo_gate`]: stay at normal scheduling.
pub(super) const FIFO_STAY_NORMAL: u8 = 2;

#[allow(clippy::too_many_arguments)]
pub(super) fn spawn_sim(
    mut sim: Simulation,
    mut poses: rtrb::Consumer<PoseIn>,
    mut models: triple_buffer::Input<ModelUpdate>,
    mut status: triple_buffer::Input<SimStatus>,
    mut faults: triple_buffer::Output<FaultTable>,
    mut journal: SimJournal,
    frames: SimFrames,
    stop: Arc<AtomicBool>,
    t0: f64,
    mut thread: SimThread,
    haptic: Option<Arc<SimWake>>,
) -> std::io::Result<JoinHandle<u64>> {
    std::thread::Builder::new()
        .name("simulation".into())
        .spawn(move || {
            // Off the haptic thread's own CPU: woken by each haptic tick, the simulation
            // would otherwise often be placed beside it. Refused is not fatal (the start
            // report says so, once the pool is made).
            let mut pinned = Some(if thread.cpus.is_empty() {
                Ok(())
            } else {
                realtime::pin_thread(&thread.cpus)
            });
            // Above the station's other normally scheduled threads and local viewers: a
            // simulation thread kept off its CPU, or a worker holding a part it took, makes
            // a late tick. Refused is not fatal (the start report says so).
            let mut nice_refused = (thread.nice != 0)
                .then(|| realtime::set_thread_nice(thread.nice).err())
                .flatten();
            let mut fifo_pending = thread.fifo_priority > 0;
            let mut fifo_granted = 0;
            // Shared-memory ports belong to the thread that opens them.
            let mut publisher = None;
            if frames.every_ticks > 0 {
                let opened = FramePublisher::open(&frames.station, &sim);
                let _ = frames
                    .opened
                    .send(opened.as_ref().map(|_| ()).map_err(|e| e.to_string()));
                publisher = opened.ok();
            }
            // On the station's 1 ms grid, woken by the haptic thread's tick (or at the
            // latest `SIM_PHASE_S` after the grid point).
            let mut clock = GridClock::starting_at(t0, SIM_TICK_S, realtime::monotonic_s());
            let mut counted = Counted::default();
            let mut sharing = SharingChooser::new();
            let mut pose: Option<PoseIn> = None;
            // Simulated ticks owed to a slowed-down simulation (1 per wall tick at real
            // time), and the stiffness factor in effect and last asked for.
            let mut credit = 0.0;
            let (mut stiffness, mut stiffness_asked) = (1.0, 1.0);
            while !stop.load(Ordering::Relaxed) {
                if fifo_pending {
                    match thread.fifo_gate.load(Ordering::Acquire) {
                        FIFO_TAKE => {
                            // Refused is not fatal: the simulation then runs with normal
                            // scheduling (reported by the status line's late ticks).
                            if realtime::make_thread_fifo(thread.fifo_priority).is_ok() {
                                fifo_granted = thread.fifo_priority;
                            }
                            fifo_pending = false;
                        }
                        FIFO_STAY_NORMAL => fifo_pending = false,
                        _ => {}
                    }
                }
                // The pool once this thread's scheduling is known: its worker gets the same.
                if !fifo_pending && let Some(pinned) = pinned.take() {
                    let (threads, mut warnings) = start_pool(&mut sim, &thread, fifo_granted);
                    if let Some(e) = nice_refused.take() {
                        warnings.push(format!(
                            "{e}: the simulation thread runs at the process's nice"
                        ));
                    }
                    let _ = thread.started.send(SimStart {
                        pinned,
                        threads,
                        warnings,
                    });
                }
                let k = clock.advance();
                let deadline = clock.deadline(k) + SIM_PHASE_S;
                match &haptic {
                    Some(h) => {
                        h.wait_for_haptic(clock.since_start(k), deadline);
                    }
                    None => realtime::sleep_until(deadline),
                }
                let started = realtime::monotonic_s();
                let started_cpu = realtime::thread_cpu_s();
                if started - deadline > 10.0 * SIM_TICK_S {
                    // Far behind (a slow scene): go on from the grid rather than catching
                    // up.
                    clock.resync(started);
                }
                while let Ok(p) = poses.pop() {
                    // An unsound pose (none of today's devices pass one on) is skipped: the
                    // last sound one holds, as the journal — which has only sound poses —
                    // will replay it.
                    if p.pose.is_sound() {
                        pose = Some(p);
                    }
                }
                let effects = faults.read().sim(station_tick(started - t0));
                if effects.stall {
                    // No tick, no frame, no new force model: the haptic watchdog fades
                    // the force out after its timeout.
                    continue;
                }
                credit = (credit + 1.0 / effects.slowdown).min(1.0);
                if credit < 1.0 - 1e-9 {
                    continue;
                }
                credit = 0.0;
                let stiffness_change = crate::faults::stiffness_to_apply(
                    stiffness,
                    effects.stiffness,
                    stiffness_asked,
                );
                stiffness_asked = effects.stiffness;
                if let Some(k) = stiffness_change {
                    stiffness = k;
                    counted.figures.stiffness_factor = k;
                }
                // This tick's inputs, as the journal records them and a replay applies them.
                let record = TickRecord {
                    tick: counted.figures.ticks + 1,
                    // What the simulation takes (only sound poses are latched above).
                    pose: pose.map(|p| p.pose),
                    stiffness: stiffness_change,
                };
                record.apply_to(&mut sim);
                // The frame goes out first: it shows the pose just taken (where this tick
                // puts the blade: the pose itself but for a jump faster than a hand), on the
                // surface of the last tick (a tick of cutting takes a few hundred
                // microseconds that the frame need not wait for).
                if let Some(p) = &mut publisher
                    && (counted.figures.ticks + 1) % frames.every_ticks == 0
                    && !effects.renderer_freeze
                {
                    let info = FrameInfo {
                        sim_tick: counted.figures.ticks,
                        tool: sim.next_blade_pose(SIM_TICK_S),
                        pose_seq: pose.map_or(0, |p| p.seq),
                        pose_received_ns: pose.map_or(0, |p| p.received_ns),
                        force_n: counted.last.force_n,
                        cutting: counted.last.cutting,
                        cut_length_mm: counted.figures.cut_length_mm,
                    };
                    // A frame that cannot be sent (renderers holding every sample) is
                    // skipped and counted; the next one is a whole new frame anyway.
                    match p.publish(&sim, &info) {
                        Ok(()) => counted.figures.frames_sent = p.frames(),
                        Err(_) => counted.figures.frames_failed += 1,
                    }
                }
                if let Some(records) = &mut journal.records
                    && records.push(record).is_err()
                {
                    journal.dropped.fetch_add(1, Ordering::Relaxed);
                }
                // Shared with the worker when that is the faster way here (sharing.rs).
                let (eligible, share) = (sim.can_share_next_tick(), sharing.next());
                sim.set_sharing(share);
                let shared = eligible && share;
                let report = sim.tick(SIM_TICK_S, &mut Monotonic);
                // The lesson's scoring is this tick's work too: a late tick counts it.
                let lesson = thread.scorer.as_mut().and_then(|scorer| {
                    scorer.observe(&sim, &report, SIM_TICK_S);
                    // The main thread sees its events in the metrics' counters.
                    while scorer.poll_event().is_some() {}
                    let tick = counted.figures.ticks + 1;
                    (tick % LESSON_METRICS_EVERY == 0).then(|| scorer.metrics())
                });
                let took_ms = (realtime::monotonic_s() - started) * 1e3;
                sharing.record(eligible, shared, took_ms);
                counted.figures.shared_ticks += u64::from(shared);
                let cpu_ms = (realtime::thread_cpu_s() - started_cpu) * 1e3;
                counted.record(&report, sim.blade_pose().map(|p| p.tip_m), took_ms, cpu_ms);
                counted.figures.recuts_waited = sim.incisions().map_or(0, |s| s.late_recuts as u64);
                if lesson.is_some() {
                    counted.figures.lesson = lesson;
                }
                let figures = counted.figures;
                models.write(ModelUpdate {
                    model: sim
                        .local_force_model()
                        .with_stiffness_at_most(thread.max_stiffness_n_per_m),
                    tick: figures.ticks,
                });
                status.write(figures);
            }
            sim.state_hash()
        })
}
