//! What a station reports: the simulation's figures, the status line, events, and the run's
//! summary.

use super::HapticWindow;

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
    /// Of the late ticks, those whose own CPU time was longer than the simulated time: the
    /// simulation's cost. The others were kept off the CPU (another thread, the host).
    pub late_ticks_cpu: u64,
    /// Longest tick so far in the thread's own CPU time (ms).
    pub max_tick_cpu_ms: f64,
    /// Ticks that shared their work with the simulation's worker (the others ran on its
    /// thread alone: too small, a single-thread station, or faster so at this station).
    pub shared_ticks: u64,
    /// Every tick's wall time so far (shown as its p50, p99 and p99.9).
    pub tick_times: super::TickTimes,
    /// Re-cuts of the incision whose result the simulation waited for at its tick (the
    /// re-cut worker had not finished it within the hand-over).
    pub recuts_waited: u64,
    /// The longest tick so far (by wall time), stage by stage: where a late tick went.
    pub slowest_tick: SlowestTick,
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
    /// The lesson's metrics, when the station runs one (every 10 ticks).
    pub lesson: Option<scalpel_sim::lesson::Metrics>,
}

/// One simulation tick's cost, stage by stage (`scalpel_sim::pipeline::Stage`, in tick
/// order), for the status line: the slowest tick of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SlowestTick {
    /// The tick's number (the journal's).
    pub tick: u64,
    /// Its wall time (ms): the whole tick, its frame and journal record included.
    pub wall_ms: f64,
    /// The thread's CPU time over it (ms).
    pub cpu_ms: f64,
    /// Wall time of each of the core's stages (ms), by name.
    pub stages_ms: [(&'static str, f64); STAGES],
}

/// `stages_ms` as "name ms, …", leaving out the stages under 0.01 ms (a tick's line).
pub fn stages_text(stages_ms: &[(&'static str, f64)]) -> String {
    let parts: Vec<String> = stages_ms
        .iter()
        .filter(|(_, ms)| *ms >= 0.01)
        .map(|(name, ms)| format!("{name} {ms:.2}"))
        .collect();
    parts.join(", ")
}

/// The core's stages.
const STAGES: usize = scalpel_sim::pipeline::Stage::ALL.len();

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
            late_ticks_cpu: 0,
            max_tick_cpu_ms: 0.0,
            shared_ticks: 0,
            tick_times: super::TickTimes::default(),
            recuts_waited: 0,
            slowest_tick: SlowestTick::default(),
            frames_sent: 0,
            frames_failed: 0,
            entries: 0,
            ruptures: 0,
            rupture_force_n: 0.0,
            stiffness_factor: 1.0,
            lesson: None,
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
    Status(Box<StatusLine>),
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
