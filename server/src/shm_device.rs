//! The shared-memory device: poses from another process (the mock device, a real device's
//! driver) on `scalpel/<station>/device/pose`, forces back on `.../device/force`
//! (docs/PROTOCOL.md). Lives on the haptic thread. Receiving a pose is a lock-free
//! shared-memory read that neither allocates nor waits. Sending is not allocation-free in
//! iceoryx2 0.10 (every `loan` boxes a small reference-counted chunk state), so the haptic
//! thread hands the force to its own **force-out thread** through an SPSC ring and wakes it
//! (a futex wake, no wait); that thread, which inherits the haptic thread's SCHED_FIFO,
//! loans and sends. The force reaches the device tens of microseconds after the tick,
//! well inside the device's next millisecond.
//!
//! A sample that is not of this layout version, not finite, out of the workspace or with a
//! degenerate orientation is dropped and counted; the haptic loop only ever sees good poses.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use nalgebra::{Quaternion, UnitQuaternion};
use scalpel_proto::shm::{self, DeviceForce, DevicePose, LAYOUT_VERSION};
use scalpel_sim::cut::ToolPose;
use scalpel_sim::math::Vec3;

use crate::device::{DeviceSample, ForceStatus, HapticDevice};

/// Tip positions farther than this from the scene origin are not a device's (m).
pub const WORKSPACE_RADIUS_M: f64 = 10.0;

/// Counters the device keeps for the status line (atomics: read from another thread).
#[derive(Debug, Default)]
pub struct ShmDeviceCounters {
    /// Poses received and used.
    pub poses: AtomicU64,
    /// Poses dropped as malformed.
    pub rejected: AtomicU64,
    /// Forces that could not be sent (no shared memory left: a subscriber holds samples).
    pub send_failures: AtomicU64,
    /// Receiving poses failed (the connection to the device broke).
    pub receive_errors: AtomicU64,
    /// Poses dropped because their process had not connected as the station's device.
    pub unconnected: AtomicU64,
}

/// The device the station accepted (its node id), set by the main thread's device monitor
/// when a device connects (`scalpel_proto::shm::connect`) and read by the haptic thread on
/// every sample: poses from any other process are dropped and counted. Atomics, no lock: a
/// read torn across an update matches no node and drops one tick's samples, which is safe.
#[derive(Debug, Default)]
pub struct DeviceGate {
    accepted: AtomicBool,
    node_low: AtomicU64,
    node_high: AtomicU64,
}

impl DeviceGate {
    /// Takes poses from `node` (a node id's value) only; `None`: from nobody.
    pub fn accept(&self, node: Option<u128>) {
        self.accepted.store(false, Ordering::Release);
        if let Some(id) = node {
            self.node_low.store(id as u64, Ordering::Release);
            self.node_high.store((id >> 64) as u64, Ordering::Release);
            self.accepted.store(true, Ordering::Release);
        }
    }

    /// Whether a sample from `node` is the accepted device's.
    pub fn admits(&self, node: u128) -> bool {
        self.accepted.load(Ordering::Acquire)
            && self.node_low.load(Ordering::Acquire) == node as u64
            && self.node_high.load(Ordering::Acquire) == (node >> 64) as u64
    }
}

/// Forces in flight from the haptic thread to the force-out thread.
const FORCE_RING: usize = 64;

/// The device end of a station's device services.
pub struct ShmDevice {
    // The node owns the ports' shared memory; it is dropped last.
    poses: Subscriber<ipc::Service, DevicePose, ()>,
    forces: rtrb::Producer<DeviceForce>,
    sender: std::thread::Thread,
    sender_handle: Option<JoinHandle<()>>,
    stop: Arc<AtomicBool>,
    counters: Arc<ShmDeviceCounters>,
    gate: Arc<DeviceGate>,
    _node: Node<ipc::Service>,
}

impl ShmDevice {
    /// Opens the station's device services (made by the station's device monitor) and
    /// starts the force-out thread; poses are taken from the device `gate` admits.
    pub fn open(
        station: &str,
        counters: Arc<ShmDeviceCounters>,
        gate: Arc<DeviceGate>,
    ) -> Result<Self, shm::ShmError> {
        let node = shm::node("scalpel-server.haptic", station)?;
        let poses = shm::pose_service(&node, station)?
            .subscriber_builder()
            .create()
            .map_err(|e| shm::iceoryx("subscribing to poses of station", station, e))?;
        let (forces, queued) = rtrb::RingBuffer::new(FORCE_RING);
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let sender_handle = {
            let station = station.to_string();
            let stop = stop.clone();
            let counters = counters.clone();
            std::thread::Builder::new()
                .name("force-out".into())
                .spawn(move || send_forces(&station, queued, &stop, &counters, ready_tx))
                .map_err(|e| shm::iceoryx("starting the force-out thread of", "", e))?
        };
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(e),
            Err(_) => {
                return Err(shm::iceoryx(
                    "starting the force-out thread of",
                    station,
                    "it ended early",
                ));
            }
        }
        Ok(Self {
            poses,
            forces,
            sender: sender_handle.thread().clone(),
            sender_handle: Some(sender_handle),
            stop,
            counters,
            gate,
            _node: node,
        })
    }
}

impl Drop for ShmDevice {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        self.sender.unpark();
        if let Some(h) = self.sender_handle.take() {
            let _ = h.join();
        }
    }
}

/// The force-out thread: opens the force publisher (ports belong to their thread), reports
/// whether that worked, then sends what the haptic thread queues, woken per tick.
fn send_forces(
    station: &str,
    mut queued: rtrb::Consumer<DeviceForce>,
    stop: &AtomicBool,
    counters: &ShmDeviceCounters,
    ready: std::sync::mpsc::Sender<Result<(), shm::ShmError>>,
) {
    let opened = shm::node("scalpel-server.force-out", station).and_then(|node| {
        let publisher = shm::force_service(&node, station)?
            .publisher_builder()
            .create()
            .map_err(|e| shm::iceoryx("publishing forces of station", station, e))?;
        Ok((node, publisher))
    });
    let (_node, publisher): (Node<ipc::Service>, Publisher<ipc::Service, DeviceForce, ()>) =
        match opened {
            Ok(p) => {
                let _ = ready.send(Ok(()));
                p
            }
            Err(e) => {
                let _ = ready.send(Err(e));
                return;
            }
        };
    loop {
        // Woken by every force queued; the timeout only bounds how late a stop is seen.
        std::thread::park_timeout(Duration::from_millis(50));
        // Read before draining: a force queued before the stop (the final zero) is sent.
        let stopping = stop.load(Ordering::Acquire);
        while let Ok(mut message) = queued.pop() {
            message.sent_time_ns = (crate::realtime::monotonic_s() * 1e9) as u64;
            let sent = match publisher.loan_uninit() {
                Ok(sample) => sample.write_payload(message).send().is_ok(),
                Err(_) => false,
            };
            if !sent {
                counters.send_failures.fetch_add(1, Ordering::Relaxed);
            }
        }
        if stopping {
            return;
        }
    }
}

/// The pose a sample describes, if it is a good one.
pub fn pose_of(sample: &DevicePose) -> Option<ToolPose> {
    if sample.layout_version != LAYOUT_VERSION {
        return None;
    }
    let tip = Vec3::from(sample.tip_m);
    let [x, y, z, w] = sample.orientation_xyzw;
    let q = Quaternion::new(w, x, y, z);
    let norm = q.norm();
    let tip_ok = tip.iter().all(|c| c.is_finite()) && tip.norm() <= WORKSPACE_RADIUS_M;
    let orientation_ok = norm.is_finite() && (0.5..=2.0).contains(&norm);
    if !(tip_ok && orientation_ok) {
        return None;
    }
    Some(ToolPose {
        tip_m: tip,
        orientation: UnitQuaternion::from_quaternion(q),
    })
}

impl HapticDevice for ShmDevice {
    fn sample(&mut self, _now_s: f64) -> Option<DeviceSample> {
        let mut latest = None;
        // Drain: only the newest pose matters, older ones are already history.
        loop {
            match self.poses.receive() {
                Ok(Some(sample)) => {
                    if !self.gate.admits(sample.header().node_id().value()) {
                        self.counters.unconnected.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    let payload = *sample.payload();
                    match pose_of(&payload) {
                        Some(pose) => {
                            latest = Some(DeviceSample {
                                pose,
                                seq: payload.seq,
                                device_time_s: payload.device_time_ns as f64 * 1e-9,
                            });
                            self.counters.poses.fetch_add(1, Ordering::Relaxed);
                        }
                        None => {
                            self.counters.rejected.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                }
                Ok(None) => break,
                Err(_) => {
                    self.counters.receive_errors.fetch_add(1, Ordering::Relaxed);
                    break;
                }
            }
        }
        latest
    }

    fn send_force(&mut self, force_n: Vec3, status: ForceStatus) {
        let message = DeviceForce {
            layout_version: LAYOUT_VERSION,
            flags: if status.faded { shm::FORCE_FADED } else { 0 }
                | if status.nan_guarded {
                    shm::FORCE_NAN_GUARDED
                } else {
                    0
                },
            tick: status.station_tick,
            pose_seq: status.pose_seq,
            tick_time_ns: status.tick_time_ns,
            sent_time_ns: 0,
            force_n: force_n.into(),
        };
        if self.forces.push(message).is_err() {
            // The force-out thread is 64 ticks behind: this force is lost, the next one
            // supersedes it anyway.
            self.counters.send_failures.fetch_add(1, Ordering::Relaxed);
        }
        self.sender.unpark();
    }
}
