//! Haptic devices as the haptic loop sees them: a pose in, a force out, every tick.
//! The in-process scripted device plays a cut script against the haptic clock; the
//! shared-memory device (the mock device over iceoryx2, real devices) comes next.

use scalpel_sim::cut::ToolPose;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::CutScript;

/// A haptic device.
pub trait HapticDevice: Send {
    /// The device's pose now (`now_s` on the haptic clock, from the loop's start), or
    /// `None` if it has nothing new (disconnected, or no sample this tick).
    fn sample(&mut self, now_s: f64) -> Option<ToolPose>;
    /// The force to render (N).
    fn send_force(&mut self, force_n: Vec3);
}

/// Plays a cut script at the haptic rate, in process; records the last force sent.
pub struct ScriptedDevice {
    script: CutScript,
    looping: bool,
    last_force_n: Vec3,
}

impl ScriptedDevice {
    /// A device playing `script`, from its start again when it ends if `looping`.
    pub fn new(script: CutScript, looping: bool) -> Self {
        Self {
            script,
            looping,
            last_force_n: Vec3::zeros(),
        }
    }

    /// The last force it was sent (N).
    pub fn last_force_n(&self) -> Vec3 {
        self.last_force_n
    }
}

impl HapticDevice for ScriptedDevice {
    fn sample(&mut self, now_s: f64) -> Option<ToolPose> {
        let duration = self.script.duration_s();
        let t = if self.looping && duration > 0.0 {
            now_s.rem_euclid(duration)
        } else {
            now_s
        };
        Some(self.script.pose_at(t))
    }

    fn send_force(&mut self, force_n: Vec3) {
        self.last_force_n = force_n;
    }
}
