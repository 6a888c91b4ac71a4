//! The blade's steady motion, read off a device that is never still.
//!
//! A haptic device at rest reads ±1 encoder count (a Geomagic Touch or a Falcon: ≈ 0.06 mm
//! per axis) and the hand holding it trembles; tick by tick that is millimetres of travel a
//! second in every direction. The force model needs the blade's *intended* motion — which
//! way the resistance acts, how far the crack has advanced, when Σ grows — so it reads the
//! tip through two stages:
//!
//! 1. a first-order low-pass with a 10 ms time constant, which takes the tick-to-tick
//!    jitter down by about five (white noise) and lags a steady motion by 10 ms;
//! 2. a leash `deadband_m` long: the steady point moves only once the smoothed tip is
//!    that far from it, and then exactly as far as the tip, a deadband behind. Jitter
//!    inside the leash moves it not at all; a tremor (8–12 Hz, which the smoothing lets
//!    through) is held once the point sits in the middle of its swing, while the swing
//!    stays under twice the leash.
//!
//! The elastic loading of the capsule still reads every move of the raw tip: a net
//! displacement, in which noise cancels.

use crate::math::Vec3;

/// Time constant of the low-pass (s).
const SMOOTHING_S: f64 = 0.01;

/// The steady point of a noisy tip.
#[derive(Debug, Clone)]
pub struct SteadyMotion {
    deadband_m: f64,
    smoothed: Option<Vec3>,
    anchor: Vec3,
}

impl SteadyMotion {
    /// A reader with a leash `deadband_m` long (0: the smoothed tip itself).
    pub fn new(deadband_m: f64) -> Self {
        Self {
            deadband_m: deadband_m.max(0.0),
            smoothed: None,
            anchor: Vec3::zeros(),
        }
    }

    /// Forgets the tip (the tool went away): the next one starts where it appears.
    pub fn reset(&mut self) {
        self.smoothed = None;
    }

    /// Reads the tip `dt_s` after the last reading; returns how far the steady point
    /// moved (m).
    pub fn update(&mut self, tip: Vec3, dt_s: f64) -> Vec3 {
        // A garbage reading is no motion (and must not stay in the filter).
        if !tip.iter().all(|c| c.is_finite()) {
            return Vec3::zeros();
        }
        let Some(smoothed) = self.smoothed.as_mut() else {
            self.smoothed = Some(tip);
            self.anchor = tip;
            return Vec3::zeros();
        };
        let dt = if dt_s.is_finite() { dt_s.max(0.0) } else { 0.0 };
        *smoothed += (tip - *smoothed) * (dt / (SMOOTHING_S + dt));
        let pull = *smoothed - self.anchor;
        let slack = pull.norm() - self.deadband_m;
        if slack <= 0.0 {
            return Vec3::zeros();
        }
        let step = pull * (slack / pull.norm());
        self.anchor += step;
        step
    }

    /// Where the steady point is, once a tip has been read.
    pub fn position(&self) -> Option<Vec3> {
        self.smoothed.map(|_| self.anchor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pseudo-random noise in [−a, a] per axis, different every tick.
    fn noise(k: u32, a: f64) -> Vec3 {
        let x = f64::from(k);
        Vec3::new((1.7 * x).sin(), (2.3 * x).sin(), (3.1 * x).cos()) * a
    }

    /// A hand's tremor: 10 Hz along (1, 1, 1), `a` per axis.
    fn tremor(k: u32, a: f64) -> Vec3 {
        Vec3::repeat(a) * (2.0 * std::f64::consts::PI * 10.0 * f64::from(k) * 1e-3).sin()
    }

    #[test]
    fn noise_held_still_is_no_motion() {
        // ±0.1 mm per axis, every tick: larger than the 0.1 mm leash on its own, inside it
        // once smoothed.
        let mut m = SteadyMotion::new(1e-4);
        let mut moved = 0.0;
        for k in 0..10_000 {
            moved += m.update(noise(k, 1e-4), 1e-3).norm();
        }
        // (Where the smoothed noise touches the leash: micrometres in 10 s.)
        assert!(moved < 1e-5, "{moved}");
    }

    #[test]
    fn a_tremor_is_held_still_while_it_spans_less_than_twice_the_leash() {
        // A 10 Hz tremor passes the smoothing almost whole (≈ 85 %). Once the steady point
        // has been dragged to the middle of the swing, a swing under twice the leash moves
        // it no more: ±0.05 mm per axis (0.15 mm peak to peak once smoothed), with the
        // device's jitter on top, is held; ±0.1 mm per axis (0.29 mm) is read as motion.
        let run = |a: f64| {
            let mut m = SteadyMotion::new(1e-4);
            (0..10_000)
                .map(|k| m.update(tremor(k, a) + noise(k, 5e-5), 1e-3).norm())
                .sum::<f64>()
        };
        let inside = run(5e-5);
        assert!(inside < 1e-4, "{inside}");
        let outside = run(1e-4);
        assert!(outside > 1e-2, "{outside}");
    }

    #[test]
    fn a_steady_motion_comes_through_whole_and_in_its_direction() {
        let mut m = SteadyMotion::new(1e-4);
        let v = Vec3::new(3e-6, 4e-6, 0.0); // 5 mm/s
        let mut travel = Vec3::zeros();
        let mut moving = 0;
        for k in 0..2000 {
            let step = m.update(v * f64::from(k) + noise(k, 5e-5), 1e-3);
            if k >= 100 && step != Vec3::zeros() {
                // Once under way, every step points the way the blade goes (a tick where
                // the smoothed noise steps back has none).
                let cos = step.normalize().dot(&v.normalize());
                assert!(cos > 0.9, "{k}: {step:?}");
                moving += 1;
            }
            travel += step;
        }
        // All of the 10 mm but the leash and the smoothing lag (0.05 mm at 5 mm/s).
        let lag = v * 1999.0 - travel;
        assert!(lag.norm() < 1e-4 + 6e-5 + 3e-5, "{lag:?}");
        assert!(moving > 1500, "{moving}");
        assert!(m.position().is_some());
    }

    #[test]
    fn a_tool_that_comes_back_starts_where_it_appears() {
        let mut m = SteadyMotion::new(1e-4);
        m.update(Vec3::zeros(), 1e-3);
        m.reset();
        assert_eq!(m.position(), None);
        assert_eq!(m.update(Vec3::x(), 1e-3), Vec3::zeros());
        assert_eq!(m.position(), Some(Vec3::x()));
        // Garbage time steps and readings do not poison it.
        assert_eq!(m.update(Vec3::repeat(f64::NAN), 1e-3), Vec3::zeros());
        assert!(m.position().unwrap().iter().all(|c| c.is_finite()));
        assert!(
            m.update(Vec3::x() * 2.0, f64::NAN)
                .iter()
                .all(|c| c.is_finite())
        );
    }
}
