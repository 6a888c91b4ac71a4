//! One station: the haptic thread, the simulation thread, and the lock-free hand-offs
//! between them (ARCHITECTURE.md):
//!
//! ```text
//!  haptic thread, 1 kHz (SCHED_FIFO when permitted, absolute-deadline sleep)
//!    device pose ─► virtual coupling on the latest local force model ─► output stage
//!    ─► device force;  pose ─► SPSC ring ─► simulation thread
//!  simulation thread, 1 kHz of simulated time, paced by the clock
//!    latest pose ─► Simulation::tick ─► local force model ─► triple buffer ─► haptic thread
//!                                     ─► status          ─► triple buffer ─► main thread
//! ```
//!
//! The haptic thread neither allocates, locks, logs nor waits on anything but its own
//! deadline: a slow or stalled simulation only leaves it with an older force model, and the
//! output stage's watchdog fades the force out if the model stops coming.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, AtomicU64, Ordering};
use std::thread::JoinHandle;

use scalpel_sim::cut::ToolPose;
use scalpel_sim::force::{CutPhase, LocalForceModel};
use scalpel_sim::math::{Mat3, Vec3};
use scalpel_sim::pipeline::{Simulation, Unobserved};
use scalpel_sim::scene::BuiltScene;

use crate::command_audit::{self, CommandAudit};
use crate::device::{DeviceFactory, DeviceSample, ForceStatus, HapticDevice};
use crate::device_monitor::{DeviceEvent, DeviceMonitor};
use crate::faults::{FaultBook, FaultTable, HapticEffects, Transition};
use crate::frames::{FrameInfo, FramePublisher};
use crate::grid_clock::GridClock;
use crate::journal::{self, TickRecord};
use crate::output::{OutputInput, OutputLimits, OutputReport, OutputStage};
use crate::realtime;
use crate::sim_wake::SimWake;
use scalpel_proto::wire::{Event, EventKind, Metrics};

/// Jitter histogram: bins of this width (s) ...
const JITTER_BIN_S: f64 = 5e-6;
/// ... this many of them (the last collects everything later).
const JITTER_BINS: usize = 1000;
/// Poses in flight from the haptic to the simulation thread.
const POSE_RING: usize = 256;
/// Simulated time per simulation tick (s).
pub(crate) const SIM_TICK_S: f64 = scalpel_sim::pipeline::SIMULATION_TICK_S;
/// The simulation thread ticks on the same 1 ms grid as the haptic thread, woken by it once
/// its tick is done (`sim_wake`), so that it takes the pose the haptic thread has just read
/// (and the frame it sends shows it) instead of one up to a millisecond old; at the latest
/// it ticks this long after the grid point (a late haptic thread, or none).
const SIM_PHASE_S: f64 = 1e-4;

/// A pose on its way from the haptic to the simulation thread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PoseIn {
    /// The pose.
    pub pose: ToolPose,
    /// The device's sample counter.
    pub seq: u64,
    /// When the haptic thread took it (CLOCK_MONOTONIC, ns).
    pub received_ns: u64,
}

/// The station clock's tick at `now_s` seconds since the start (1 ms ticks; faults are
/// scheduled on it). The threads wake on the tick's grid point or just after it, and the
/// nanosecond of slack keeps one that float rounding puts a hair early on its own tick.
pub fn station_tick(now_s: f64) -> u64 {
    ((now_s + 1e-9) * 1e3).max(0.0) as u64
}

/// Device samples a latency fault can hold back (a second at 1 kHz, and room).
const DELAY_LINE: usize = 2048;

/// Journal records in flight to the writer thread (a minute at 1 kHz).
const JOURNAL_RING: usize = 1 << 16;

/// The force model and when it was made, handed from the simulation to the haptic thread.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ModelUpdate {
    model: LocalForceModel,
    /// Simulation ticks so far.
    tick: u64,
}

/// The simulation's figures, handed to the main thread.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SimStatus {
    /// Simulation ticks so far.
    pub ticks: u64,
    /// Blade travel while cutting, summed (mm).
    pub cut_length_mm: f64,
    /// The tool force the simulation computed last (N).
    pub sim_force_n: f64,
    /// Points integrated in the last tick.
    pub active_points: usize,
    /// Explicit sub-steps the last tick took (1 for a projective step).
    pub substeps: u32,
    /// Most sub-steps one tick took so far (a rollback doubles them for that tick).
    pub most_substeps: u32,
    /// Longest tick so far (ms of wall time).
    pub max_tick_ms: f64,
    /// Ticks that took longer than the simulated time they advance.
    pub late_ticks: u64,
    /// Render frames sent over shared memory.
    pub frames_sent: u64,
    /// Render frames that could not be sent (no shared memory free: renderers hold
    /// every sample).
    pub frames_failed: u64,
    /// Times the blade entered the tissue.
    pub entries: u64,
    /// Times the tissue ruptured under the blade (cutting began).
    pub ruptures: u64,
    /// Factor on the tissue's stiffness in effect (1: the scene's; an instructor's fault).
    pub stiffness_factor: f64,
}

impl Default for SimStatus {
    fn default() -> Self {
        Self {
            ticks: 0,
            cut_length_mm: 0.0,
            sim_force_n: 0.0,
            active_points: 0,
            substeps: 0,
            most_substeps: 0,
            max_tick_ms: 0.0,
            late_ticks: 0,
            frames_sent: 0,
            frames_failed: 0,
            entries: 0,
            ruptures: 0,
            stiffness_factor: 1.0,
        }
    }
}

/// Counters the haptic thread keeps with atomics only; the main thread reads and resets the
/// windowed ones.
pub struct HapticCounters {
    ticks: AtomicU64,
    misses: AtomicU64,
    jitter: Vec<AtomicU32>,
    max_jitter_ns: AtomicU64,
    force_bits: AtomicU64,
    nan_guards: AtomicU64,
    watchdog_faded: AtomicBool,
    passivity_ticks: AtomicU64,
    passivity_energy_bits: AtomicU64,
    total_ticks: AtomicU64,
    total_misses: AtomicU64,
    ring_full: AtomicU64,
}

impl HapticCounters {
    fn new() -> Self {
        Self {
            ticks: AtomicU64::new(0),
            misses: AtomicU64::new(0),
            jitter: (0..JITTER_BINS).map(|_| AtomicU32::new(0)).collect(),
            max_jitter_ns: AtomicU64::new(0),
            force_bits: AtomicU64::new(0),
            nan_guards: AtomicU64::new(0),
            watchdog_faded: AtomicBool::new(true),
            passivity_ticks: AtomicU64::new(0),
            passivity_energy_bits: AtomicU64::new(0),
            total_ticks: AtomicU64::new(0),
            total_misses: AtomicU64::new(0),
            ring_full: AtomicU64::new(0),
        }
    }

    fn record(&self, jitter_s: f64, missed: bool, out: &OutputReport) {
        self.ticks.fetch_add(1, Ordering::Relaxed);
        self.total_ticks.fetch_add(1, Ordering::Relaxed);
        if missed {
            self.misses.fetch_add(1, Ordering::Relaxed);
            self.total_misses.fetch_add(1, Ordering::Relaxed);
        }
        let bin = ((jitter_s / JITTER_BIN_S) as usize).min(JITTER_BINS - 1);
        self.jitter[bin].fetch_add(1, Ordering::Relaxed);
        self.max_jitter_ns
            .fetch_max((jitter_s * 1e9) as u64, Ordering::Relaxed);
        self.force_bits
            .store(out.force_n.norm().to_bits(), Ordering::Relaxed);
        if out.nan_guarded {
            self.nan_guards.fetch_add(1, Ordering::Relaxed);
        }
        self.watchdog_faded
            .store(out.watchdog_gain == 0.0, Ordering::Relaxed);
        if out.passivity_damping > 0.0 {
            self.passivity_ticks.fetch_add(1, Ordering::Relaxed);
        }
        self.passivity_energy_bits
            .store(out.passivity_energy_j.to_bits(), Ordering::Relaxed);
    }

    /// Takes the window's figures and starts a new window.
    fn take_window(&self, seconds: f64) -> HapticWindow {
        let counts: Vec<u32> = self
            .jitter
            .iter()
            .map(|b| b.swap(0, Ordering::Relaxed))
            .collect();
        let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        let quantile = |q: f64| {
            if total == 0 {
                return 0.0;
            }
            let want = (q * total as f64).ceil() as u64;
            let mut seen = 0;
            for (k, &c) in counts.iter().enumerate() {
                seen += u64::from(c);
                if seen >= want.max(1) {
                    return (k + 1) as f64 * JITTER_BIN_S * 1e3;
                }
            }
            JITTER_BINS as f64 * JITTER_BIN_S * 1e3
        };
        let ticks = self.ticks.swap(0, Ordering::Relaxed);
        let over_0_1_ms: u64 = counts[(1e-4 / JITTER_BIN_S).round() as usize..]
            .iter()
            .map(|&c| u64::from(c))
            .sum();
        HapticWindow {
            ticks,
            ticks_late_over_0_1_ms: over_0_1_ms,
            rate_hz: ticks as f64 / seconds,
            jitter_p50_ms: quantile(0.5),
            jitter_p99_ms: quantile(0.99),
            jitter_p999_ms: quantile(0.999),
            jitter_max_ms: self.max_jitter_ns.swap(0, Ordering::Relaxed) as f64 * 1e-6,
            deadline_misses: self.misses.swap(0, Ordering::Relaxed),
            force_n: f64::from_bits(self.force_bits.load(Ordering::Relaxed)),
            nan_guards: self.nan_guards.load(Ordering::Relaxed),
            watchdog_faded: self.watchdog_faded.load(Ordering::Relaxed),
            passivity_ticks: self.passivity_ticks.swap(0, Ordering::Relaxed),
            passivity_energy_mj: f64::from_bits(self.passivity_energy_bits.load(Ordering::Relaxed))
                * 1e3,
        }
    }
}

/// One status window of the haptic loop.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HapticWindow {
    /// Ticks in the window.
    pub ticks: u64,
    /// Ticks that woke 0.1 ms or more late (with `ticks`, the fraction for a p99.9 target).
    pub ticks_late_over_0_1_ms: u64,
    /// Ticks per second.
    pub rate_hz: f64,
    /// Wake-up lateness against the deadline, median and p99 (ms; histogram bins of 5 µs).
    pub jitter_p50_ms: f64,
    /// See `jitter_p50_ms`.
    pub jitter_p99_ms: f64,
    /// See `jitter_p50_ms` (p99.9: one tick in a thousand is later than this).
    pub jitter_p999_ms: f64,
    /// Latest wake-up (ms).
    pub jitter_max_ms: f64,
    /// Ticks that woke a whole period or more late.
    pub deadline_misses: u64,
    /// Force sent on the last tick (N).
    pub force_n: f64,
    /// Non-finite requests replaced by zero so far.
    pub nan_guards: u64,
    /// The watchdog has the force faded out.
    pub watchdog_faded: bool,
    /// Ticks in the window on which the passivity controller added damping.
    pub passivity_ticks: u64,
    /// The passivity observer's energy at the last tick (mJ): absorbed by the tissue and
    /// not given back, as far as the observer still remembers (`output.passivity_memory_ms`).
    pub passivity_energy_mj: f64,
}

/// A status line: the haptic window and the simulation's figures.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct StatusLine {
    /// Seconds since the start.
    pub uptime_s: f64,
    /// The haptic loop (`None` when the scene has no haptics).
    pub haptic: Option<HapticWindow>,
    /// The simulation.
    pub sim: SimStatus,
    /// A shared-memory device is connected (`None`: the device is in process).
    pub device_connected: Option<bool>,
    /// Dead iceoryx2 nodes (killed devices, viewers, servers) cleaned up so far.
    pub dead_nodes_cleaned: u64,
}

/// Something that happened at the station, reported as it happens.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StationEvent {
    /// Seconds since the start.
    pub uptime_s: f64,
    /// What happened.
    pub event: String,
}

/// What the station reports while it runs.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(untagged)]
pub enum StationReport {
    /// The periodic status line.
    Status(StatusLine),
    /// An event.
    Event(StationEvent),
}

/// What the station did, at the end.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RunSummary {
    /// Haptic ticks.
    pub haptic_ticks: u64,
    /// Haptic ticks that woke a period or more late.
    pub deadline_misses: u64,
    /// Poses dropped because the simulation thread was behind (ring full).
    pub poses_dropped: u64,
    /// The simulation's figures.
    pub sim: SimStatus,
    /// The simulation's state hash at the end (see `Simulation::state_hash`).
    pub state_hash: u64,
    /// Journal records lost because the writer fell a minute behind (0: the journal is
    /// complete and replays bit for bit).
    pub journal_dropped: u64,
    /// The real-time set-up in effect.
    pub fifo_priority: i32,
    /// Memory locked.
    pub memory_locked: bool,
    /// Why some real-time request was not granted.
    pub warnings: Vec<String>,
}

/// How to run a station.
pub struct StationParams {
    /// Haptic rate (Hz).
    pub haptic_hz: f64,
    /// SCHED_FIFO priority for the haptic thread (0: normal).
    pub fifo_priority: i32,
    /// SCHED_FIFO priority for the simulation thread (0: normal).
    pub sim_fifo_priority: i32,
    /// Lock memory.
    pub lock_memory: bool,
    /// A CPU of its own for the haptic thread (config `realtime.haptic_cpu`).
    pub haptic_cpu: Option<usize>,
    /// Output stage.
    pub limits: OutputLimits,
    /// Status interval (s).
    pub status_interval_s: f64,
    /// Station name (names the shared-memory services).
    pub station: String,
    /// Render frames per second over shared memory (0: none).
    pub frame_hz: f64,
    /// Watch for a shared-memory device coming and going.
    pub monitor_device: bool,
    /// Run the haptic thread (the scene's `haptics` feature); without it the simulation
    /// runs with no tool.
    pub haptics: bool,
    /// The QUIC endpoint for remote observers and instructors, if any.
    pub network: Option<crate::net::NetworkParams>,
}

/// The live server among a station's nodes (one server per station).
pub fn live_server(nodes: &[scalpel_proto::shm::NodeSeen]) -> Option<&str> {
    nodes
        .iter()
        .find(|n| n.alive && n.name.starts_with("scalpel-server."))
        .map(|n| n.name.as_str())
}

/// Why a second server on `station` is refused (its live `node`).
pub fn station_taken(station: &str, node: &str) -> String {
    format!(
        "station {station} already has a running server (its node {node} is alive): stop it, or give this one another `station` name"
    )
}

/// Runs a station until `stop` is set, calling `report` with a status line every interval
/// and with events as they happen (on this thread). The device is made on the haptic
/// thread. With `journal` (its header written), every tick's input is appended to it by a
/// writer thread and the file is closed with the tick count and the final state hash.
pub fn run(
    scene: &BuiltScene,
    device: DeviceFactory,
    params: &StationParams,
    journal: Option<std::io::BufWriter<std::fs::File>>,
    stop: Arc<AtomicBool>,
    mut report: impl FnMut(&StationReport),
) -> anyhow::Result<RunSummary> {
    let mut warnings = Vec::new();
    let mut memory_locked = false;
    let (pose_in, pose_out) = rtrb::RingBuffer::<PoseIn>::new(POSE_RING);
    let zero_model = ModelUpdate {
        model: LocalForceModel {
            f0_n: Vec3::zeros(),
            x0_m: Vec3::zeros(),
            stiffness_n_per_m: Mat3::zeros(),
            stored_energy_j: 0.0,
        },
        tick: 0,
    };
    let (model_in, model_out) = triple_buffer::triple_buffer(&zero_model);
    let (status_in, mut status_out) = triple_buffer::triple_buffer(&SimStatus::default());
    // The instructor's faults, one table per real-time thread.
    let (mut faults_to_haptic, faults_haptic) =
        triple_buffer::triple_buffer(&FaultTable::default());
    let (mut faults_to_sim, faults_sim) = triple_buffer::triple_buffer(&FaultTable::default());
    let counters = Arc::new(HapticCounters::new());
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let (frames_tx, frames_rx) = std::sync::mpsc::channel();
    // One server per station: the services are the station's.
    match scalpel_proto::shm::station_nodes(&params.station) {
        Ok(nodes) => {
            if let Some(n) = live_server(&nodes) {
                anyhow::bail!("{}", station_taken(&params.station, n));
            }
        }
        Err(e) => warnings.push(format!("{e}: cannot check that the station is free")),
    }
    // The haptic thread's own CPU, if one is given: the simulation and the network threads
    // run on the others.
    let cpus = realtime::allowed_cpus();
    let (haptic_cpu, other_cpus) = match params.haptic_cpu {
        Some(c) => match realtime::cpus_besides(c, &cpus) {
            Ok(others) => (Some(c), others),
            Err(e) => {
                warnings.push(format!("{e}: the haptic thread shares its CPU"));
                (None, Vec::new())
            }
        },
        None => (None, Vec::new()),
    };
    // The network endpoint first: if it cannot listen, nothing else has started yet.
    let network = match &params.network {
        Some(n) => Some(crate::net::start(crate::net::NetworkParams {
            cpus: other_cpus.clone(),
            ..n.clone()
        })?),
        None => None,
    };
    // The monitor also cleans up after any dead node (a killed viewer, a killed server of
    // this station before this one), so it runs whatever the device.
    let mut monitor = match DeviceMonitor::open(&params.station) {
        Ok(m) => Some(m),
        Err(e) if !params.monitor_device => {
            warnings.push(format!("{e}: no shared-memory clean-up"));
            None
        }
        Err(e) => return Err(e.into()),
    };

    // Built before the threads start: everything the loops use is allocated up front.
    let mut sim = Simulation::new(scene);
    // The stable step and the mass scaling to whole sub-steps: power iterations, here and
    // not in the first real-time tick.
    sim.prepare(SIM_TICK_S);
    let t0 = realtime::monotonic_s();
    let journal_dropped = Arc::new(AtomicU64::new(0));
    let sim_done = Arc::new(AtomicBool::new(false));
    let (commands_journal, commands_out) = std::sync::mpsc::channel::<String>();
    let (records_in, writer) = match journal {
        Some(file) => {
            let (records_in, records_out) = rtrb::RingBuffer::<TickRecord>::new(JOURNAL_RING);
            let writer = spawn_journal_writer(file, records_out, commands_out, sim_done.clone())?;
            (Some(records_in), Some(writer))
        }
        None => {
            // No journal: the command lines go nowhere (sending then fails, harmlessly)
            // instead of piling up unread.
            drop(commands_out);
            (None, None)
        }
    };
    // The haptic thread wakes the simulation thread once its tick is done.
    let sim_wake = params.haptics.then(|| Arc::new(SimWake::new()));
    let sim_fifo_gate = Arc::new(AtomicU8::new(FIFO_PENDING));
    let (sim_pinned_tx, sim_pinned_rx) = std::sync::mpsc::sync_channel(1);
    let sim_thread = spawn_sim(
        sim,
        pose_out,
        model_in,
        status_in,
        faults_sim,
        SimJournal {
            records: records_in,
            dropped: journal_dropped.clone(),
        },
        SimFrames {
            station: params.station.clone(),
            every_ticks: frame_interval_ticks(params.frame_hz),
            opened: frames_tx,
        },
        stop.clone(),
        t0,
        SimThread {
            fifo_priority: params.sim_fifo_priority,
            fifo_gate: sim_fifo_gate.clone(),
            cpus: other_cpus.clone(),
            pinned: sim_pinned_tx,
        },
        sim_wake.clone(),
    )?;
    let haptic_thread = if let Some(sim_wake) = sim_wake {
        Some(spawn_haptic(
            device,
            HapticContext {
                period_s: 1.0 / params.haptic_hz,
                fifo_priority: params.fifo_priority,
                cpu: haptic_cpu,
                limits: params.limits,
                t0,
            },
            (sim_wake, sim_thread.thread().clone()),
            pose_in,
            model_out,
            faults_haptic,
            counters.clone(),
            stop.clone(),
            ready_tx,
        )?)
    } else {
        drop((device, pose_in, model_out, faults_haptic, ready_tx));
        None
    };
    let mut fifo_priority = 0;
    let mut pinned_cpu = None;
    let device_error = match (&haptic_thread, ready_rx.recv()) {
        (None, _) => None,
        (Some(_), Ok(ready)) => {
            match ready.fifo {
                Ok(p) => fifo_priority = p,
                Err(e) => warnings.push(format!(
                    "{e}: the haptic thread runs with normal scheduling"
                )),
            }
            match ready.cpu {
                Ok(c) => pinned_cpu = c,
                Err(e) => warnings.push(format!("{e}: the haptic thread shares its CPU")),
            }
            ready.device.err()
        }
        (Some(_), Err(_)) => Some("the haptic thread ended before it started".to_string()),
    };
    // The simulation takes SCHED_FIFO only above a haptic thread that got it (or with none).
    sim_fifo_gate.store(
        if haptic_thread.is_none() || fifo_priority > 0 {
            FIFO_TAKE
        } else {
            FIFO_STAY_NORMAL
        },
        Ordering::Release,
    );
    let sim_pinned = match sim_pinned_rx.recv() {
        Ok(Ok(())) => !other_cpus.is_empty(),
        Ok(Err(e)) => {
            warnings.push(format!(
                "{e}: the simulation thread may share the haptic thread's CPU"
            ));
            false
        }
        Err(_) => false,
    };
    let mut frames_running = false;
    if params.frame_hz > 0.0 {
        match frames_rx.recv() {
            Ok(Ok(())) => frames_running = true,
            Ok(Err(e)) => warnings.push(format!("{e}: no render frames")),
            Err(_) => {}
        }
    }
    // Locked once the threads, their stacks, the device's and the frames' shared memory
    // and the hand-off buffers exist.
    if params.lock_memory && device_error.is_none() {
        match realtime::lock_memory() {
            Ok(()) => memory_locked = true,
            Err(e) => warnings.push(format!("{e}: the haptic loop may wait on page faults")),
        }
    }
    if let Some(e) = &device_error {
        stop.store(true, Ordering::Relaxed);
        if let Some(h) = haptic_thread {
            let _ = h.join();
        }
        let _ = sim_thread.join();
        sim_done.store(true, Ordering::Release);
        if let Some(w) = writer {
            let _ = w.join();
        }
        anyhow::bail!("cannot open the device: {e}");
    }
    let mut running = vec![if sim_pinned {
        format!("simulation thread (CPUs {other_cpus:?})")
    } else {
        "simulation thread".to_string()
    }];
    let mut off = Vec::new();
    if haptic_thread.is_some() {
        running.push(format!(
            "haptic thread {} Hz ({}, memory {}{})",
            params.haptic_hz,
            if fifo_priority > 0 {
                format!("SCHED_FIFO {fifo_priority}")
            } else {
                "normal scheduling".into()
            },
            if memory_locked {
                "locked"
            } else {
                "not locked"
            },
            pinned_cpu.map_or(String::new(), |c| format!(", CPU {c} to itself"))
        ));
        running.push(if params.monitor_device {
            "shared-memory device with its force-out thread".into()
        } else {
            "in-process scripted device".into()
        });
    } else {
        off.push("haptic thread (the scene has no haptics)".to_string());
    }
    if frames_running {
        running.push(format!("render frames {} Hz", params.frame_hz));
    } else {
        off.push("render frames".into());
    }
    if monitor.is_some() {
        running.push("shared-memory monitor".into());
    }
    match &network {
        Some(n) => running.push(format!("network endpoint on {}", n.local_addr)),
        None => off.push("network endpoint (no observers)".into()),
    }
    report(&StationReport::Event(StationEvent {
        uptime_s: realtime::monotonic_s() - t0,
        event: format!(
            "runs: {}; off: {}",
            running.join(", "),
            if off.is_empty() {
                "nothing".to_string()
            } else {
                off.join(", ")
            }
        ),
    }));
    // Instructors schedule on the station clock; a tool on this machine that logs
    // CLOCK_MONOTONIC (a device trace, a renderer) lines up with it through this.
    report(&StationReport::Event(StationEvent {
        uptime_s: realtime::monotonic_s() - t0,
        event: format!(
            "clock: station tick 0 is CLOCK_MONOTONIC {} ns",
            (t0 * 1e9).round() as u64
        ),
    }));
    for w in &warnings {
        report(&StationReport::Event(StationEvent {
            uptime_s: realtime::monotonic_s() - t0,
            event: format!("warning: {w}"),
        }));
    }

    let mut next = t0 + params.status_interval_s;
    let mut window_start = t0;
    let mut remote = RemoteFeed::default();
    let mut book = FaultBook::new();
    let mut audit = CommandAudit::new();
    let mut stream_lost = false;
    // The table the threads have (rebuilt only when the book changes).
    let mut table = FaultTable::default();
    let stiff_mode = scene.spec.features.stiff_mode;
    while !stop.load(Ordering::Relaxed) {
        // Every 10 ms: instructors' commands are answered within that.
        realtime::sleep_until(next.min(realtime::monotonic_s() + 0.01));
        let now = realtime::monotonic_s();
        let sim_now = *status_out.read();
        let tick = station_tick(now - t0);
        let mut table_changed = false;
        if let Some(n) = &network {
            while let Ok(request) = n.commands.try_recv() {
                use scalpel_proto::wire::{Action, Fault, Outcome, Role};
                let refuse = |reason: &str| {
                    (
                        Outcome::Rejected {
                            reason: reason.to_string(),
                        },
                        None,
                    )
                };
                let (outcome, listed) = if request.reply.is_closed() {
                    // The session gave up waiting (and told its client so): not carried
                    // out late.
                    refuse("expired: the station did not take it in time")
                } else if request.role != Role::Instructor {
                    refuse("an observer certificate may not instruct")
                } else if stiff_mode
                    && matches!(
                        &request.command.action,
                        Action::Schedule(spec) if matches!(spec.fault, Fault::TissueStiffness { .. })
                    )
                {
                    // Each change would re-factorise the projective solver on the
                    // simulation thread (milliseconds, allocating).
                    refuse("tissue-stiffness is not available in a stiff-mode scene")
                } else {
                    book.command(&request.by, &request.command, tick)
                };
                table_changed |=
                    matches!(outcome, Outcome::Scheduled { .. } | Outcome::Cleared { .. });
                let refused = matches!(outcome, Outcome::Rejected { .. });
                if audit.record(&request.by, refused, tick) == command_audit::Record::Full {
                    let record = serde_json::json!({
                        "station_tick": tick,
                        "sim_tick": sim_now.ticks,
                        "by": request.by,
                        "role": request.role,
                        "seq": request.command.seq,
                        "action": request.command.action,
                        "outcome": outcome,
                    });
                    // No journal: nobody reads the channel, and that is fine.
                    let _ = commands_journal.send(journal::command_line(&record));
                    report(&StationReport::Event(StationEvent {
                        uptime_s: now - t0,
                        event: format!(
                            "instructor {}: command {} {:?} -> {:?}",
                            request.by, request.command.seq, request.command.action, outcome
                        ),
                    }));
                }
                // The session may have gone: its answer has nowhere to go.
                let _ = request.reply.send((outcome, listed));
            }
            for summary in audit.summaries(tick, false) {
                record_refusals(&summary, &sim_now, now - t0, &commands_journal, &mut report);
            }
        }
        for transition in book.advance(tick) {
            table_changed = true;
            let (kind, text) = match transition {
                Transition::Applied(t) => (EventKind::FaultApplied, format!("{t}: applied")),
                Transition::Ended(t) => (EventKind::FaultCleared, t),
            };
            remote.event(&network, &sim_now, now - t0, kind, &text);
            report(&StationReport::Event(StationEvent {
                uptime_s: now - t0,
                event: text,
            }));
        }
        if table_changed {
            table = book.table();
            faults_to_haptic.write(table);
            faults_to_sim.write(table);
        }
        if let Some(n) = &network {
            let lost = table.stream_lost(tick);
            if lost != stream_lost {
                stream_lost = lost;
                n.feeds.stream_lost.send_replace(lost);
            }
        }
        if let Some(m) = &mut monitor
            && let Some(change) = m.poll()
            && params.monitor_device
        {
            let (kind, text) = match change {
                DeviceEvent::Connected => (EventKind::DeviceConnected, "device connected".into()),
                DeviceEvent::Lost => (
                    EventKind::DeviceLost,
                    format!(
                        "device lost (dead nodes cleaned so far: {}); the force fades to zero",
                        m.dead_nodes_cleaned()
                    ),
                ),
            };
            remote.event(&network, &sim_now, now - t0, kind, &text);
            report(&StationReport::Event(StationEvent {
                uptime_s: now - t0,
                event: text,
            }));
        }
        if let Some(n) = &network {
            remote.publish(
                n,
                &sim_now,
                now - t0,
                &counters,
                monitor
                    .as_ref()
                    .filter(|_| params.monitor_device)
                    .is_none_or(|m| m.connected())
                    && params.haptics,
            );
        }
        if now >= next {
            let line = StatusLine {
                uptime_s: now - t0,
                haptic: params
                    .haptics
                    .then(|| counters.take_window(now - window_start)),
                sim: *status_out.read(),
                device_connected: monitor
                    .as_ref()
                    .filter(|_| params.monitor_device)
                    .map(|m| m.connected()),
                dead_nodes_cleaned: monitor.as_ref().map_or(0, |m| m.dead_nodes_cleaned()),
            };
            if let Some(h) = &line.haptic {
                remote.window = Some(*h);
            }
            report(&StationReport::Status(line));
            window_start = now;
            next += params.status_interval_s;
        }
        if haptic_thread.as_ref().is_some_and(|h| h.is_finished()) || sim_thread.is_finished() {
            stop.store(true, Ordering::Relaxed);
        }
    }
    let now = realtime::monotonic_s();
    for summary in audit.summaries(station_tick(now - t0), true) {
        let sim_now = *status_out.read();
        record_refusals(&summary, &sim_now, now - t0, &commands_journal, &mut report);
    }
    let haptic_result = match haptic_thread {
        Some(h) => h.join(),
        None => Ok(()),
    };
    if let Some(n) = network {
        n.stop();
    }
    let sim_result = sim_thread.join();
    sim_done.store(true, Ordering::Release);
    let sim_status = *status_out.read();
    // The journal is flushed whatever happened: a session that failed is the one to replay.
    let mut file = match writer {
        Some(w) => Some(
            w.join()
                .map_err(|_| anyhow::anyhow!("the journal writer panicked"))??,
        ),
        None => None,
    };
    let (Ok(()), Ok(state_hash)) = (haptic_result, sim_result) else {
        if let Some(f) = &mut file {
            std::io::Write::flush(f)?;
        }
        anyhow::bail!("a station thread panicked (the journal has the inputs up to it)");
    };
    if let Some(f) = &mut file {
        std::io::Write::write_all(f, journal::footer(sim_status.ticks, state_hash).as_bytes())?;
        std::io::Write::flush(f)?;
    }
    Ok(RunSummary {
        haptic_ticks: counters.total_ticks.load(Ordering::Relaxed),
        deadline_misses: counters.total_misses.load(Ordering::Relaxed),
        poses_dropped: counters.ring_full.load(Ordering::Relaxed),
        sim: sim_status,
        state_hash,
        journal_dropped: journal_dropped.load(Ordering::Relaxed),
        fifo_priority,
        memory_locked,
        warnings,
    })
}

/// Writes out refusals the audit counted: one journal line (`refused_unrecorded`, which
/// `scalpel replay` lists) and one line of the station's log.
fn record_refusals(
    summary: &command_audit::Summary,
    sim_now: &SimStatus,
    uptime_s: f64,
    journal: &std::sync::mpsc::Sender<String>,
    report: &mut dyn FnMut(&StationReport),
) {
    // Station and simulation ticks of the summary, like every command line's; the refusals
    // it counts came between the first and the last tick given.
    let record = serde_json::json!({
        "station_tick": station_tick(uptime_s),
        "sim_tick": sim_now.ticks,
        "by": summary.by,
        "refused_unrecorded": summary.refused,
        "first_station_tick": summary.ticks.0,
        "last_station_tick": summary.ticks.1,
    });
    let _ = journal.send(journal::command_line(&record));
    report(&StationReport::Event(StationEvent {
        uptime_s,
        event: format!(
            "instructor {}: {} more commands refused from station tick {} to {} (a flood: \
             counted, not written out one by one)",
            summary.by, summary.refused, summary.ticks.0, summary.ticks.1
        ),
    }));
}

#[derive(Clone, Copy)]
struct HapticContext {
    period_s: f64,
    fifo_priority: i32,
    cpu: Option<usize>,
    limits: OutputLimits,
    t0: f64,
}

/// What the haptic thread reports once it has set itself up.
struct HapticReady {
    /// The SCHED_FIFO priority granted, or why not.
    fifo: Result<i32, String>,
    /// The CPU the thread has to itself, or why not.
    cpu: Result<Option<usize>, String>,
    /// The device opened, or why not.
    device: Result<(), String>,
}

#[allow(clippy::too_many_arguments)]
fn spawn_haptic(
    device: DeviceFactory,
    ctx: HapticContext,
    (sim_wake, sim_thread): (Arc<SimWake>, std::thread::Thread),
    mut poses: rtrb::Producer<PoseIn>,
    mut models: triple_buffer::Output<ModelUpdate>,
    mut faults: triple_buffer::Output<FaultTable>,
    counters: Arc<HapticCounters>,
    stop: Arc<AtomicBool>,
    ready: std::sync::mpsc::Sender<HapticReady>,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name("haptic".into())
        .spawn(move || {
            let granted = if ctx.fifo_priority > 0 {
                realtime::make_thread_fifo(ctx.fifo_priority).map(|()| ctx.fifo_priority)
            } else {
                Ok(0)
            };
            let cpu = match ctx.cpu {
                Some(c) => realtime::pin_thread(&[c]).map(|()| Some(c)),
                None => Ok(None),
            };
            let mut device = match device() {
                Ok(d) => {
                    let _ = ready.send(HapticReady {
                        fifo: granted,
                        cpu,
                        device: Ok(()),
                    });
                    d
                }
                Err(e) => {
                    let _ = ready.send(HapticReady {
                        fifo: granted,
                        cpu,
                        device: Err(format!("{e:#}")),
                    });
                    return;
                }
            };
            let mut state = HapticState::new(ctx.limits);
            // The schedule starts once this thread runs (spawning and the scheduler change
            // take a while); the device's clock still counts from the station's start.
            // On the station's grid (the simulation ticks just after it).
            let mut clock = GridClock::starting_at(ctx.t0, ctx.period_s, realtime::monotonic_s());
            while !stop.load(Ordering::Relaxed) {
                let mut k = clock.advance();
                let deadline = clock.deadline(k);
                realtime::sleep_until(deadline);
                let wall = realtime::monotonic_s();
                let lateness = (wall - deadline).max(0.0);
                let missed = lateness >= ctx.period_s;
                if missed {
                    // Woke a whole period late: go on from the grid point now rather than
                    // running the missed ticks back to back.
                    k = clock.resync(wall);
                }
                state.tick(
                    wall - ctx.t0,
                    lateness,
                    missed,
                    device.as_mut(),
                    &mut poses,
                    &mut models,
                    &mut faults,
                    &counters,
                );
                sim_wake.haptic_done(clock.since_start(k), &sim_thread);
            }
            // Stopping: bring the force down at the rate limit and leave the device at
            // zero (many devices hold their last command).
            for _ in 0..10_000 {
                let k = clock.advance();
                realtime::sleep_until(clock.deadline(k));
                let now = realtime::monotonic_s() - ctx.t0;
                if state.release(now, device.as_mut()) == Vec3::zeros() {
                    break;
                }
            }
            let now = realtime::monotonic_s();
            device.send_force(
                Vec3::zeros(),
                ForceStatus {
                    faded: true,
                    nan_guarded: false,
                    tick_time_ns: (now * 1e9) as u64,
                    station_tick: station_tick(now - ctx.t0),
                    pose_seq: state.used_seq,
                },
            );
        })
}

/// The haptic loop's state between ticks.
pub struct HapticState {
    stage: OutputStage,
    /// Device time (s) and position of the last sample.
    last_pose: Option<(f64, Vec3)>,
    /// Device velocity from its last two samples, held between samples.
    velocity: Vec3,
    device_seen: Option<f64>,
    sim_seen: Option<f64>,
    last_model_tick: u64,
    /// Device samples held back by a latency fault, with the time each arrived (capacity
    /// reserved up front: pushing never allocates).
    delay: std::collections::VecDeque<(f64, DeviceSample)>,
    /// `seq` of the sample the force is computed from.
    used_seq: u64,
    /// The noise fault's generator (seeded: a run's noise is the journal's to replay,
    /// since the poses the simulation used are journaled after the noise).
    rng: rand_pcg::Pcg32,
}

impl HapticState {
    /// A loop that has not ticked yet.
    pub fn new(limits: OutputLimits) -> Self {
        Self {
            stage: OutputStage::new(limits),
            last_pose: None,
            velocity: Vec3::zeros(),
            device_seen: None,
            sim_seen: None,
            last_model_tick: 0,
            delay: std::collections::VecDeque::with_capacity(DELAY_LINE),
            used_seq: 0,
            rng: rand_pcg::Pcg32::new(0x05ca_19e1, 0x0da7_a5e7),
        }
    }

    /// The device's sample for this tick, through the faults: dropped while the device
    /// drops out, held back by a latency, or passed on.
    fn faulted_sample(
        &mut self,
        now: f64,
        arrived: Option<DeviceSample>,
        effects: &HapticEffects,
    ) -> Option<DeviceSample> {
        if let Some(s) = arrived
            && !effects.dropout
        {
            if self.delay.len() == DELAY_LINE {
                self.delay.pop_front();
            }
            self.delay.push_back((now, s));
        }
        let mut delivered = None;
        while let Some(&(arrived_at, s)) = self.delay.front() {
            if now - arrived_at + 1e-9 < effects.latency_s {
                break;
            }
            delivered = Some(s);
            self.delay.pop_front();
        }
        delivered
    }

    /// A Gaussian offset with `sigma` per axis (Box–Muller on the seeded generator).
    fn noise(&mut self, sigma: f64) -> Vec3 {
        use rand_pcg::rand_core::Rng;
        let mut uniform = || (self.rng.next_u32() as f64 + 0.5) / 4_294_967_296.0;
        let mut gauss = || {
            let (u, v) = (uniform(), uniform());
            (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
        };
        Vec3::new(gauss(), gauss(), gauss()) * sigma
    }

    /// One haptic tick at `now` (s since the start) that woke `lateness` late: device pose
    /// in (through the instructor's faults), coupling on the latest model, output stage,
    /// force out, pose to the simulation. No allocation, no lock, no wait
    /// (tests/realtime.rs counts allocations).
    #[allow(clippy::too_many_arguments)]
    fn tick(
        &mut self,
        now: f64,
        lateness: f64,
        missed: bool,
        device: &mut dyn HapticDevice,
        poses: &mut rtrb::Producer<PoseIn>,
        models: &mut triple_buffer::Output<ModelUpdate>,
        faults: &mut triple_buffer::Output<FaultTable>,
        counters: &HapticCounters,
    ) {
        let tick_wall_s = realtime::monotonic_s();
        let effects = faults.read().haptic(station_tick(now));
        let mut x = self.last_pose.map_or(Vec3::zeros(), |(_, x)| x);
        let arrived = device.sample(now);
        if arrived.is_some() && !effects.dropout {
            // The device is alive even while a latency fault holds its samples back: the
            // watchdog must not fade the force for the lag.
            self.device_seen = Some(now);
        }
        if let Some(mut sample) = self.faulted_sample(now, arrived, &effects) {
            // Velocity on the device's clock: a device and this loop both at 1 kHz drift in
            // phase, so some ticks get no sample and some two; the receive times would
            // make that look like stops and jumps.
            self.velocity = match self.last_pose {
                Some((t, last_x)) if sample.device_time_s > t => {
                    (sample.pose.tip_m - last_x) / (sample.device_time_s - t)
                }
                _ => Vec3::zeros(),
            };
            x = sample.pose.tip_m;
            self.last_pose = Some((sample.device_time_s, x));
            self.device_seen = Some(now);
            self.used_seq = sample.seq;
            if effects.noise_sigma_m > 0.0 {
                // On what the coupling and the simulation see, not on the velocity (a
                // millimetre of noise a millisecond would read as metres a second).
                sample.pose.tip_m += self.noise(effects.noise_sigma_m);
                x = sample.pose.tip_m;
            }
            let received_ns = (tick_wall_s * 1e9) as u64;
            if poses
                .push(PoseIn {
                    pose: sample.pose,
                    seq: sample.seq,
                    received_ns,
                })
                .is_err()
            {
                counters.ring_full.fetch_add(1, Ordering::Relaxed);
            }
        } else if self.device_seen.is_none_or(|t| now - t > 0.005) {
            // Silent device: no motion to feed the passivity observer.
            self.velocity = Vec3::zeros();
        }
        let velocity = self.velocity;
        let update = *models.read();
        if update.tick != self.last_model_tick {
            self.last_model_tick = update.tick;
            self.sim_seen = Some(now);
        }
        let mut requested = update.model.force_at(x);
        if effects.spike_n != 0.0 {
            // Along the force there is (or up, out of the tissue): the output stage limits
            // it like any other request.
            let along = requested.try_normalize(1e-9).unwrap_or_else(Vec3::z);
            requested += along * effects.spike_n;
        }
        let report = self.stage.process(&OutputInput {
            now_s: now,
            requested_n: requested,
            velocity_m_per_s: velocity,
            device_seen_s: self.device_seen,
            sim_seen_s: self.sim_seen,
            cap_n: effects.cap_n,
            stored_energy_j: update.model.stored_energy_j,
        });
        device.send_force(
            report.force_n,
            ForceStatus {
                faded: report.watchdog_gain < 1.0,
                nan_guarded: report.nan_guarded,
                tick_time_ns: (tick_wall_s * 1e9) as u64,
                station_tick: station_tick(now),
                pose_seq: self.used_seq,
            },
        );
        counters.record(lateness, missed, &report);
    }
}

impl HapticState {
    /// One tick of winding down: the force requested is zero; returns what was sent.
    fn release(&mut self, now: f64, device: &mut dyn HapticDevice) -> Vec3 {
        let report = self.stage.process(&OutputInput {
            now_s: now,
            requested_n: Vec3::zeros(),
            velocity_m_per_s: Vec3::zeros(),
            device_seen_s: Some(now),
            sim_seen_s: Some(now),
            cap_n: f64::INFINITY,
            stored_energy_j: 0.0,
        });
        device.send_force(
            report.force_n,
            ForceStatus {
                faded: true,
                nan_guarded: false,
                tick_time_ns: (realtime::monotonic_s() * 1e9) as u64,
                station_tick: station_tick(now),
                pose_seq: self.used_seq,
            },
        );
        report.force_n
    }
}

/// Drives [`HapticState::tick`] with real hand-offs, for the allocation test: `ticks`
/// haptic ticks of 1 ms against `device`, with a simulation side that publishes `model`
/// every tick and drains the poses, under the instructor's `faults`. Returns the force
/// sent on the last tick.
pub fn drive_haptic_ticks(
    device: &mut dyn HapticDevice,
    limits: OutputLimits,
    model: LocalForceModel,
    faults: FaultTable,
    ticks: usize,
    mut between: impl FnMut(),
) -> f64 {
    let (mut pose_in, mut pose_out) = rtrb::RingBuffer::<PoseIn>::new(POSE_RING);
    let first = ModelUpdate { model, tick: 0 };
    let (mut model_in, mut model_out) = triple_buffer::triple_buffer(&first);
    let (_faults_in, mut faults_out) = triple_buffer::triple_buffer(&faults);
    let counters = HapticCounters::new();
    let mut state = HapticState::new(limits);
    let mut force = 0.0;
    for k in 0..ticks {
        model_in.write(ModelUpdate {
            model,
            tick: k as u64 + 1,
        });
        state.tick(
            k as f64 * 1e-3,
            0.0,
            false,
            device,
            &mut pose_in,
            &mut model_out,
            &mut faults_out,
            &counters,
        );
        while pose_out.pop().is_ok() {}
        force = f64::from_bits(counters.force_bits.load(Ordering::Relaxed));
        between();
    }
    force
}

/// The simulation thread's end of the journal.
struct SimJournal {
    records: Option<rtrb::Producer<TickRecord>>,
    dropped: Arc<AtomicU64>,
}

/// Writes journal records as they come, until the simulation has stopped and the ring is
/// empty; hands the file back for the footer.
fn spawn_journal_writer(
    mut file: std::io::BufWriter<std::fs::File>,
    mut records: rtrb::Consumer<TickRecord>,
    commands: std::sync::mpsc::Receiver<String>,
    sim_done: Arc<AtomicBool>,
) -> std::io::Result<JoinHandle<std::io::Result<std::io::BufWriter<std::fs::File>>>> {
    std::thread::Builder::new()
        .name("journal".into())
        .spawn(move || {
            loop {
                let done = sim_done.load(Ordering::Acquire);
                while let Ok(line) = commands.try_recv() {
                    std::io::Write::write_all(&mut file, line.as_bytes())?;
                }
                while let Ok(r) = records.pop() {
                    journal::write_record(&mut file, &r)?;
                }
                if done {
                    return Ok(file);
                }
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
        })
}

/// What the main thread tells remote observers: metrics at 10 Hz, and events (its own and
/// the simulation's, from its counters).
#[derive(Default)]
struct RemoteFeed {
    /// The last haptic status window (rate, jitter).
    window: Option<HapticWindow>,
    last_publish: f64,
    entries: u64,
    ruptures: u64,
}

/// Sends an event to the observers (none connected is not an error).
fn send_event(
    network: &crate::net::Network,
    sim: &SimStatus,
    uptime_s: f64,
    kind: EventKind,
    detail: String,
) {
    let _ = network.feeds.events.send(Event {
        sim_tick: sim.ticks,
        uptime_s,
        kind,
        detail,
    });
}

impl RemoteFeed {
    fn event(
        &self,
        network: &Option<crate::net::Network>,
        sim: &SimStatus,
        uptime_s: f64,
        kind: EventKind,
        detail: &str,
    ) {
        if let Some(n) = network {
            send_event(n, sim, uptime_s, kind, detail.to_string());
        }
    }

    fn publish(
        &mut self,
        network: &crate::net::Network,
        sim: &SimStatus,
        uptime_s: f64,
        counters: &HapticCounters,
        device_connected: bool,
    ) {
        let send = |kind, detail: String| send_event(network, sim, uptime_s, kind, detail);
        if sim.entries > self.entries {
            self.entries = sim.entries;
            send(EventKind::CutStarted, "the blade entered the tissue".into());
        }
        if sim.ruptures > self.ruptures {
            self.ruptures = sim.ruptures;
            send(
                EventKind::Rupture,
                format!("rupture: cutting, {:.1} N on the tool", sim.sim_force_n),
            );
        }
        if uptime_s - self.last_publish < 0.1 {
            return;
        }
        self.last_publish = uptime_s;
        let w = self.window;
        let metrics = Metrics {
            sim_tick: sim.ticks,
            station_tick: station_tick(uptime_s),
            uptime_s,
            haptic_rate_hz: w.map_or(0.0, |w| w.rate_hz as f32),
            jitter_p99_ms: w.map_or(0.0, |w| w.jitter_p99_ms as f32),
            deadline_misses: counters.total_misses.load(Ordering::Relaxed),
            force_n: f64::from_bits(counters.force_bits.load(Ordering::Relaxed)) as f32,
            faded: counters.watchdog_faded.load(Ordering::Relaxed),
            cut_length_mm: sim.cut_length_mm as f32,
            active_points: sim.active_points as u32,
            device_connected,
        };
        let _ = network.feeds.metrics.send(metrics);
    }
}

/// What the frame sent before a tick reports of the tick before it.
#[derive(Debug, Clone, Copy, Default)]
struct LastTick {
    force_n: Vec3,
    cutting: bool,
    in_tissue: bool,
}

/// The simulation thread's render frames.
struct SimFrames {
    station: String,
    /// Send a frame every this many ticks (0: never).
    every_ticks: u64,
    /// Told whether the frame services opened.
    opened: std::sync::mpsc::Sender<Result<(), String>>,
}

/// Simulation ticks between frames at `frame_hz` (0: no frames).
fn frame_interval_ticks(frame_hz: f64) -> u64 {
    if frame_hz > 0.0 {
        ((1.0 / (frame_hz * SIM_TICK_S)).round() as u64).max(1)
    } else {
        0
    }
}

/// How the simulation thread is scheduled.
struct SimThread {
    /// SCHED_FIFO priority (0: normal scheduling).
    fifo_priority: i32,
    /// Whether to take it: [`FIFO_PENDING`] until the haptic thread says what it got — a
    /// real-time simulation must not run above a haptic thread left at normal scheduling.
    fifo_gate: Arc<AtomicU8>,
    /// The CPUs it may run on (empty: any); the CPUs besides a pinned haptic thread's.
    cpus: Vec<usize>,
    /// Where it says whether pinning to `cpus` worked (for the start report).
    pinned: std::sync::mpsc::SyncSender<Result<(), String>>,
}

/// [`SimThread::fifo_gate`]: waiting for the haptic thread's scheduling.
const FIFO_PENDING: u8 = 0;
/// [`SimThread::fifo_gate`]: take SCHED_FIFO.
const FIFO_TAKE: u8 = 1;
/// [`SimThread::fifo_gate`]: stay at normal scheduling.
const FIFO_STAY_NORMAL: u8 = 2;

#[allow(clippy::too_many_arguments)]
fn spawn_sim(
    mut sim: Simulation,
    mut poses: rtrb::Consumer<PoseIn>,
    mut models: triple_buffer::Input<ModelUpdate>,
    mut status: triple_buffer::Input<SimStatus>,
    mut faults: triple_buffer::Output<FaultTable>,
    mut journal: SimJournal,
    frames: SimFrames,
    stop: Arc<AtomicBool>,
    t0: f64,
    thread: SimThread,
    haptic: Option<Arc<SimWake>>,
) -> std::io::Result<JoinHandle<u64>> {
    std::thread::Builder::new()
        .name("simulation".into())
        .spawn(move || {
            // Off the haptic thread's own CPU: woken by each haptic tick, the simulation
            // would otherwise often be placed beside it. Refused is not fatal (the start
            // report says so).
            let _ = thread.pinned.send(if thread.cpus.is_empty() {
                Ok(())
            } else {
                realtime::pin_thread(&thread.cpus)
            });
            let mut fifo_pending = thread.fifo_priority > 0;
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
            let mut figures = SimStatus::default();
            let mut last_tip: Option<Vec3> = None;
            let mut pose: Option<PoseIn> = None;
            let mut last = LastTick::default();
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
                            let _ = realtime::make_thread_fifo(thread.fifo_priority);
                            fifo_pending = false;
                        }
                        FIFO_STAY_NORMAL => fifo_pending = false,
                        _ => {}
                    }
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
                    sim.set_stiffness_factor(k);
                    stiffness = k;
                    figures.stiffness_factor = k;
                }
                let tool = pose.map(|p| p.pose);
                sim.set_tool(tool);
                // The frame goes out first: it shows the pose just taken (where this tick
                // puts the blade: the pose itself but for a jump faster than a hand), on the
                // surface of the last tick (a tick of cutting takes a few hundred
                // microseconds that the frame need not wait for).
                if let Some(p) = &mut publisher
                    && (figures.ticks + 1) % frames.every_ticks == 0
                    && !effects.renderer_freeze
                {
                    let info = FrameInfo {
                        sim_tick: figures.ticks,
                        tool: sim.next_blade_pose(SIM_TICK_S),
                        pose_seq: pose.map_or(0, |p| p.seq),
                        pose_received_ns: pose.map_or(0, |p| p.received_ns),
                        force_n: last.force_n,
                        cutting: last.cutting,
                        cut_length_mm: figures.cut_length_mm,
                    };
                    // A frame that cannot be sent (renderers holding every sample) is
                    // skipped and counted; the next one is a whole new frame anyway.
                    match p.publish(&sim, &info) {
                        Ok(()) => figures.frames_sent = p.frames(),
                        Err(_) => figures.frames_failed += 1,
                    }
                }
                if let Some(records) = &mut journal.records {
                    let record = TickRecord {
                        tick: figures.ticks + 1,
                        // What the simulation took (only sound poses are latched above).
                        pose: tool,
                        stiffness: stiffness_change,
                    };
                    if records.push(record).is_err() {
                        journal.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                }
                let report = sim.tick(SIM_TICK_S, &mut Unobserved);
                // Where the blade went (a pose faster than a hand is followed at a hand's
                // speed: the cut is as long as the blade's path, not the noise's).
                let tip = sim.blade_pose().map(|p| p.tip_m);
                let cutting = report
                    .cut
                    .as_ref()
                    .is_some_and(|c| c.in_tissue && c.force.phase == CutPhase::Cutting);
                if let (Some(cut), Some(tip), Some(last)) = (&report.cut, tip, last_tip)
                    && cutting
                    && !cut.withdrawing
                {
                    figures.cut_length_mm += (tip - last).norm() * 1e3;
                }
                let in_tissue = report.cut.as_ref().is_some_and(|c| c.in_tissue);
                figures.entries += u64::from(in_tissue && !last.in_tissue);
                figures.ruptures += u64::from(cutting && !last.cutting);
                last_tip = tip;
                last = LastTick {
                    force_n: report.tool_force_n,
                    cutting,
                    in_tissue,
                };
                let took_ms = (realtime::monotonic_s() - started) * 1e3;
                figures.ticks += 1;
                figures.sim_force_n = report.tool_force_n.norm();
                figures.active_points = report.active_points;
                figures.substeps = report.solver.substeps;
                figures.most_substeps = figures.most_substeps.max(report.solver.substeps);
                figures.max_tick_ms = figures.max_tick_ms.max(took_ms);
                figures.late_ticks += u64::from(took_ms > SIM_TICK_S * 1e3);
                models.write(ModelUpdate {
                    model: sim.local_force_model(),
                    tick: figures.ticks,
                });
                status.write(figures);
            }
            sim.state_hash()
        })
}
