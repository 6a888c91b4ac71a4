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
mod control;
mod haptic;
mod journal_writer;
mod remote_feed;
mod report;
mod sharing;
mod sim_thread;
mod startup;
mod tick_times;

pub use haptic::{HapticCounters, HapticState, HapticWindow, drive_haptic_ticks};
pub use report::{RunSummary, SimStatus, StationEvent, StationReport, StatusLine, stages_text};
pub use startup::prepare_simulation;
pub use tick_times::{TICK_BIN_MS, TICK_BINS, TickTimes};

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use scalpel_sim::cut::ToolPose;
use scalpel_sim::force::LocalForceModel;
use scalpel_sim::scene::BuiltScene;

use crate::device::DeviceFactory;
use crate::output::OutputLimits;

use control::Station;
use startup::{
    HandOffs, Threads, lock_memory_if_asked, open_monitor, refuse_taken_station, split_cpus,
    start_clock_and_journal, start_network,
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
    /// Threads for the simulation, its own included (config `realtime.sim_threads`).
    pub sim_threads: usize,
    /// The simulation threads' nice value under normal scheduling (`realtime.sim_nice`).
    pub sim_nice: i32,
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
    /// The lesson the station's sessions are scored on, laid on its scene (docs/LESSONS.md).
    pub lesson: Option<scalpel_sim::lesson::Plan>,
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
    sim: scalpel_sim::pipeline::Simulation,
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
