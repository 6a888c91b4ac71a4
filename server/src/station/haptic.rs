//! The haptic thread: its loop state ([`HapticState`], one tick of device pose in, virtual
//! coupling on the latest force model, output stage, force out), the thread that runs it on
//! the station's 1 ms grid ([`spawn_haptic`]), the atomic counters it keeps for the main
//! thread ([`HapticCounters`], [`HapticWindow`]), and [`drive_haptic_ticks`] for the
//! allocation test.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::thread::JoinHandle;

use scalpel_sim::force::LocalForceModel;
use scalpel_sim::math::Vec3;

use crate::device::{DeviceFactory, DeviceSample, ForceStatus, HapticDevice};
use crate::faults::{FaultTable, HapticEffects};
use crate::grid_clock::GridClock;
use crate::output::{OutputInput, OutputLimits, OutputReport, OutputStage};
use crate::realtime;
use crate::sim_wake::SimWake;

use super::{ModelUpdate, POSE_RING, PoseIn, station_tick};

/// Jitter histogram: bins of this width (s) ...
const JITTER_BIN_S: f64 = 5e-6;
/// ... this many of them (the last collects everything later).
const JITTER_BINS: usize = 1000;

/// Device samples a latency fault can hold back (a second at 1 kHz, and room).
const DELAY_LINE: usize = 2048;

/// Counters the haptic thread keeps with atomics only; the main thread reads and resets the
/// windowed ones.
pub struct HapticCounters {
    ticks: AtomicU64,
    misses: AtomicU64,
    jitter: Vec<AtomicU32>,
    max_jitter_ns: AtomicU64,
    pub(super) force_bits: AtomicU64,
    nan_guards: AtomicU64,
    pub(super) watchdog_faded: AtomicBool,
    passivity_ticks: AtomicU64,
    passivity_energy_bits: AtomicU64,
    pub(super) total_ticks: AtomicU64,
    pub(super) total_misses: AtomicU64,
    pub(super) ring_full: AtomicU64,
}

impl HapticCounters {
    pub(super) fn new() -> Self {
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
    pub(super) fn take_window(&self, seconds: f64) -> HapticWindow {
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

#[derive(Clone, Copy)]
pub(super) struct HapticContext {
    pub(super) period_s: f64,
    pub(super) fifo_priority: i32,
    pub(super) cpu: Option<usize>,
    pub(super) limits: OutputLimits,
    pub(super) t0: f64,
}

/// What the haptic thread reports once it has set itself up.
pub(super) struct HapticReady {
    /// The SCHED_FIFO priority granted, or why not.
    pub(super) fifo: Result<i32, String>,
    /// The CPU the thread has to itself, or why not.
    pub(super) cpu: Result<Option<usize>, String>,
    /// The device opened, or why not.
    pub(super) device: Result<(), String>,
}

#[allow(clippy::too_many_arguments)]
pub(super) fn spawn_haptic(
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
