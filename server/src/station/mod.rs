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

mod commands;
mod haptic;
mod journal_writer;
mod remote_feed;
mod sim_thread;

pub use haptic::{HapticCounters, HapticState, HapticWindow, drive_haptic_ticks};

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::thread::JoinHandle;

use scalpel_sim::cut::ToolPose;
use scalpel_sim::force::LocalForceModel;
use scalpel_sim::math::{Mat3, Vec3};
use scalpel_sim::pipeline::Simulation;
use scalpel_sim::scene::BuiltScene;

use crate::device::DeviceFactory;
use crate::device_monitor::{DeviceEvent, DeviceMonitor};
use crate::faults::{FaultTable, Transition};
use crate::journal::{self, TickRecord};
use crate::output::OutputLimits;
use crate::realtime;
use crate::sim_wake::SimWake;
use scalpel_proto::wire::EventKind;

use commands::{CommandDesk, Moment};
use haptic::{HapticContext, HapticReady, spawn_haptic};
use journal_writer::{JOURNAL_RING, SimJournal, spawn_journal_writer};
use remote_feed::RemoteFeed;
use sim_thread::{
    FIFO_PENDING, FIFO_STAY_NORMAL, FIFO_TAKE, SimFrames, SimThread, frame_interval_ticks,
    spawn_sim,
};

/// Poses in flight from the haptic to the simulation thread.
const POSE_RING: usize = 256;
/// Simulated time per simulation tick (s).
pub(crate) const SIM_TICK_S: f64 = scalpel_sim::pipeline::SIMULATION_TICK_S;

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
    /// The force on the tool as the tissue last ruptured: the peak before the drop (N).
    pub rupture_force_n: f64,
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
            rupture_force_n: 0.0,
            stiffness_factor: 1.0,
        }
    }
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
    /// Whose poses the shared-memory device takes (set by the monitor when a device
    /// connects).
    pub device_gate: Arc<crate::shm_device::DeviceGate>,
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
    sim: Simulation,
    device: DeviceFactory,
    params: &StationParams,
    journal: Option<std::io::BufWriter<std::fs::File>>,
    stop: Arc<AtomicBool>,
    mut report: impl FnMut(&StationReport),
) -> anyhow::Result<RunSummary> {
    let mut warnings = Vec::new();
    let hand_offs = HandOffs::new();
    refuse_taken_station(params, &mut warnings)?;
    let (haptic_cpu, other_cpus) = split_cpus(params, &mut warnings);
    // The station's shared memory first (nothing may take its services), then the network
    // endpoint: if either fails, no thread has started yet.
    let monitor = open_monitor(params, &mut warnings)?;
    let network = start_network(params, &other_cpus)?;
    let built = start_clock_and_journal(sim, journal)?;
    let (threads, start_channels) = Threads::spawn(
        device,
        params,
        hand_offs,
        built,
        haptic_cpu,
        &other_cpus,
        &stop,
    )?;
    let started =
        start_channels.collect(params, &threads.haptic_thread, &other_cpus, &mut warnings);
    let memory_locked = lock_memory_if_asked(params, &started.device_error, &mut warnings);
    if let Some(e) = &started.device_error {
        threads.abandon(&stop);
        anyhow::bail!("cannot open the device: {e}");
    }
    let mut station = Station {
        params,
        stop,
        threads,
        monitor,
        network,
        warnings,
    };
    station.report_start(&started, memory_locked, &other_cpus, &mut report);
    station.status_loop(scene, &mut report);
    station.shut_down(started.fifo_priority, memory_locked)
}

/// The hand-offs between the threads, and the channels on which the threads report their
/// start, made before anything starts.
struct HandOffs {
    pose_in: rtrb::Producer<PoseIn>,
    pose_out: rtrb::Consumer<PoseIn>,
    model_in: triple_buffer::Input<ModelUpdate>,
    model_out: triple_buffer::Output<ModelUpdate>,
    status_in: triple_buffer::Input<SimStatus>,
    status_out: triple_buffer::Output<SimStatus>,
    faults_to_haptic: triple_buffer::Input<FaultTable>,
    faults_haptic: triple_buffer::Output<FaultTable>,
    faults_to_sim: triple_buffer::Input<FaultTable>,
    faults_sim: triple_buffer::Output<FaultTable>,
    counters: Arc<HapticCounters>,
    ready_tx: std::sync::mpsc::Sender<HapticReady>,
    ready_rx: std::sync::mpsc::Receiver<HapticReady>,
    frames_tx: std::sync::mpsc::Sender<Result<(), String>>,
    frames_rx: std::sync::mpsc::Receiver<Result<(), String>>,
}

impl HandOffs {
    /// Makes the pose ring, the triple buffers, the haptic counters and the start channels.
    fn new() -> Self {
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
        let (status_in, status_out) = triple_buffer::triple_buffer(&SimStatus::default());
        // The instructor's faults, one table per real-time thread.
        let (faults_to_haptic, faults_haptic) =
            triple_buffer::triple_buffer(&FaultTable::default());
        let (faults_to_sim, faults_sim) = triple_buffer::triple_buffer(&FaultTable::default());
        let counters = Arc::new(HapticCounters::new());
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (frames_tx, frames_rx) = std::sync::mpsc::channel();
        Self {
            pose_in,
            pose_out,
            model_in,
            model_out,
            status_in,
            status_out,
            faults_to_haptic,
            faults_haptic,
            faults_to_sim,
            faults_sim,
            counters,
            ready_tx,
            ready_rx,
            frames_tx,
            frames_rx,
        }
    }
}

/// Refuses a station that already has a live server; warns when that cannot be checked.
fn refuse_taken_station(params: &StationParams, warnings: &mut Vec<String>) -> anyhow::Result<()> {
    // One server per station: the services are the station's.
    match scalpel_proto::shm::station_nodes(&params.station) {
        Ok(nodes) => {
            if let Some(n) = live_server(&nodes) {
                anyhow::bail!("{}", station_taken(&params.station, n));
            }
        }
        Err(e) => warnings.push(format!("{e}: cannot check that the station is free")),
    }
    Ok(())
}

/// The haptic thread's CPU, if it can have one to itself, and the CPUs for the other threads.
fn split_cpus(params: &StationParams, warnings: &mut Vec<String>) -> (Option<usize>, Vec<usize>) {
    // The haptic thread's own CPU, if one is given: the simulation and the network threads
    // run on the others.
    let cpus = realtime::allowed_cpus();
    match params.haptic_cpu {
        Some(c) => match realtime::cpus_besides(c, &cpus) {
            Ok(others) => (Some(c), others),
            Err(e) => {
                warnings.push(format!("{e}: the haptic thread shares its CPU"));
                (None, Vec::new())
            }
        },
        None => (None, Vec::new()),
    }
}

/// Starts the network endpoint on `other_cpus`, if the station has one.
fn start_network(
    params: &StationParams,
    other_cpus: &[usize],
) -> anyhow::Result<Option<crate::net::Network>> {
    let network = match &params.network {
        Some(n) => Some(crate::net::start(crate::net::NetworkParams {
            cpus: other_cpus.to_vec(),
            ..n.clone()
        })?),
        None => None,
    };
    Ok(network)
}

/// Makes the station's shared-memory services and opens their monitor. A service another
/// live process made refuses the start; any other failure of shared memory only matters to
/// a station whose device is on it (the others run without frames and clean-up).
fn open_monitor(
    params: &StationParams,
    warnings: &mut Vec<String>,
) -> anyhow::Result<Option<DeviceMonitor>> {
    let monitor = match DeviceMonitor::open(&params.station, params.device_gate.clone()) {
        Ok(m) => {
            for service in m.reused() {
                warnings.push(format!(
                    "{service}: took over what a previous server of this station left"
                ));
            }
            Some(m)
        }
        Err(e @ scalpel_proto::shm::ShmError::Taken { .. }) => {
            return Err(anyhow::anyhow!(
                "station {}'s shared memory is taken: {e}",
                params.station
            ));
        }
        Err(e) if !params.monitor_device => {
            warnings.push(format!("{e}: no shared-memory clean-up"));
            None
        }
        Err(e) => return Err(e.into()),
    };
    Ok(monitor)
}

/// The prepared simulation, the station clock's start and the journal's writer thread.
struct SimAndJournal {
    sim: Simulation,
    /// Station tick 0 (CLOCK_MONOTONIC, s).
    t0: f64,
    journal_dropped: Arc<AtomicU64>,
    sim_done: Arc<AtomicBool>,
    commands_journal: std::sync::mpsc::Sender<String>,
    records_in: Option<rtrb::Producer<TickRecord>>,
    writer: Option<JoinHandle<std::io::Result<std::io::BufWriter<std::fs::File>>>>,
}

/// The station's simulation of `scene`, built and prepared: everything the loops use is
/// allocated up front, and the stable step and the mass scaling to whole sub-steps (power
/// iterations) are found here, not in the first real-time tick. Seconds for a large scene:
/// the server does it while it can still be stopped (before [`run`]).
pub fn prepare_simulation(scene: &BuiltScene) -> Simulation {
    let mut sim = Simulation::new(scene);
    // The re-cut worker, spawned here (normal scheduling, any CPU: recut_worker.rs).
    crate::recut_worker::attach(&mut sim);
    sim.prepare(SIM_TICK_S);
    sim
}

/// Starts the station clock and the journal writer for the prepared `sim`.
fn start_clock_and_journal(
    sim: Simulation,
    journal: Option<std::io::BufWriter<std::fs::File>>,
) -> anyhow::Result<SimAndJournal> {
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
    Ok(SimAndJournal {
        sim,
        t0,
        journal_dropped,
        sim_done,
        commands_journal,
        records_in,
        writer,
    })
}

/// The started threads, and the main thread's ends of their hand-offs.
struct Threads {
    haptic_thread: Option<JoinHandle<()>>,
    sim_thread: JoinHandle<u64>,
    writer: Option<JoinHandle<std::io::Result<std::io::BufWriter<std::fs::File>>>>,
    /// Station tick 0 (CLOCK_MONOTONIC, s).
    t0: f64,
    sim_done: Arc<AtomicBool>,
    journal_dropped: Arc<AtomicU64>,
    commands_journal: std::sync::mpsc::Sender<String>,
    status_out: triple_buffer::Output<SimStatus>,
    faults_to_haptic: triple_buffer::Input<FaultTable>,
    faults_to_sim: triple_buffer::Input<FaultTable>,
    counters: Arc<HapticCounters>,
}

/// Where the threads report how their start went, and the simulation's SCHED_FIFO gate.
struct StartChannels {
    ready_rx: std::sync::mpsc::Receiver<HapticReady>,
    sim_fifo_gate: Arc<AtomicU8>,
    sim_pinned_rx: std::sync::mpsc::Receiver<Result<(), String>>,
    frames_rx: std::sync::mpsc::Receiver<Result<(), String>>,
}

/// What the threads reported as they started.
struct Started {
    /// The haptic thread's SCHED_FIFO priority (0: normal scheduling).
    fifo_priority: i32,
    /// The CPU the haptic thread has to itself.
    pinned_cpu: Option<usize>,
    /// Why the device did not open (or the haptic thread did not start).
    device_error: Option<String>,
    /// The simulation thread runs on the other CPUs.
    sim_pinned: bool,
    /// Render frames are sent.
    frames_running: bool,
}

impl Threads {
    /// Spawns the simulation thread and, with haptics, the haptic thread on the hand-offs.
    fn spawn(
        device: DeviceFactory,
        params: &StationParams,
        hand_offs: HandOffs,
        built: SimAndJournal,
        haptic_cpu: Option<usize>,
        other_cpus: &[usize],
        stop: &Arc<AtomicBool>,
    ) -> anyhow::Result<(Self, StartChannels)> {
        let t0 = built.t0;
        // The haptic thread wakes the simulation thread once its tick is done.
        let sim_wake = params.haptics.then(|| Arc::new(SimWake::new()));
        let sim_fifo_gate = Arc::new(AtomicU8::new(FIFO_PENDING));
        let (sim_pinned_tx, sim_pinned_rx) = std::sync::mpsc::sync_channel(1);
        let sim_thread = spawn_sim(
            built.sim,
            hand_offs.pose_out,
            hand_offs.model_in,
            hand_offs.status_in,
            hand_offs.faults_sim,
            SimJournal {
                records: built.records_in,
                dropped: built.journal_dropped.clone(),
            },
            SimFrames {
                station: params.station.clone(),
                every_ticks: frame_interval_ticks(params.frame_hz),
                opened: hand_offs.frames_tx,
            },
            stop.clone(),
            t0,
            SimThread {
                fifo_priority: params.sim_fifo_priority,
                fifo_gate: sim_fifo_gate.clone(),
                cpus: other_cpus.to_vec(),
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
                hand_offs.pose_in,
                hand_offs.model_out,
                hand_offs.faults_haptic,
                hand_offs.counters.clone(),
                stop.clone(),
                hand_offs.ready_tx,
            )?)
        } else {
            drop((
                device,
                hand_offs.pose_in,
                hand_offs.model_out,
                hand_offs.faults_haptic,
                hand_offs.ready_tx,
            ));
            None
        };
        Ok((
            Self {
                haptic_thread,
                sim_thread,
                writer: built.writer,
                t0,
                sim_done: built.sim_done,
                journal_dropped: built.journal_dropped,
                commands_journal: built.commands_journal,
                status_out: hand_offs.status_out,
                faults_to_haptic: hand_offs.faults_to_haptic,
                faults_to_sim: hand_offs.faults_to_sim,
                counters: hand_offs.counters,
            },
            StartChannels {
                ready_rx: hand_offs.ready_rx,
                sim_fifo_gate,
                sim_pinned_rx,
                frames_rx: hand_offs.frames_rx,
            },
        ))
    }

    /// Stops the threads after a device error and waits for them and the journal writer.
    fn abandon(self, stop: &AtomicBool) {
        let Threads {
            haptic_thread,
            sim_thread,
            writer,
            sim_done,
            ..
        } = self;
        stop.store(true, Ordering::Relaxed);
        if let Some(h) = haptic_thread {
            let _ = h.join();
        }
        let _ = sim_thread.join();
        sim_done.store(true, Ordering::Release);
        if let Some(w) = writer {
            let _ = w.join();
        }
    }
}

impl StartChannels {
    /// Waits for the start reports (device, SCHED_FIFO, pinning, frames) and opens the
    /// simulation's SCHED_FIFO gate accordingly.
    fn collect(
        self,
        params: &StationParams,
        haptic_thread: &Option<JoinHandle<()>>,
        other_cpus: &[usize],
        warnings: &mut Vec<String>,
    ) -> Started {
        let StartChannels {
            ready_rx,
            sim_fifo_gate,
            sim_pinned_rx,
            frames_rx,
        } = self;
        let mut fifo_priority = 0;
        let mut pinned_cpu = None;
        let device_error = match (haptic_thread, ready_rx.recv()) {
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
        Started {
            fifo_priority,
            pinned_cpu,
            device_error,
            sim_pinned,
            frames_running,
        }
    }
}

/// Locks memory if asked to and the device opened; whether it is locked.
fn lock_memory_if_asked(
    params: &StationParams,
    device_error: &Option<String>,
    warnings: &mut Vec<String>,
) -> bool {
    let mut memory_locked = false;
    // Locked once the threads, their stacks, the device's and the frames' shared memory
    // and the hand-off buffers exist.
    if params.lock_memory && device_error.is_none() {
        match realtime::lock_memory() {
            Ok(()) => memory_locked = true,
            Err(e) => warnings.push(format!("{e}: the haptic loop may wait on page faults")),
        }
    }
    memory_locked
}

/// A started station, as the main thread holds it while it runs.
struct Station<'a> {
    params: &'a StationParams,
    stop: Arc<AtomicBool>,
    // Field order is drop order: the threads' handles, then the monitor, then the network
    // endpoint.
    threads: Threads,
    monitor: Option<DeviceMonitor>,
    network: Option<crate::net::Network>,
    /// Why some real-time request was not granted.
    warnings: Vec<String>,
}

impl Station<'_> {
    /// Reports what runs and what is off, the station clock, and the warnings.
    fn report_start(
        &self,
        started: &Started,
        memory_locked: bool,
        other_cpus: &[usize],
        mut report: impl FnMut(&StationReport),
    ) {
        let Station {
            params,
            network,
            monitor,
            threads,
            warnings,
            ..
        } = self;
        let Started {
            fifo_priority,
            pinned_cpu,
            sim_pinned,
            frames_running,
            ..
        } = *started;
        let (haptic_thread, t0) = (&threads.haptic_thread, threads.t0);
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
        for w in warnings {
            report(&StationReport::Event(StationEvent {
                uptime_s: realtime::monotonic_s() - t0,
                event: format!("warning: {w}"),
            }));
        }
    }

    /// Runs the main thread's loop until `stop` (instructors' commands, faults, device
    /// events, the remote feed, status lines), then writes out the audit's last refusals.
    fn status_loop(&mut self, scene: &BuiltScene, mut report: impl FnMut(&StationReport)) {
        let Station {
            params,
            stop,
            network,
            monitor,
            threads:
                Threads {
                    t0,
                    haptic_thread,
                    sim_thread,
                    commands_journal,
                    status_out,
                    faults_to_haptic,
                    faults_to_sim,
                    counters,
                    ..
                },
            ..
        } = self;
        let t0 = *t0;
        let mut next = t0 + params.status_interval_s;
        let mut window_start = t0;
        let mut remote = RemoteFeed::default();
        let mut desk = CommandDesk::new(scene.spec.features.stiff_mode);
        let mut stream_lost = false;
        // The table the threads have (rebuilt only when the book changes).
        let mut table = FaultTable::default();
        while !stop.load(Ordering::Relaxed) {
            // Every 10 ms: instructors' commands are answered within that.
            realtime::sleep_until(next.min(realtime::monotonic_s() + 0.01));
            let now = realtime::monotonic_s();
            let sim_now = *status_out.read();
            let tick = station_tick(now - t0);
            let mut table_changed = false;
            if let Some(n) = &network {
                // Refused connections, said or summed up by the endpoint.
                while let Ok(line) = n.log.try_recv() {
                    report(&StationReport::Event(StationEvent {
                        uptime_s: now - t0,
                        event: line,
                    }));
                }
                table_changed |= desk.answer(
                    n,
                    &Moment {
                        sim: &sim_now,
                        uptime_s: now - t0,
                        tick,
                    },
                    commands_journal,
                    &mut report,
                );
            }
            for transition in desk.book.advance(tick) {
                table_changed = true;
                let (kind, text) = match transition {
                    Transition::Applied(t) => (EventKind::FaultApplied, format!("{t}: applied")),
                    Transition::Ended(t) => (EventKind::FaultCleared, t),
                };
                remote.event(network, &sim_now, now - t0, kind, &text);
                report(&StationReport::Event(StationEvent {
                    uptime_s: now - t0,
                    event: text,
                }));
            }
            if table_changed {
                table = desk.book.table();
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
            if let Some(m) = &mut *monitor
                && let Some(change) = m.poll(now - t0)
                && params.monitor_device
            {
                let (kind, text) = match change {
                    DeviceEvent::Connected(name) => (
                        EventKind::DeviceConnected,
                        format!("device connected ({name})"),
                    ),
                    DeviceEvent::Refused(name, why) => {
                        (EventKind::Notice, format!("device {name} refused: {why}"))
                    }
                    DeviceEvent::Lost => (
                        EventKind::DeviceLost,
                        format!(
                            "device lost (dead nodes cleaned so far: {}); the force fades to zero",
                            m.dead_nodes_cleaned()
                        ),
                    ),
                };
                remote.event(network, &sim_now, now - t0, kind, &text);
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
                    counters,
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
        let sim_now = *status_out.read();
        let at = Moment {
            sim: &sim_now,
            uptime_s: now - t0,
            tick: station_tick(now - t0),
        };
        desk.close(&at, commands_journal, &mut report);
    }

    /// Joins the threads, stops the network endpoint, closes the journal with its footer
    /// and sums up the run.
    fn shut_down(self, fifo_priority: i32, memory_locked: bool) -> anyhow::Result<RunSummary> {
        let Station {
            network,
            threads:
                Threads {
                    haptic_thread,
                    sim_thread,
                    writer,
                    sim_done,
                    journal_dropped,
                    mut status_out,
                    counters,
                    ..
                },
            warnings,
            ..
        } = self;
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
}
