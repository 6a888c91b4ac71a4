//! Whether the simulation's ticks share their work with its worker, chosen from what the
//! ticks take at this station: a worker kept off its CPU (viewers rendering on the same two
//! cores) makes the simulation thread wait for the part it took, and two threads then lose
//! (docs/BENCHMARKS.md, "The stations as a lab runs them").

/// Ticks from one trial to the next.
const PERIOD_TICKS: u64 = 5000;
/// Ticks of a trial: alternately held to one thread and shared, so that a change of the
/// work over the trial (the awake region) falls on both alike.
const TRIAL_TICKS: u64 = 400;
/// A tick's time counts at most this much (ms): one stall of the host must not decide.
const COUNTED_MAX_MS: f64 = 5.0;

/// The choice and the trial under way.
#[derive(Debug, Clone)]
pub(super) struct SharingChooser {
    tick: u64,
    /// Summed wall times (ms) and counts of the trial's ticks, on one thread and shared.
    sums: [f64; 2],
    counts: [u32; 2],
    /// Outside trials: share.
    shared: bool,
}

impl SharingChooser {
    pub(super) fn new() -> Self {
        Self {
            tick: 0,
            sums: [0.0; 2],
            counts: [0; 2],
            shared: true,
        }
    }

    fn in_trial(&self) -> bool {
        self.tick % PERIOD_TICKS < TRIAL_TICKS
    }

    /// Whether the next tick may share its work.
    pub(super) fn next(&self) -> bool {
        if self.in_trial() {
            self.tick % 2 == 1
        } else {
            self.shared
        }
    }

    /// Counts the tick just run: whether it could share at all (`eligible`), whether it did,
    /// and its wall time. A trial's end sets the choice to the faster way.
    pub(super) fn record(&mut self, eligible: bool, shared: bool, ms: f64) {
        if self.in_trial() && eligible && ms.is_finite() {
            let k = usize::from(shared);
            self.sums[k] += ms.min(COUNTED_MAX_MS);
            self.counts[k] += 1;
        }
        self.tick += 1;
        if self.tick % PERIOD_TICKS == TRIAL_TICKS {
            let enough = (TRIAL_TICKS / 8) as u32;
            if self.counts.iter().all(|&n| n >= enough) {
                let mean = |k: usize| self.sums[k] / f64::from(self.counts[k]);
                self.shared = mean(1) < mean(0);
            }
            self.sums = [0.0; 2];
            self.counts = [0; 2];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `ticks` ticks taking `serial_ms` on one thread and `shared_ms` shared.
    fn run(chooser: &mut SharingChooser, ticks: u64, serial_ms: f64, shared_ms: f64) {
        for _ in 0..ticks {
            let shared = chooser.next();
            chooser.record(true, shared, if shared { shared_ms } else { serial_ms });
        }
    }

    #[test]
    fn the_faster_way_is_kept_until_the_next_trial() {
        let mut c = SharingChooser::new();
        // The trial alternates.
        assert!(!c.next());
        run(&mut c, 1, 1.0, 1.0);
        assert!(c.next());
        // Shared ticks slower (a worker kept off its CPU): one thread after the trial.
        run(&mut c, TRIAL_TICKS - 1, 1.0, 1.4);
        assert!(!c.shared);
        run(&mut c, PERIOD_TICKS - TRIAL_TICKS, 1.0, 1.4);
        // The next trial finds sharing faster again.
        run(&mut c, TRIAL_TICKS, 1.0, 0.7);
        assert!(c.shared);
        assert!(c.next());
    }

    #[test]
    fn a_stall_does_not_decide_and_too_few_ticks_keep_the_choice() {
        let mut c = SharingChooser::new();
        for k in 0..TRIAL_TICKS {
            let shared = c.next();
            // Shared ticks faster, but one of them stalls 50 ms: counted in full it would
            // make sharing the slower way (mean 1.05 against 1.0 ms), at 5 ms it does not.
            let ms = match (shared, k) {
                (true, 11) => 50.0,
                (true, _) => 0.8,
                (false, _) => 1.0,
            };
            c.record(true, shared, ms);
        }
        assert!(c.shared);
        // A trial whose ticks could not share (small work) leaves the choice as it was.
        let mut c = SharingChooser::new();
        c.shared = false;
        for _ in 0..TRIAL_TICKS {
            let shared = c.next();
            c.record(false, shared, 1.0);
        }
        assert!(!c.shared);
    }
}
