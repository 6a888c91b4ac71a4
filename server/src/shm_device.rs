//! The shared-memory device: poses from another process (the mock device, a real device's
//! driver) on `scalpel/<station>/device/pose`, forces back on `.../device/force`
//! (docs/PROTOCOL.md). Lives on the haptic thread: receiving and sending are lock-free
//! shared-memory operations that neither allocate nor wait.
//!
//! A sample that is not of this layout version, not finite, out of the workspace or with a
//! degenerate orientation is dropped and counted; the haptic loop only ever sees good poses.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use nalgebra::{Quaternion, UnitQuaternion};
use scalpel_proto::shm::{self, DeviceForce, DevicePose, LAYOUT_VERSION};
use scalpel_sim::cut::ToolPose;
use scalpel_sim::math::Vec3;

use crate::device::{ForceStatus, HapticDevice};

/// Tip positions farther than this from the scene origin are not a device's (m).
const WORKSPACE_RADIUS_M: f64 = 10.0;

/// Counters the device keeps for the status line (atomics: read from another thread).
#[derive(Debug, Default)]
pub struct ShmDeviceCounters {
    /// Poses received and used.
    pub poses: AtomicU64,
    /// Poses dropped as malformed.
    pub rejected: AtomicU64,
    /// Forces that could not be sent (no shared memory left: a subscriber holds samples).
    pub send_failures: AtomicU64,
}

/// The device end of a station's device services.
pub struct ShmDevice {
    // The node owns the ports' shared memory; it is dropped last.
    poses: Subscriber<ipc::Service, DevicePose, ()>,
    forces: Publisher<ipc::Service, DeviceForce, ()>,
    tick: u64,
    last_seq: u64,
    counters: Arc<ShmDeviceCounters>,
    _node: Node<ipc::Service>,
}

impl ShmDevice {
    /// Opens (or creates) the station's device services.
    pub fn open(station: &str, counters: Arc<ShmDeviceCounters>) -> Result<Self, shm::ShmError> {
        let node = shm::node("scalpel-server.haptic", station)?;
        let poses = shm::pose_service(&node, station)?
            .subscriber_builder()
            .create()
            .map_err(|e| shm::iceoryx("subscribing to poses of station", station, e))?;
        let forces = shm::force_service(&node, station)?
            .publisher_builder()
            .create()
            .map_err(|e| shm::iceoryx("publishing forces of station", station, e))?;
        Ok(Self {
            poses,
            forces,
            tick: 0,
            last_seq: 0,
            counters,
            _node: node,
        })
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
    fn sample(&mut self, _now_s: f64) -> Option<ToolPose> {
        let mut latest = None;
        // Drain: only the newest pose matters, older ones are already history.
        while let Ok(Some(sample)) = self.poses.receive() {
            let payload = *sample.payload();
            match pose_of(&payload) {
                Some(pose) => {
                    latest = Some(pose);
                    self.last_seq = payload.seq;
                    self.counters.poses.fetch_add(1, Ordering::Relaxed);
                }
                None => {
                    self.counters.rejected.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        latest
    }

    fn send_force(&mut self, force_n: Vec3, status: ForceStatus) {
        self.tick += 1;
        let message = DeviceForce {
            layout_version: LAYOUT_VERSION,
            flags: if status.faded { shm::FORCE_FADED } else { 0 }
                | if status.nan_guarded {
                    shm::FORCE_NAN_GUARDED
                } else {
                    0
                },
            tick: self.tick,
            pose_seq: self.last_seq,
            force_n: force_n.into(),
        };
        let sent = match self.forces.loan_uninit() {
            Ok(sample) => sample.write_payload(message).send().is_ok(),
            Err(_) => false,
        };
        if !sent {
            self.counters.send_failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}
