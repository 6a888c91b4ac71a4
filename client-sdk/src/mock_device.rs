//! The mock haptic device: plays a scripted keyframe trajectory (`CutScript`, TOML or CSV)
//! to a station over shared memory at a true 1 kHz, and records every force it receives.
//!
//! "True 1 kHz": sample k is sent at t0 + k·period on the monotonic clock, sleeping to each
//! absolute deadline (never spinning), under SCHED_FIFO when the host permits it. The pose
//! of sample k is the script at exactly k·period; a wake-up a whole period late skips the
//! missed samples (a device does not send a backlog in a burst) and is counted.
//!
//! Its clock and the server's haptic loop both run at 1 kHz from unrelated origins, so a
//! pose could wait anything up to a millisecond for the haptic tick that takes it. The
//! mock therefore locks its phase once forces flow: from when the answers to its poses
//! arrive it finds the server's tick and moves its own schedule to send each pose
//! [`PHASE_LEAD_S`] before it (once, after [`PHASE_LOCK_AFTER`] samples).
//!
//! Like a real device it does not hold a force the server stopped sending: the force it
//! renders (and records) is the newest received, or zero once none has come for
//! [`DEVICE_WATCHDOG_S`].

use hdrhistogram::Histogram;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use scalpel_proto::shm::{self, DeviceForce, DevicePose, LAYOUT_VERSION, ShmError};
use scalpel_sim::pipeline::CutScript;

/// The mock sends its pose this long before the server's haptic tick (s).
pub const PHASE_LEAD_S: f64 = 2e-4;
/// Samples after which the phase is locked (forces have been flowing for a while).
pub const PHASE_LOCK_AFTER: u64 = 300;

/// Send times kept for the latency (samples).
const POSE_TIMES: usize = 256;

/// No force for this long and the device renders zero (s).
pub const DEVICE_WATCHDOG_S: f64 = 0.010;

/// Whether the device renders zero for a force received `force_age_s` ago (its watchdog).
pub fn too_old(force_age_s: f64) -> bool {
    force_age_s > DEVICE_WATCHDOG_S
}

pub use crate::frame_reader::monotonic_ns;

/// How to run the mock device.
#[derive(Debug, Clone)]
pub struct MockOptions {
    /// Samples per second.
    pub rate_hz: f64,
    /// Stop after this long (s); `None`: when the script ends (or never, if looping).
    pub duration_s: Option<f64>,
    /// Start the script again when it ends.
    pub looping: bool,
    /// SCHED_FIFO priority to ask for (0: normal scheduling).
    pub fifo_priority: u8,
    /// Lock the sending phase to just before the server's haptic tick.
    pub phase_lock: bool,
}

impl Default for MockOptions {
    fn default() -> Self {
        Self {
            rate_hz: 1000.0,
            duration_s: None,
            looping: false,
            fifo_priority: 70,
            phase_lock: true,
        }
    }
}

/// One tick of the mock device: the pose it sent and the latest force it had received.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MockTick {
    /// Script time of the pose (s).
    pub t_s: f64,
    /// The pose's sequence number.
    pub seq: u64,
    /// Blade tip sent (m).
    pub tip_m: [f64; 3],
    /// The force the device renders (N): the newest received, or zero before the first
    /// and once none has come for [`DEVICE_WATCHDOG_S`].
    pub force_n: [f64; 3],
    /// Age of the newest force received (s; infinite before the first).
    pub force_age_s: f64,
    /// Its flags (`shm::FORCE_*`).
    pub force_flags: u32,
    /// The server's haptic tick of that force (0: none yet).
    pub server_tick: u64,
    /// `pose_seq` of that force: the last pose the server had used.
    pub pose_seq: u64,
    /// Wake-up lateness of this tick (s).
    pub lateness_s: f64,
    /// Pose-to-force latency of the newest pose the server answered this tick (s).
    pub latency_s: Option<f64>,
}

/// What a run did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MockSummary {
    /// Poses sent.
    pub ticks: u64,
    /// Ticks that woke a whole period or more late.
    pub late_ticks: u64,
    /// Samples skipped because of those late wake-ups.
    pub skipped: u64,
    /// Receiving forces failed.
    pub receive_errors: u64,
    /// Ticks whose force was older than the device watchdog (rendered as zero).
    pub stale_ticks: u64,
    /// Forces received.
    pub forces_received: u64,
    /// Forces dropped: not of this layout version, or not finite.
    pub forces_rejected: u64,
    /// Largest force magnitude received (N).
    pub max_force_n: f64,
    /// The SCHED_FIFO priority in effect (0: normal scheduling).
    pub fifo_priority: u8,
    /// Achieved rate (poses per second of wall time).
    pub rate_hz: f64,
    /// Pose-to-force lag as the device feels it, median: at tick k the newest force answers
    /// pose k − lag (in device ticks; 1 = the force for the pose sent one tick earlier).
    pub lag_p50_ticks: u64,
    /// The same, 99th percentile.
    pub lag_p99_ticks: u64,
    /// Pose-to-force latencies (s): from the device stamping a pose to the server sending
    /// the first force computed with it (iceoryx2's delivery adds microseconds).
    pub latencies_s: Vec<f64>,
    /// How far the phase lock moved the schedule (s), if it did.
    pub phase_shift_s: Option<f64>,
}

/// The median of phases on a circle of circumference `period`: the median of the phases
/// unrolled from the middle of their widest gap.
fn circular_median(phases: &[f64], period: f64) -> f64 {
    let mut p: Vec<f64> = phases.iter().map(|x| x.rem_euclid(period)).collect();
    p.sort_by(f64::total_cmp);
    let n = p.len();
    // The widest gap between neighbours (the last to the first wraps).
    let (mut cut, mut widest) = (0, p[0] + period - p[n - 1]);
    for i in 1..n {
        if p[i] - p[i - 1] > widest {
            widest = p[i] - p[i - 1];
            cut = i;
        }
    }
    let mut unrolled: Vec<f64> = (0..n)
        .map(|j| {
            let x = p[(cut + j) % n];
            if (cut + j) >= n { x + period } else { x }
        })
        .collect();
    unrolled.sort_by(f64::total_cmp);
    unrolled[n / 2].rem_euclid(period)
}

/// Lags counted up to this many ticks (a larger one counts as this).
const LAG_MAX_TICKS: u64 = 1 << 16;

/// Longest wait for the station's welcome (it answers within its main loop's 10 ms).
const HELLO_TIMEOUT: Duration = Duration::from_secs(2);

/// A mock device attached to a station's device services.
pub struct MockDevice {
    poses: Publisher<ipc::Service, DevicePose, ()>,
    forces: Subscriber<ipc::Service, DeviceForce, ()>,
    _node: Node<ipc::Service>,
}

impl MockDevice {
    /// Connects to the running `station` as its device (the handshake of
    /// docs/PROTOCOL.md, then the pose publisher and the force subscriber).
    pub fn open(station: &str) -> Result<Self, ShmError> {
        let node = shm::node("scalpel-mock-device", station)?;
        shm::connect::hello(&node, station, "scalpel-mock-device", HELLO_TIMEOUT)?;
        let poses = shm::pose_service(&node, station)?
            .publisher_builder()
            .create()
            .map_err(|e| shm::iceoryx("publishing poses to station", station, e))?;
        let forces = shm::force_service(&node, station)?
            .subscriber_builder()
            .create()
            .map_err(|e| shm::iceoryx("subscribing to forces of station", station, e))?;
        Ok(Self {
            poses,
            forces,
            _node: node,
        })
    }

    /// Plays `script` until it ends (or `options.duration_s`, or `stop`), calling `on_tick`
    /// after every tick (keep it short: it runs on the device's clock).
    pub fn run(
        &mut self,
        script: &CutScript,
        options: &MockOptions,
        stop: &AtomicBool,
        mut on_tick: impl FnMut(&MockTick),
    ) -> Result<MockSummary, ShmError> {
        let mut summary = MockSummary {
            fifo_priority: make_fifo(options.fifo_priority),
            ..MockSummary::default()
        };
        let period = 1.0 / options.rate_hz;
        let end = options.duration_s.unwrap_or(if options.looping {
            f64::INFINITY
        } else {
            script.duration_s()
        });
        let mut tick = MockTick::default();
        // Made before the loop: recording within its range does not allocate.
        let mut lags = Histogram::<u64>::new_with_max(LAG_MAX_TICKS, 2).expect("a lag histogram");
        let mut newest: Option<(DeviceForce, Instant)> = None;
        let mut t0 = Instant::now();
        let t0_ns = monotonic_ns();
        // Arrival phases (s into the mock's period) of new forces, for the phase lock.
        let mut arrivals: Vec<f64> = Vec::with_capacity(PHASE_LOCK_AFTER as usize);
        let mut last_force_tick = 0;
        let mut pose_times = [(0u64, 0u64); POSE_TIMES];
        let mut last_answered = 0;
        let mut k: u64 = 0;
        while !stop.load(Ordering::Relaxed) {
            let t = k as f64 * period;
            if t > end {
                break;
            }
            let deadline = t0 + Duration::from_secs_f64(t);
            let now = Instant::now();
            if deadline > now {
                std::thread::sleep(deadline - now);
            }
            let lateness = Instant::now()
                .saturating_duration_since(deadline)
                .as_secs_f64();
            if lateness >= period {
                // A whole period late: go on from now, skipping the missed samples.
                summary.late_ticks += 1;
                let behind = (lateness / period).floor() as u64;
                summary.skipped += behind;
                k += behind;
                continue;
            }
            let script_t = if options.looping && script.duration_s() > 0.0 {
                t.rem_euclid(script.duration_s())
            } else {
                t
            };
            let pose = script.pose_at(script_t);
            let q = pose.orientation.coords;
            k += 1;
            let sample = DevicePose {
                layout_version: LAYOUT_VERSION,
                flags: 0,
                seq: k,
                device_time_ns: monotonic_ns(),
                tip_m: pose.tip_m.into(),
                orientation_xyzw: [q.x, q.y, q.z, q.w],
            };
            pose_times[(k % POSE_TIMES as u64) as usize] = (k, sample.device_time_ns);
            self.poses
                .send_copy(sample)
                .map_err(|e| shm::iceoryx("sending a pose to", "the station", e))?;
            self.drain_forces(&mut summary, &mut newest);
            // Pose-to-force latency from the timestamps: the server stamps when it sent the
            // force that first used a pose (no need to sit and watch for it).
            tick.latency_s = None;
            if let Some((f, _)) = newest
                && f.pose_seq > last_answered
            {
                last_answered = f.pose_seq;
                let (seq, sent_ns) = pose_times[(f.pose_seq % POSE_TIMES as u64) as usize];
                if seq == f.pose_seq && f.sent_time_ns >= sent_ns {
                    tick.latency_s = Some((f.sent_time_ns - sent_ns) as f64 * 1e-9);
                }
            }
            // Latencies count once the phase is locked (before, they measure where the
            // two clocks happened to start).
            if let Some(l) = tick.latency_s
                && (k > PHASE_LOCK_AFTER || !options.phase_lock)
            {
                summary.latencies_s.push(l);
            }
            if let Some((f, _)) = newest
                && f.tick != last_force_tick
            {
                last_force_tick = f.tick;
                if k > PHASE_LOCK_AFTER / 2 && k <= PHASE_LOCK_AFTER && f.tick_time_ns > t0_ns {
                    let since = (f.tick_time_ns - t0_ns) as f64 * 1e-9;
                    arrivals.push(since.rem_euclid(period));
                }
            }
            if k == PHASE_LOCK_AFTER && options.phase_lock && arrivals.len() > 10 {
                // The server's ticks land at a steady phase of our period (a circular
                // median: phases wrap at the period).
                let phase = circular_median(&arrivals, period);
                let shift = (phase - PHASE_LEAD_S).rem_euclid(period);
                t0 += Duration::from_secs_f64(shift);
                summary.phase_shift_s = Some(shift);
            }
            match newest {
                Some((f, at)) => {
                    tick.force_age_s = at.elapsed().as_secs_f64();
                    tick.force_flags = f.flags;
                    tick.server_tick = f.tick;
                    tick.pose_seq = f.pose_seq;
                    if !too_old(tick.force_age_s) {
                        tick.force_n = f.force_n;
                    } else {
                        tick.force_n = [0.0; 3];
                        summary.stale_ticks += 1;
                    }
                }
                None => {
                    tick.force_age_s = f64::INFINITY;
                    tick.force_n = [0.0; 3];
                }
            }
            if tick.pose_seq > 0 {
                let _ = lags.record((k - tick.pose_seq.min(k)).min(LAG_MAX_TICKS));
            }
            tick.t_s = t;
            tick.seq = k;
            tick.tip_m = sample.tip_m;
            tick.lateness_s = lateness;
            summary.ticks += 1;
            on_tick(&tick);
        }
        summary.rate_hz = summary.ticks as f64 / t0.elapsed().as_secs_f64().max(1e-9);
        summary.lag_p50_ticks = lags.value_at_quantile(0.5);
        summary.lag_p99_ticks = lags.value_at_quantile(0.99);
        Ok(summary)
    }
}

impl MockDevice {
    /// Takes every force waiting; keeps the newest good one with when it arrived.
    fn drain_forces(
        &mut self,
        summary: &mut MockSummary,
        newest: &mut Option<(DeviceForce, Instant)>,
    ) {
        loop {
            match self.forces.receive() {
                Ok(Some(received)) => {
                    let f = *received.payload();
                    if f.layout_version != LAYOUT_VERSION
                        || f.force_n.iter().any(|c| !c.is_finite())
                    {
                        summary.forces_rejected += 1;
                        continue;
                    }
                    summary.forces_received += 1;
                    let magnitude = f.force_n.iter().map(|c| c * c).sum::<f64>().sqrt();
                    summary.max_force_n = summary.max_force_n.max(magnitude);
                    *newest = Some((f, Instant::now()));
                }
                Ok(None) => return,
                Err(_) => {
                    summary.receive_errors += 1;
                    return;
                }
            }
        }
    }
}

/// Asks for SCHED_FIFO for the calling thread; returns the priority granted (0: not
/// permitted, normal scheduling).
pub fn make_fifo(priority: u8) -> u8 {
    use thread_priority::{
        RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
        set_thread_priority_and_policy, thread_native_id,
    };
    if priority == 0 {
        return 0;
    }
    let Ok(value) = ThreadPriorityValue::try_from(priority) else {
        return 0;
    };
    match set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    ) {
        Ok(()) => priority,
        Err(_) => 0,
    }
}
