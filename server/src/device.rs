//! Haptic devices as the haptic loop sees them: a pose in, a force out, every tick.
//! Two kinds: the in-process scripted device (plays a cut script against the haptic clock)
//! and the shared-memory device (`shm_device`: the mock device or a real device's driver,
//! another process, over iceoryx2).

use scalpel_sim::cut::ToolPose;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::CutScript;

/// What the output stage did to the force, sent along with it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ForceStatus {
    /// The watchdog is fading the force (device or simulation lost).
    pub faded: bool,
    /// The request was not finite and was replaced by zero.
    pub nan_guarded: bool,
    /// CLOCK_MONOTONIC at the haptic tick (ns).
    pub tick_time_ns: u64,
    /// The haptic tick on the station clock (ms since the server started; instructors
    /// schedule faults on it).
    pub station_tick: u64,
    /// `seq` of the device sample the force was computed from (0: none yet); behind the
    /// device's latest when a latency fault holds samples back.
    pub pose_seq: u64,
}

/// One sample of a device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceSample {
    /// The tool pose.
    pub pose: ToolPose,
    /// The device's sample counter.
    pub seq: u64,
    /// When the device took it, on the device's clock (s); velocities are taken on this
    /// clock, so that a sample that travelled late does not look like a fast move.
    pub device_time_s: f64,
}

/// A haptic device. Not `Send`: shared-memory ports belong to the thread that made them,
/// so a device is made on the haptic thread by a [`DeviceFactory`].
pub trait HapticDevice {
    /// The device's newest sample (`now_s` on the haptic clock, from the loop's start), or
    /// `None` if it has nothing new (disconnected, or no sample this tick).
    fn sample(&mut self, now_s: f64) -> Option<DeviceSample>;
    /// The force to render (N), finite and within the device's limits.
    fn send_force(&mut self, force_n: Vec3, status: ForceStatus);
}

/// Makes the device on the thread that will use it.
pub type DeviceFactory = Box<dyn FnOnce() -> anyhow::Result<Box<dyn HapticDevice>> + Send>;

/// Plays a cut script at the haptic rate, in process; records the last force sent.
pub struct ScriptedDevice {
    script: CutScript,
    looping: bool,
    last_force_n: Vec3,
    seq: u64,
}

impl ScriptedDevice {
    /// A device playing `script`, from its start again when it ends if `looping`.
    pub fn new(script: CutScript, looping: bool) -> Self {
        Self {
            script,
            looping,
            last_force_n: Vec3::zeros(),
            seq: 0,
        }
    }

    /// The last force it was sent (N).
    pub fn last_force_n(&self) -> Vec3 {
        self.last_force_n
    }
}

impl HapticDevice for ScriptedDevice {
    fn sample(&mut self, now_s: f64) -> Option<DeviceSample> {
        let duration = self.script.duration_s();
        let t = if self.looping && duration > 0.0 {
            now_s.rem_euclid(duration)
        } else {
            now_s
        };
        self.seq += 1;
        Some(DeviceSample {
            pose: self.script.pose_at(t),
            seq: self.seq,
            device_time_s: now_s,
        })
    }

    fn send_force(&mut self, force_n: Vec3, _status: ForceStatus) {
        self.last_force_n = force_n;
    }
}
