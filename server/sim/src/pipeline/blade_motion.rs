//! The simulated blade follows the tool's pose no faster than a hand moves a scalpel.
//!
//! A pose that jumps — a tracker glitch, a device re-homing, an instructor's pose-noise
//! fault (σ up to 20 mm, white per tick) — would otherwise drag the blade through the tissue
//! at metres per second: the points it holds move several lattice spacings per sub-step, the
//! solver rolls back and doubles its sub-steps (to 1472 in a measured station run), ticks
//! take hundreds of milliseconds and the force model books a cut of tens of metres. A blade
//! moved at most [`MAX_BLADE_SPEED_M_PER_S`] per tick never asks that of the solver, and a
//! real hand's motion, always slower, passes unchanged. The force the haptic loop renders
//! still follows the device's own position (the local force model is evaluated there, within
//! its reach), so a jump is felt at once while the tissue catches up.

use crate::cut::ToolPose;

/// Fastest the simulated blade moves (m/s): the scripts' own bound, a hand's quickest.
pub const MAX_BLADE_SPEED_M_PER_S: f64 = super::script::MAX_TIP_SPEED_M_PER_S;

/// Relative slack before a move counts as too fast: a script at exactly the bound, whose
/// interpolation rounds a hair over, is passed bit for bit.
const SLACK: f64 = 1e-9;

/// The pose the blade takes on a tick of `dt` seconds when it was at `from` and the tool asks
/// for `to`: the tip moves at most `MAX_BLADE_SPEED_M_PER_S · dt` toward `to.tip_m`, and the
/// blade turns toward `to.orientation` at most as far as moves its far end (`blade_length_m`
/// from the tip) by the same distance; each along the straight path, so the blade reaches
/// the pose the tool holds still at.
pub fn follow(from: &ToolPose, to: &ToolPose, dt: f64, blade_length_m: f64) -> ToolPose {
    let reach = MAX_BLADE_SPEED_M_PER_S * dt.max(0.0);
    let step = to.tip_m - from.tip_m;
    let distance = step.norm();
    let tip_m = if distance > reach * (1.0 + SLACK) {
        from.tip_m + step * (reach / distance)
    } else {
        to.tip_m
    };
    // The turn from `from` to `to` the short way round, as an axis times an angle in 0..=π.
    let turn = (to.orientation * from.orientation.inverse()).scaled_axis();
    let angle = turn.norm();
    let max_angle = reach / blade_length_m.max(f64::MIN_POSITIVE);
    let orientation = if angle > max_angle * (1.0 + SLACK) {
        nalgebra::UnitQuaternion::from_scaled_axis(turn * (max_angle / angle)) * from.orientation
    } else {
        to.orientation
    };
    ToolPose { tip_m, orientation }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vec3;
    use nalgebra::UnitQuaternion;

    const DT: f64 = 1e-3;
    const BLADE: f64 = 0.025;

    fn pose(tip_mm: [f64; 3], edge: Vec3) -> ToolPose {
        ToolPose::pointing(Vec3::from(tip_mm) * 1e-3, edge)
    }

    #[test]
    fn a_hands_motion_passes_bit_for_bit() {
        let from = pose([0.0, 0.0, 0.0], -Vec3::z());
        // 1.5 mm and a small turn in a millisecond: 1.5 m/s, under the bound.
        let to = ToolPose {
            tip_m: Vec3::new(1.5e-3, 0.0, 0.0),
            orientation: UnitQuaternion::from_axis_angle(&Vec3::y_axis(), 0.02) * from.orientation,
        };
        assert_eq!(follow(&from, &to, DT, BLADE), to);
        // Exactly at the bound.
        let at_bound = pose([2.0, 0.0, 0.0], -Vec3::z());
        assert_eq!(follow(&from, &at_bound, DT, BLADE), at_bound);
    }

    #[test]
    fn a_jump_is_crossed_at_the_bound_along_the_straight_line() {
        let from = pose([0.0, 0.0, 0.0], -Vec3::z());
        let to = pose([30.0, 40.0, 0.0], -Vec3::z());
        let mut at = from;
        let mut ticks = 0;
        while at.tip_m != to.tip_m {
            let next = follow(&at, &to, DT, BLADE);
            let moved = (next.tip_m - at.tip_m).norm();
            assert!(
                moved <= MAX_BLADE_SPEED_M_PER_S * DT * (1.0 + 1e-9),
                "{moved}"
            );
            // On the line from `from` to `to`.
            assert!(next.tip_m.cross(&to.tip_m).norm() < 1e-15);
            at = next;
            ticks += 1;
            assert!(ticks < 100);
        }
        // 50 mm at 2 mm a tick.
        assert_eq!(ticks, 25);
    }

    #[test]
    fn a_flip_is_turned_at_the_bound_and_arrives() {
        let from = pose([0.0, 0.0, 0.0], -Vec3::z());
        let to = pose([0.0, 0.0, 0.0], Vec3::z());
        let max_angle = MAX_BLADE_SPEED_M_PER_S * DT / BLADE;
        let mut at = from;
        let mut ticks = 0;
        while at.orientation != to.orientation {
            let next = follow(&at, &to, DT, BLADE);
            assert!(next.orientation.angle_to(&at.orientation) <= max_angle * (1.0 + 1e-6));
            assert!(next.is_sound());
            at = next;
            ticks += 1;
            assert!(ticks < 100);
        }
        // π at 0.08 rad a tick.
        assert_eq!(ticks, (std::f64::consts::PI / max_angle).ceil() as usize);
    }

    #[test]
    fn noise_of_twenty_millimetres_moves_the_blade_at_most_two_millimetres_a_tick() {
        let centre = pose([0.0, 0.0, 0.0], -Vec3::z());
        let mut at = centre;
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for _ in 0..10_000 {
            let noisy = ToolPose {
                tip_m: Vec3::new(uniform(), uniform(), uniform()) * 0.07,
                ..centre
            };
            let next = follow(&at, &noisy, DT, BLADE);
            assert!((next.tip_m - at.tip_m).norm() <= 2e-3 * (1.0 + 1e-9));
            at = next;
        }
    }
}
