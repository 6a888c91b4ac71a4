//! The haptic thread wakes the simulation thread as soon as its tick (and the pose it read)
//! is done, instead of the simulation sleeping to a fixed phase behind it.
//!
//! Both threads tick on the station's grid `t0 + k·period`. The simulation used to wake
//! 0.1 ms after each grid point so that it would find the pose the haptic thread had just
//! read; a haptic tick takes a few microseconds, so most of that 0.1 ms was waiting, and it
//! sat directly in the latency from a device pose to the frame that shows it. Now the
//! simulation waits for whichever comes first: the haptic thread's word that its tick on
//! (or after) the grid point is done, or the old phase as a fallback (a haptic thread that
//! woke late, or stalled, delays the simulation by no more than before).
//!
//! The haptic side is a store, a load and, when the simulation waits for this tick or an
//! earlier one, `unpark`: an atomic swap, plus a futex wake if the thread is parked — no
//! lock, no allocation, no wait. (While the simulation computes, its word still names the
//! tick it took, so the haptic thread unparks then too: a swap that leaves a token, and
//! the simulation's next wait checks once more before parking.)

use std::sync::atomic::{AtomicU64, Ordering};
use std::thread::Thread;
use std::time::Duration;

use crate::realtime;

/// Grid times are compared in whole nanoseconds since the station's start, with this much
/// slack for float rounding (k·period at one rate against j·1 ms at the other).
const SLACK_NS: u64 = 1_000;

/// The two threads' shared word.
#[derive(Debug, Default)]
pub struct SimWake {
    /// Grid time (ns since the start) of the haptic thread's last finished tick, + 1
    /// (0: none yet).
    haptic_done: AtomicU64,
    /// Grid time (ns since the start) of the simulation tick waiting for it.
    sim_due: AtomicU64,
}

fn grid_ns(grid_s: f64) -> u64 {
    (grid_s.max(0.0) * 1e9).round() as u64
}

impl SimWake {
    /// New, with no haptic tick done.
    pub fn new() -> Self {
        Self::default()
    }

    /// The haptic thread: its tick on grid time `grid_s` (seconds since the start) is
    /// done. Wakes `sim` if it waits for that tick or an earlier one.
    pub fn haptic_done(&self, grid_s: f64, sim: &Thread) {
        let done = grid_ns(grid_s);
        // SeqCst on both sides: each thread stores its word and then reads the other's, so
        // at least one of them sees the other's store (no lost wake-up).
        self.haptic_done.store(done + 1, Ordering::SeqCst);
        if done + SLACK_NS >= self.sim_due.load(Ordering::SeqCst) {
            sim.unpark();
        }
    }

    /// The simulation thread: waits until the haptic tick on grid time `grid_s` (seconds
    /// since the start) is done, or until `fallback_s` (CLOCK_MONOTONIC seconds) at the
    /// latest. Returns whether the haptic thread's word woke it.
    pub fn wait_for_haptic(&self, grid_s: f64, fallback_s: f64) -> bool {
        let due = grid_ns(grid_s);
        self.sim_due.store(due, Ordering::SeqCst);
        loop {
            let done = self.haptic_done.load(Ordering::SeqCst);
            if done > 0 && done - 1 + SLACK_NS >= due {
                return true;
            }
            let left = fallback_s - realtime::monotonic_s();
            if left <= 0.0 {
                return false;
            }
            // May return early (a token left by an earlier wake, or spuriously): the loop
            // checks again.
            std::thread::park_timeout(Duration::from_secs_f64(left));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn the_haptic_word_wakes_the_simulation_before_its_fallback() {
        let wake = Arc::new(SimWake::new());
        let start = realtime::monotonic_s();
        let waiter = {
            let wake = wake.clone();
            std::thread::spawn(move || {
                let woken = wake.wait_for_haptic(0.005, start + 10.0);
                (woken, realtime::monotonic_s() - start)
            })
        };
        // An earlier grid point is not the one it waits for.
        std::thread::sleep(Duration::from_millis(20));
        wake.haptic_done(0.004, waiter.thread());
        std::thread::sleep(Duration::from_millis(20));
        assert!(!waiter.is_finished(), "woken by an earlier tick");
        wake.haptic_done(0.005, waiter.thread());
        let (woken, after) = waiter.join().unwrap();
        assert!(woken);
        assert!(after < 5.0, "waited {after} s for a tick that was done");
    }

    #[test]
    fn without_the_haptic_word_the_simulation_wakes_at_its_fallback() {
        let wake = SimWake::new();
        let start = realtime::monotonic_s();
        assert!(!wake.wait_for_haptic(0.001, start + 0.03));
        assert!(realtime::monotonic_s() >= start + 0.03);
        // A tick already done returns at once, whatever the fallback.
        wake.haptic_done(0.002, &std::thread::current());
        assert!(wake.wait_for_haptic(0.002, start + 1e6));
        // Float sums a hair off the grid still match.
        assert!(wake.wait_for_haptic(0.002 + 3e-10, start + 1e6));
    }
}
