//! A station's start: the hand-offs between its threads, the checks before anything
//! starts (a live server on the station, the CPUs), its shared memory and network endpoint,
//! the simulation's clock and journal, and the threads themselves.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::thread::JoinHandle;

use scalpel_sim::force::LocalForceModel;
use scalpel_sim::math::{Mat3, Vec3};
use scalpel_sim::pipeline::Simulation;
use scalpel_sim::scene::BuiltScene;

use crate::device::DeviceFactory;
use crate::device_monitor::DeviceMonitor;
use crate::faults::FaultTable;
use crate::journal::TickRecord;
use crate::realtime;
use crate::sim_pool::usable_threads;
use crate::sim_wake::SimWake;

use super::haptic::{HapticContext, HapticReady, spawn_haptic};
use super::journal_writer::{JOURNAL_RING, SimJournal, spawn_journal_writer};
use super::sim_thread::{
    FIFO_PENDING, FIFO_STAY_NORMAL, FIFO_TAKE, SimFrames, SimStart, SimThread,
    frame_interval_ticks, spawn_sim,
};
use super::{
    HapticCounters, ModelUpdate, POSE_RING, PoseIn, SIM_TICK_S, SimStatus, StationParams,
    live_server, station_taken,
};

/// The hand-offs between the threads, and the channels on which the threads report their
/// start, made before anything starts.
pub(super) struct HandOffs {
    pub(super) pose_in: rtrb::Producer<PoseIn>,
    pub(super) pose_out: rtrb::Consumer<PoseIn>,
    pub(super) model_in: triple_buffer::Input<ModelUpdate>,
    pub(super) model_out: triple_buffer::Output<ModelUpdate>,
    pub(super) status_in: triple_buffer::Input<SimStatus>,
    pub(super) status_out: triple_buffer::Output<SimStatus>,
    pub(super) faults_to_haptic: triple_buffer::Input<FaultTable>,
    pub(super) faults_haptic: triple_buffer::Output<FaultTable>,
    pub(super) faults_to_sim: triple_buffer::Input<FaultTable>,
    pub(super) faults_sim: triple_buffer::Output<FaultTable>,
    pub(super) counters: Arc<HapticCounters>,
    pub(super) ready_tx: std::sync::mpsc::Sender<HapticReady>,
    pub(super) ready_rx: std::sync::mpsc::Receiver<HapticReady>,
    pub(super) frames_tx: std::sync::mpsc::Sender<Result<(), String>>,
    pub(super) frames_rx: std::sync::mpsc::Receiver<Result<(), String>>,
}

impl HandOffs {
    /// Makes the pose ring, the triple buffers, the haptic counters and the start channels.
    pub(super) fn new() -> Self {
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
pub(super) fn refuse_taken_station(
    params: &StationParams,
    warnings: &mut Vec<String>,
) -> anyhow::Result<()> {
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
pub(super) fn split_cpus(
    params: &StationParams,
    warnings: &mut Vec<String>,
) -> (Option<usize>, Vec<usize>) {
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
pub(super) fn start_network(
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
pub(super) fn open_monitor(
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
pub(super) struct SimAndJournal {
    pub(super) sim: Simulation,
    /// Station tick 0 (CLOCK_MONOTONIC, s).
    pub(super) t0: f64,
    pub(super) journal_dropped: Arc<AtomicU64>,
    pub(super) sim_done: Arc<AtomicBool>,
    pub(super) commands_journal: std::sync::mpsc::Sender<String>,
    pub(super) records_in: Option<rtrb::Producer<TickRecord>>,
    pub(super) writer: Option<JoinHandle<std::io::Result<std::io::BufWriter<std::fs::File>>>>,
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
pub(super) fn start_clock_and_journal(
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
pub(super) struct Threads {
    pub(super) haptic_thread: Option<JoinHandle<()>>,
    pub(super) sim_thread: JoinHandle<u64>,
    pub(super) writer: Option<JoinHandle<std::io::Result<std::io::BufWriter<std::fs::File>>>>,
    /// Station tick 0 (CLOCK_MONOTONIC, s).
    pub(super) t0: f64,
    pub(super) sim_done: Arc<AtomicBool>,
    pub(super) journal_dropped: Arc<AtomicU64>,
    pub(super) commands_journal: std::sync::mpsc::Sender<String>,
    pub(super) status_out: triple_buffer::Output<SimStatus>,
    pub(super) faults_to_haptic: triple_buffer::Input<FaultTable>,
    pub(super) faults_to_sim: triple_buffer::Input<FaultTable>,
    pub(super) counters: Arc<HapticCounters>,
}

/// Where the threads report how their start went, and the simulation's SCHED_FIFO gate.
pub(super) struct StartChannels {
    pub(super) ready_rx: std::sync::mpsc::Receiver<HapticReady>,
    pub(super) sim_fifo_gate: Arc<AtomicU8>,
    pub(super) sim_started_rx: std::sync::mpsc::Receiver<SimStart>,
    pub(super) frames_rx: std::sync::mpsc::Receiver<Result<(), String>>,
}

/// What the threads reported as they started.
pub(super) struct Started {
    /// The haptic thread's SCHED_FIFO priority (0: normal scheduling).
    pub(super) fifo_priority: i32,
    /// The CPU the haptic thread has to itself.
    pub(super) pinned_cpu: Option<usize>,
    /// Why the device did not open (or the haptic thread did not start).
    pub(super) device_error: Option<String>,
    /// The simulation thread runs on the other CPUs.
    pub(super) sim_pinned: bool,
    /// The threads the simulation runs on, its own included.
    pub(super) sim_threads: usize,
    /// Render frames are sent.
    pub(super) frames_running: bool,
}

impl Threads {
    /// Spawns the simulation thread and, with haptics, the haptic thread on the hand-offs.
    pub(super) fn spawn(
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
        let (sim_started_tx, sim_started_rx) = std::sync::mpsc::sync_channel(1);
        // Read here: the simulation thread's own is its pinned CPUs.
        let allowed = realtime::allowed_cpus();
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
                threads: usable_threads(params.sim_threads, allowed.len()),
                // The worker on the other CPUs when there are two; else anywhere (on two
                // CPUs with a haptic CPU, beside the haptic thread, below its priority),
                // said explicitly, as a thread inherits the pinned simulation's CPUs.
                worker_cpus: if other_cpus.len() >= 2 || other_cpus.is_empty() {
                    other_cpus.to_vec()
                } else {
                    allowed
                },
                nice: params.sim_nice,
                started: sim_started_tx,
                max_stiffness_n_per_m: params.limits.max_stiffness_n_per_m,
                scorer: params
                    .lesson
                    .as_ref()
                    .map(|plan| scalpel_sim::lesson::Scorer::new(plan.clone())),
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
                sim_started_rx,
                frames_rx: hand_offs.frames_rx,
            },
        ))
    }

    /// Stops the threads after a device error and waits for them and the journal writer.
    pub(super) fn abandon(self, stop: &AtomicBool) {
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
    pub(super) fn collect(
        self,
        params: &StationParams,
        haptic_thread: &Option<JoinHandle<()>>,
        other_cpus: &[usize],
        warnings: &mut Vec<String>,
    ) -> Started {
        let StartChannels {
            ready_rx,
            sim_fifo_gate,
            sim_started_rx,
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
        // Sent once the simulation knows its scheduling (the gate above) and made its pool.
        let (mut sim_pinned, mut sim_threads) = (false, 1);
        if let Ok(start) = sim_started_rx.recv() {
            match start.pinned {
                Ok(()) => sim_pinned = !other_cpus.is_empty(),
                Err(e) => warnings.push(format!(
                    "{e}: the simulation thread may share the haptic thread's CPU"
                )),
            }
            sim_threads = start.threads;
            warnings.extend(start.warnings);
        }
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
            sim_threads,
            frames_running,
        }
    }
}

/// Locks memory if asked to and the device opened; whether it is locked.
pub(super) fn lock_memory_if_asked(
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
