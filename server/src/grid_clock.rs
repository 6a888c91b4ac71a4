//! A real-time thread's schedule on the station's grid `t0 + k·period`.
//!
//! Grid points are counted, not summed: `deadline += period` rounds at every tick, and with
//! `t0` (seconds since boot) large the rounding does not average out — on a host ten days
//! up the sum is 0.17 ms off the grid after one hour at 1 kHz (0.59 ms at 3 kHz), and two
//! sums from different starting points drift apart, while the simulation thread matches
//! its 1 ms ticks to the haptic thread's (`sim_wake`).

/// Index of the first grid point at or after `now`.
fn index_at_or_after(t0: f64, period: f64, now: f64) -> u64 {
    ((now - t0) / period).ceil().max(0.0) as u64
}

/// A thread's ticks on the grid.
#[derive(Debug, Clone)]
pub struct GridClock {
    t0: f64,
    period: f64,
    next: u64,
}

impl GridClock {
    /// Ticks every `period` seconds on the grid from `t0`, starting at the first grid point
    /// at or after `now` (CLOCK_MONOTONIC seconds).
    pub fn starting_at(t0: f64, period: f64, now: f64) -> Self {
        Self {
            t0,
            period,
            next: index_at_or_after(t0, period, now),
        }
    }

    /// The next tick's grid index (and on to the one after).
    pub fn advance(&mut self) -> u64 {
        let k = self.next;
        self.next += 1;
        k
    }

    /// Grid point `k` in seconds since `t0`.
    pub fn since_start(&self, k: u64) -> f64 {
        k as f64 * self.period
    }

    /// Grid point `k` on CLOCK_MONOTONIC (seconds).
    pub fn deadline(&self, k: u64) -> f64 {
        self.t0 + self.since_start(k)
    }

    /// Goes on from `now` after a stall instead of running the missed ticks back to back:
    /// the next tick is the first grid point at or after `now`. Returns the index of the
    /// grid point before that one (the tick `now` falls in).
    pub fn resync(&mut self, now: f64) -> u64 {
        self.next = index_at_or_after(self.t0, self.period, now);
        self.next.saturating_sub(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counted_grid_points_stay_on_the_grid_after_days_of_uptime() {
        // Ten days since boot, haptic loops at 1, 2 and 3 kHz against the simulation's
        // 1 ms grid, nine days of ticks in.
        let t0 = 864_000.0;
        let sim = GridClock::starting_at(t0, 1e-3, t0);
        for hz in [1000.0, 2000.0, 3000.0] {
            let mut haptic = GridClock::starting_at(t0, 1.0 / hz, t0);
            let ticks_per_ms = (hz / 1000.0) as u64;
            let k_sim = 9 * 86_400_000u64;
            haptic.next = k_sim * ticks_per_ms;
            let k = haptic.advance();
            let gap_ns = (haptic.since_start(k) - sim.since_start(k_sim)).abs() * 1e9;
            assert!(gap_ns < 1e-3, "{hz} Hz: {gap_ns} ns apart");
        }
        // The float sum the loops used to keep is off the grid by 0.17 ms after one hour
        // at 1 kHz on a host ten days up (0.25 and 0.59 ms at 2 and 3 kHz).
        let (mut summed, period) = (t0, 1e-3);
        for _ in 0..3_600_000 {
            summed += period;
        }
        assert!(((summed - t0) - 3600.0).abs() > 1e-4);
    }

    #[test]
    fn a_resync_goes_on_from_the_grid_point_now_falls_in() {
        let mut clock = GridClock::starting_at(100.0, 0.001, 100.0005);
        assert_eq!(clock.advance(), 1);
        assert_eq!(clock.advance(), 2);
        // Woken at 100.0104: the tick 10 ms in is the current one, 11 the next.
        assert_eq!(clock.resync(100.0104), 10);
        assert_eq!(clock.advance(), 11);
        assert!((clock.deadline(11) - 100.011).abs() < 1e-9);
    }
}
