//! The output stage: the last thing between the simulation and the device, run on the haptic
//! thread after every other input (ARCHITECTURE.md). Whatever comes in — a NaN from a broken
//! model, a spike, a stale model, a device that stopped talking — what goes out is finite,
//! at most `max_force_n`, changes by at most the rate limit per tick, does not make the
//! virtual environment a source of energy (Hannaford–Ryu passivity observer and controller),
//! and fades to zero when the device or the simulation goes quiet (watchdog).
//!
//! Sans-IO: time comes in as arguments, nothing allocates.

use scalpel_sim::math::Vec3;

/// Limits and timings of the output stage.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputLimits {
    /// Largest force ever sent (N).
    pub max_force_n: f64,
    /// Largest change of the force in one millisecond (N).
    pub rate_limit_n_per_ms: f64,
    /// No device sample for this long fades the force out (s).
    pub device_timeout_s: f64,
    /// No simulation update for this long fades the force out (s).
    pub sim_timeout_s: f64,
    /// The fade to zero takes this long (s): short, so that the force is gone within
    /// about 10 ms of the last sample (reliability.md, row 4).
    pub fade_out_s: f64,
    /// The fade back in takes this long (s): long, so that a returning device is not
    /// jolted.
    pub fade_in_s: f64,
    /// Run the passivity observer and controller.
    pub passivity: bool,
    /// Time constant (s) over which the observer forgets energy the environment absorbed
    /// beyond what it still stores (infinite: never, the classic observer). A reserve built
    /// up by long dissipative cutting would otherwise let an environment that turns active
    /// (an unstable model, a force spike) give that much energy back before the controller
    /// acts (Ryu et al. 2005 describe this delay); forgetting bounds the reserve to about
    /// the power dissipated times this constant. The energy the model says the contact
    /// stores (a pressed capsule) is kept, so its release is never mistaken for a source;
    /// a deficit is never forgotten.
    pub passivity_memory_s: f64,
    /// The haptic loop's period (s): the rate limit and the fade advance by at most one
    /// period per tick, however late the tick woke.
    pub period_s: f64,
    /// The stiffest local model rendered (N/m, each eigenvalue of K bounded, by the
    /// simulation thread as it hands the model over): what the device renders stably at
    /// the loop's rate.
    pub max_stiffness_n_per_m: f64,
}

impl Default for OutputLimits {
    /// The configuration's defaults (docs/SERVER.md) with a Geomagic Touch's 3.3 N peak.
    fn default() -> Self {
        Self {
            max_force_n: 3.3,
            rate_limit_n_per_ms: 0.5,
            device_timeout_s: 0.005,
            sim_timeout_s: 0.1,
            fade_out_s: 0.005,
            fade_in_s: 0.05,
            passivity: true,
            passivity_memory_s: 1.0,
            period_s: 0.001,
            max_stiffness_n_per_m: 1000.0,
        }
    }
}

/// What the stage is given on one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputInput {
    /// Now (s, monotonic).
    pub now_s: f64,
    /// The force the coupling asks for (N).
    pub requested_n: Vec3,
    /// Device velocity (m/s), from its last two samples.
    pub velocity_m_per_s: Vec3,
    /// When the device was last heard from (s); `None` if never.
    pub device_seen_s: Option<f64>,
    /// When the simulation last published a force model (s); `None` if never.
    pub sim_seen_s: Option<f64>,
    /// A cap below the device limit (N; infinite: none), e.g. a force-saturation fault.
    /// It can only lower the limit.
    pub cap_n: f64,
    /// Energy the model says the contact stores and would give back (J): the observer
    /// does not forget below it.
    pub stored_energy_j: f64,
}

/// What the stage did on one tick, for counters.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OutputReport {
    /// The force sent (N).
    pub force_n: Vec3,
    /// The request was not finite and was replaced by zero.
    pub nan_guarded: bool,
    /// The request was above the device limit.
    pub clamped: bool,
    /// The rate limit cut the change.
    pub rate_limited: bool,
    /// Damping the passivity controller added (N·s/m).
    pub passivity_damping: f64,
    /// The passivity observer's energy after this tick (J): what the environment has
    /// absorbed and not given back (forgetting included).
    pub passivity_energy_j: f64,
    /// Watchdog gain applied, 1 healthy, 0 faded out.
    pub watchdog_gain: f64,
}

/// The output stage's state.
#[derive(Debug, Clone)]
pub struct OutputStage {
    limits: OutputLimits,
    last_force: Vec3,
    last_now_s: Option<f64>,
    /// Energy the virtual environment has absorbed and not given back (J): the passivity
    /// observer, forgetting included.
    observed_energy_j: f64,
    gain: f64,
}

impl OutputStage {
    /// A stage with `limits`, starting faded in only once the watchdog sees fresh inputs.
    pub fn new(limits: OutputLimits) -> Self {
        Self {
            limits,
            last_force: Vec3::zeros(),
            last_now_s: None,
            observed_energy_j: 0.0,
            gain: 0.0,
        }
    }

    /// The limits.
    pub fn limits(&self) -> &OutputLimits {
        &self.limits
    }

    /// One tick: the force to send.
    pub fn process(&mut self, input: &OutputInput) -> OutputReport {
        let l = self.limits;
        // NaN compares false: a NaN cap leaves the device limit.
        let max_n = if input.cap_n < l.max_force_n {
            input.cap_n.max(0.0)
        } else {
            l.max_force_n
        };
        let dt = match self.last_now_s {
            Some(t) if input.now_s > t => (input.now_s - t).min(0.1),
            _ => 0.001,
        };
        self.last_now_s = Some(input.now_s);
        let mut report = OutputReport::default();
        let v = if input.velocity_m_per_s.iter().all(|c| c.is_finite()) {
            input.velocity_m_per_s
        } else {
            Vec3::zeros()
        };

        // NaN guard.
        let mut f = input.requested_n;
        if !f.iter().all(|c| c.is_finite()) {
            f = Vec3::zeros();
            report.nan_guarded = true;
        }
        // Passivity (Hannaford & Ryu 2002): the observer (updated below with the force that
        // was actually sent) holds the energy the environment has absorbed, −∫f·v dt. If it
        // has given out more than it took in, damp the device just enough to take the
        // excess back this tick.
        if l.passivity {
            let v2 = v.norm_squared();
            if self.observed_energy_j < 0.0 && v2 > 1e-12 {
                let alpha = -self.observed_energy_j / (dt * v2);
                f -= v * alpha;
                report.passivity_damping = alpha;
            }
        }
        // Clamp to the limit, a fault's cap included (scaled, never distorted in direction),
        // after the damping: nothing the stages before asked for gets past it.
        report.clamped |= clamp(&mut f, max_n);
        // Watchdog: fade out while the device or the model is stale, back in when fresh.
        let stale =
            |seen: Option<f64>, timeout: f64| seen.is_none_or(|t| input.now_s - t > timeout);
        let healthy = !stale(input.device_seen_s, l.device_timeout_s)
            && !stale(input.sim_seen_s, l.sim_timeout_s);
        // A late tick does not buy a bigger step: the fade and the rate limit move by at
        // most one period's worth per tick.
        let tick_dt = dt.min(l.period_s);
        self.gain = if healthy {
            (self.gain + tick_dt / l.fade_in_s.max(1e-6)).min(1.0)
        } else {
            (self.gain - tick_dt / l.fade_out_s.max(1e-6)).max(0.0)
        };
        f *= self.gain;
        report.watchdog_gain = self.gain;
        // Rate limit, then the device limit again: both hold on what is sent, whatever
        // the stages before asked for (a spike, the passivity damping, a fade).
        let step = f - self.last_force;
        let max_step = l.rate_limit_n_per_ms * tick_dt * 1e3;
        if step.norm() > max_step {
            f = self.last_force + step * (max_step / step.norm());
            report.rate_limited = true;
        }
        // The device limit only: a cap that a fault lowers suddenly is reached at the rate
        // limit (the request was capped above), never by a jump.
        report.clamped |= clamp(&mut f, l.max_force_n);
        if !f.iter().all(|c| c.is_finite()) {
            f = Vec3::zeros();
            report.nan_guarded = true;
        }
        if l.passivity {
            self.observed_energy_j += -f.dot(&v) * dt;
            let kept = if input.stored_energy_j.is_finite() {
                input.stored_energy_j.max(0.0)
            } else {
                0.0
            };
            let surplus = self.observed_energy_j - kept;
            if surplus > 0.0 && l.passivity_memory_s.is_finite() {
                self.observed_energy_j =
                    kept + surplus * (-dt / l.passivity_memory_s.max(1e-6)).exp();
            }
            report.passivity_energy_j = self.observed_energy_j;
        }
        self.last_force = f;
        report.force_n = f;
        report
    }
}

/// Scales `f` down to at most `max_n`; returns whether it did.
fn clamp(f: &mut Vec3, max_n: f64) -> bool {
    let m = f.norm();
    if m > max_n {
        *f *= max_n / m;
        true
    } else {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn limits() -> OutputLimits {
        OutputLimits::default()
    }

    fn input(t: f64, f: Vec3, v: Vec3) -> OutputInput {
        OutputInput {
            now_s: t,
            requested_n: f,
            velocity_m_per_s: v,
            device_seen_s: Some(t),
            sim_seen_s: Some(t),
            cap_n: f64::INFINITY,
            stored_energy_j: 0.0,
        }
    }

    /// Runs `ticks` healthy ticks of 1 ms with a constant request; returns the last report.
    fn settle(stage: &mut OutputStage, f: Vec3, ticks: usize) -> OutputReport {
        let mut r = OutputReport::default();
        for k in 0..ticks {
            r = stage.process(&input(k as f64 * 1e-3, f, Vec3::zeros()));
        }
        r
    }

    /// Runs `ticks` (1 ms each, numbered from the start) of an energy source: a "negative
    /// damper" pushing along a 5 cm/s motion with `gain` N·s/m. Returns the energy it gave
    /// the device (J).
    fn energy_from_a_source(
        stage: &mut OutputStage,
        ticks: std::ops::Range<usize>,
        gain: f64,
    ) -> f64 {
        let v = Vec3::new(0.05, 0.0, 0.0);
        ticks
            .map(|k| {
                let r = stage.process(&input(k as f64 * 1e-3, v * gain, v));
                r.force_n.dot(&v) * 1e-3
            })
            .sum()
    }

    #[test]
    fn nan_becomes_zero_and_the_loop_goes_on() {
        let mut s = OutputStage::new(limits());
        settle(&mut s, Vec3::new(1.0, 0.0, 0.0), 200);
        let r = s.process(&input(0.2, Vec3::new(f64::NAN, 0.0, 0.0), Vec3::zeros()));
        assert!(r.nan_guarded);
        assert!(r.force_n.iter().all(|c| c.is_finite()));
        // Rate-limited towards zero, not a jump.
        assert!((r.force_n.x - 0.5).abs() < 1e-12, "{:?}", r.force_n);
    }

    #[test]
    fn the_rate_limit_shapes_a_step() {
        let mut s = OutputStage::new(limits());
        let mut last = 0.0;
        for k in 0..200 {
            let r = s.process(&input(
                k as f64 * 1e-3,
                Vec3::new(0.0, 0.0, 3.0),
                Vec3::zeros(),
            ));
            assert!(r.force_n.z - last <= 0.5 + 1e-12);
            last = r.force_n.z;
        }
        assert!((last - 3.0).abs() < 1e-9);
    }

    #[test]
    fn an_energy_source_is_damped_to_passivity() {
        // A "negative damper" environment pushes along the motion: it feeds energy in.
        let run = |passivity: bool| {
            let mut s = OutputStage::new(OutputLimits {
                passivity,
                ..limits()
            });
            settle(&mut s, Vec3::zeros(), 100);
            energy_from_a_source(&mut s, 100..600, 20.0)
        };
        let without = run(false);
        let with = run(true);
        assert!(without > 0.02, "the source should give energy: {without}");
        // The controller takes the excess back within a few ticks (the rate limit spreads
        // its damping): what is left is a few ticks' worth, not a growing supply.
        assert!(with < 0.05 * without, "{with} of {without}");
    }

    #[test]
    fn a_long_dissipative_cut_banks_no_reserve_for_an_environment_that_turns_active() {
        // 10 s of steady cutting: 2.2 N against the blade at 5 mm/s (0.11 J absorbed), then
        // the environment turns active — a negative damper pushing along the motion.
        let run = |memory_s: f64| {
            let mut s = OutputStage::new(OutputLimits {
                passivity_memory_s: memory_s,
                ..limits()
            });
            let v_cut = Vec3::new(0.005, 0.0, 0.0);
            for k in 0..10_000 {
                let r = s.process(&input(k as f64 * 1e-3, v_cut * -440.0, v_cut));
                // A passive environment is never damped.
                assert_eq!(r.passivity_damping, 0.0, "tick {k}");
            }
            energy_from_a_source(&mut s, 10_000..10_500, 40.0)
        };
        let classic = run(f64::INFINITY);
        let forgetting = run(1.0);
        // The classic observer lets the source give all 0.5 s of its 0.1 W: the reserve is
        // larger than that.
        assert!(classic > 0.045, "{classic}");
        // Forgetting over 1 s keeps about 11 mJ (absorbed power × 1 s): the source gets that
        // and a few ticks' worth while the rate limit spreads the damping.
        assert!(forgetting < 0.015, "{forgetting} (classic {classic})");
    }

    #[test]
    fn a_held_press_is_released_without_damping() {
        // A spring of 300 N/m pressed 5 mm at 5 mm/s, held 3 s (three memory constants),
        // released at 5 mm/s. The contact stores ½kx², and gives it back on release.
        let run = |publish_stored: bool| {
            let mut s = OutputStage::new(limits());
            settle(&mut s, Vec3::zeros(), 100);
            let (k, step) = (300.0, 5e-6);
            let mut damped = 0;
            let mut tick = |s: &mut OutputStage, t: usize, x: f64, v: f64| {
                let mut i = input(t as f64 * 1e-3, Vec3::new(-k * x, 0.0, 0.0), Vec3::x() * v);
                if publish_stored {
                    i.stored_energy_j = 0.5 * k * x * x;
                }
                damped += usize::from(s.process(&i).passivity_damping > 0.0);
            };
            let mut t = 100;
            for j in 1..=1000 {
                tick(&mut s, t, j as f64 * step, 5e-3);
                t += 1;
            }
            for _ in 0..3000 {
                tick(&mut s, t, 1000.0 * step, 0.0);
                t += 1;
            }
            for j in (0..1000).rev() {
                tick(&mut s, t, j as f64 * step, -5e-3);
                t += 1;
            }
            damped
        };
        assert_eq!(run(true), 0);
        // Forgetting the stored energy too would have damped the release.
        let unheld = run(false);
        assert!(unheld > 100, "{unheld}");
    }

    #[test]
    fn silence_fades_the_force_out_and_back() {
        let mut s = OutputStage::new(limits());
        let f = Vec3::new(0.0, 2.0, 0.0);
        settle(&mut s, f, 200);
        // The device stops talking at 0.2 s.
        let mut t = 0.2;
        let mut gone_at = None;
        while t < 0.4 {
            let r = s.process(&OutputInput {
                device_seen_s: Some(0.2),
                ..input(t, f, Vec3::zeros())
            });
            if r.force_n.norm() == 0.0 && gone_at.is_none() {
                gone_at = Some(t);
            }
            t += 1e-3;
        }
        let gone = gone_at.expect("the force should fade to zero");
        // Timeout 5 ms, fade 5 ms (2 N is under what the rate limit moves in 5 ms): gone
        // within 10 ms of the last sample.
        assert!(gone - 0.2 <= 0.010 + 1e-3, "{gone}");
        // A stalled simulation (no model for 100 ms) fades too.
        let mut s = OutputStage::new(limits());
        settle(&mut s, f, 200);
        let r = (0..300)
            .map(|k| {
                let t = 0.2 + k as f64 * 1e-3;
                s.process(&OutputInput {
                    sim_seen_s: Some(0.2),
                    ..input(t, f, Vec3::zeros())
                })
            })
            .last()
            .unwrap();
        assert_eq!(r.force_n, Vec3::zeros());
    }

    #[test]
    fn a_cap_lowers_the_limit_and_never_raises_it() {
        let mut s = OutputStage::new(limits());
        let f = Vec3::new(0.0, 0.0, 100.0);
        settle(&mut s, f, 200);
        let capped = |s: &mut OutputStage, t: f64, cap: f64| {
            s.process(&OutputInput {
                cap_n: cap,
                ..input(t, f, Vec3::zeros())
            })
        };
        // Down to the cap at the rate limit (no jump), then held there.
        let first = capped(&mut s, 0.2, 1.0);
        let max = limits().max_force_n;
        assert!(
            (first.force_n.norm() - (max - 0.5)).abs() < 1e-12,
            "{first:?}"
        );
        let r = (1..50)
            .map(|k| capped(&mut s, 0.2 + k as f64 * 1e-3, 1.0))
            .last()
            .unwrap();
        assert!((r.force_n.norm() - 1.0).abs() < 1e-12, "{:?}", r.force_n);
        for cap in [1e9, f64::NAN, f64::INFINITY] {
            let r = (0..100)
                .map(|k| capped(&mut s, 0.3 + k as f64 * 1e-3, cap))
                .last()
                .unwrap();
            assert!(r.force_n.norm() <= limits().max_force_n + 1e-12);
        }
        let r = capped(&mut s, 0.5, -3.0);
        assert!(r.force_n.norm() < limits().max_force_n);
    }

    proptest! {
        #[test]
        fn a_cap_holds_with_passivity_damping_whatever_the_motion(
            cap in 0.0f64..4.0,
            requests in prop::collection::vec((-50.0f64..50.0, -50.0f64..50.0, -50.0f64..50.0, -2.0f64..2.0), 30..200)
        ) {
            let mut s = OutputStage::new(limits());
            for (k, (x, y, z, v)) in requests.into_iter().enumerate() {
                let t = k as f64 * 1e-3;
                let r = s.process(&OutputInput {
                    cap_n: cap,
                    ..input(t, Vec3::new(x, y, z), Vec3::new(v, -v, 0.5 * v))
                });
                // From rest the force never passes the cap: every stage after it moves
                // within the ball of the cap (a fade scales, the rate limit steps along a
                // segment between two points inside it).
                prop_assert!(r.force_n.norm() <= cap + 1e-9, "{} > {cap}", r.force_n.norm());
            }
        }

        #[test]
        fn the_force_sent_is_always_finite_and_bounded(
            requests in prop::collection::vec((-1e6f64..1e6, -1e6f64..1e6, -1e6f64..1e6, -10.0f64..10.0, any::<bool>(), prop_oneof![Just(0.0), 0.0f64..0.05]), 1..200)
        ) {
            let mut s = OutputStage::new(limits());
            let mut last = Vec3::zeros();
            let mut t = 0.0;
            for (x, y, z, v, nan, late) in requests {
                // Ticks that wake late (up to 50 ms) still move by one tick's rate limit.
                t += 1e-3 + late;
                let f = if nan { Vec3::new(f64::NAN, y, z) } else { Vec3::new(x, y, z) };
                let r = s.process(&input(t, f, Vec3::new(v, 0.0, 0.0)));
                prop_assert!(r.force_n.iter().all(|c| c.is_finite()));
                prop_assert!(r.force_n.norm() <= limits().max_force_n + 1e-9);
                prop_assert!((r.force_n - last).norm() <= limits().rate_limit_n_per_ms + 1e-9);
                last = r.force_n;
            }
        }
    }
}
