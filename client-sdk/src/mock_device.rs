//! The mock haptic device: plays a scripted keyframe trajectory (`CutScript`, TOML or CSV)
//! to a station over shared memory at a true 1 kHz, and records every force it receives.
//!
//! "True 1 kHz": sample k is sent at t0 + k·period on the monotonic clock, sleeping to each
//! absolute deadline (never spinning), under SCHED_FIFO when the host permits it. The pose
//! of sample k is the script at exactly k·period, so a run is the same trajectory however
//! late a wake-up was; late wake-ups are counted, not hidden.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use scalpel_proto::shm::{self, DeviceForce, DevicePose, LAYOUT_VERSION, ShmError};
use scalpel_sim::pipeline::CutScript;

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
}

impl Default for MockOptions {
    fn default() -> Self {
        Self {
            rate_hz: 1000.0,
            duration_s: None,
            looping: false,
            fifo_priority: 70,
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
    /// The newest force received by now (N); zero before the first.
    pub force_n: [f64; 3],
    /// Its flags (`shm::FORCE_*`).
    pub force_flags: u32,
    /// The server's haptic tick of that force (0: none yet).
    pub server_tick: u64,
    /// `pose_seq` of that force: the last pose the server had used.
    pub pose_seq: u64,
    /// Wake-up lateness of this tick (s).
    pub lateness_s: f64,
}

/// What a run did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MockSummary {
    /// Poses sent.
    pub ticks: u64,
    /// Ticks that woke a whole period or more late.
    pub late_ticks: u64,
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
}

/// Lags counted up to this many ticks (the last bin collects the rest).
const LAG_BINS: usize = 64;

fn quantile(counts: &[u64; LAG_BINS], q: f64) -> u64 {
    let total: u64 = counts.iter().sum();
    let want = ((q * total as f64).ceil() as u64).max(1);
    let mut seen = 0;
    for (lag, &c) in counts.iter().enumerate() {
        seen += c;
        if seen >= want {
            return lag as u64;
        }
    }
    0
}

/// A mock device attached to a station's device services.
pub struct MockDevice {
    poses: Publisher<ipc::Service, DevicePose, ()>,
    forces: Subscriber<ipc::Service, DeviceForce, ()>,
    _node: Node<ipc::Service>,
}

impl MockDevice {
    /// Attaches to `station` (the server need not run yet: the services are created if
    /// they do not exist, and the server opens them when it starts).
    pub fn open(station: &str) -> Result<Self, ShmError> {
        let node = shm::node("scalpel-mock-device", station)?;
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
        let mut lags = [0u64; LAG_BINS];
        let t0 = Instant::now();
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
                device_time_ns: t0.elapsed().as_nanos() as u64,
                tip_m: pose.tip_m.into(),
                orientation_xyzw: [q.x, q.y, q.z, q.w],
            };
            self.poses
                .send_copy(sample)
                .map_err(|e| shm::iceoryx("sending a pose to", "the station", e))?;
            while let Ok(Some(received)) = self.forces.receive() {
                let f = *received.payload();
                if f.layout_version != LAYOUT_VERSION || f.force_n.iter().any(|c| !c.is_finite()) {
                    summary.forces_rejected += 1;
                    continue;
                }
                summary.forces_received += 1;
                let magnitude = f.force_n.iter().map(|c| c * c).sum::<f64>().sqrt();
                summary.max_force_n = summary.max_force_n.max(magnitude);
                tick.force_n = f.force_n;
                tick.force_flags = f.flags;
                tick.server_tick = f.tick;
                tick.pose_seq = f.pose_seq;
            }
            if tick.pose_seq > 0 {
                lags[((k - tick.pose_seq.min(k)) as usize).min(LAG_BINS - 1)] += 1;
            }
            tick.t_s = t;
            tick.seq = k;
            tick.tip_m = sample.tip_m;
            tick.lateness_s = lateness;
            summary.ticks += 1;
            summary.late_ticks += u64::from(lateness >= period);
            on_tick(&tick);
        }
        summary.rate_hz = summary.ticks as f64 / t0.elapsed().as_secs_f64().max(1e-9);
        summary.lag_p50_ticks = quantile(&lags, 0.5);
        summary.lag_p99_ticks = quantile(&lags, 0.99);
        Ok(summary)
    }
}

/// Asks for SCHED_FIFO; returns the priority granted (0: not permitted, normal scheduling).
fn make_fifo(priority: u8) -> u8 {
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
