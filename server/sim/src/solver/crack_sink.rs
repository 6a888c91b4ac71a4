//! What the crack takes. When the front jumps, the strain energy the blade stored ahead of
//! its edge is released, and the crack spends it: J_c·w·Δa goes into the new crack faces
//! (cutting-physics.md §3, the energy balance of Mahvash & Hayward). The field does not
//! know that the crack took it, so without this sink the released energy would come back
//! as motion: the unloaded tissue ahead springs back onto the edge at about 1 m/s and hits
//! it (a 3–4 N spike two ticks after each jump, then ringing at the local mode: the
//! liver's fracture trace, docs/CUTTING-DECISIONS.md). The sink damps the points that
//! carried the front, up to what the jump cost, over the next ticks: the tissue settles
//! back onto the edge without ringing instead.

use crate::math::Vec3;

/// The sink closes this many ticks after the jump, whatever it has not taken (the local
/// modes' periods are a few ticks).
const SINK_TICKS: u32 = 20;
/// The sink's damping rate (1/s): about the front's local mode (the liver's rings at
/// 125 Hz, 785 rad/s), so that mode is damped a little past critical and settles within
/// a few milliseconds. All of a tick's kinetic energy taken each sub-step instead left the
/// tissue stuck where it was for the sink's whole life (docs/CUTTING-DECISIONS.md).
const SINK_RATE_PER_S: f64 = 2000.0;

/// The points the crack front loaded and the energy the crack may still take from them.
#[derive(Debug, Clone)]
pub(crate) struct CrackSink {
    points: Vec<u32>,
    marked: Vec<bool>,
    budget_j: f64,
    ticks_left: u32,
    /// At the tick's start, for a retry.
    at_tick: (f64, u32),
}

impl CrackSink {
    /// Room for a body of `points` points (made once).
    pub(crate) fn with_room(points: usize) -> Self {
        Self {
            points: Vec::with_capacity(points),
            marked: vec![false; points],
            budget_j: 0.0,
            ticks_left: 0,
            at_tick: (0.0, 0),
        }
    }

    /// The front jumped: `budget_j` may be taken from `points` (each once) over the next
    /// ticks. A sink still open keeps its points and what it has not taken (the jump
    /// before's energy is the crack's too).
    pub(crate) fn open(&mut self, points: impl Iterator<Item = u32>, budget_j: f64) {
        if self.ticks_left == 0 {
            for &k in &self.points {
                self.marked[k as usize] = false;
            }
            self.points.clear();
            self.budget_j = 0.0;
        }
        for k in points {
            let Some(m) = self.marked.get_mut(k as usize) else {
                continue;
            };
            if !*m && self.points.len() < self.points.capacity() {
                *m = true;
                self.points.push(k);
            }
        }
        self.budget_j += budget_j.max(0.0);
        self.ticks_left = SINK_TICKS;
    }

    /// A tick starts (kept for its retries).
    pub(crate) fn begin_tick(&mut self) {
        self.at_tick = (self.budget_j, self.ticks_left);
    }

    /// A (re)try of the tick starts from its start's budget.
    pub(crate) fn begin_attempt(&mut self) {
        (self.budget_j, self.ticks_left) = self.at_tick;
    }

    /// Damps the sink's points (velocities `v`, masses `mass`) over a step of `h` at
    /// [`SINK_RATE_PER_S`], taking at most what is left of the budget. Returns what it took.
    pub(crate) fn absorb(&mut self, v: &mut [Vec3], mass: &[f64], h: f64) -> f64 {
        if self.budget_j <= 0.0 || self.ticks_left == 0 {
            return 0.0;
        }
        let kinetic: f64 = self
            .points
            .iter()
            .map(|&k| 0.5 * mass[k as usize] * v[k as usize].norm_squared())
            .sum();
        if kinetic <= 0.0 || !kinetic.is_finite() {
            return 0.0;
        }
        let damped = 1.0 - (-2.0 * SINK_RATE_PER_S * h).exp();
        let take = (kinetic * damped).min(self.budget_j);
        let scale = (1.0 - take / kinetic).max(0.0).sqrt();
        for &k in &self.points {
            v[k as usize] *= scale;
        }
        self.budget_j -= take;
        take
    }

    /// The tick is done: one tick less open.
    pub(crate) fn end_tick(&mut self) {
        self.ticks_left = self.ticks_left.saturating_sub(1);
        if self.ticks_left == 0 {
            self.budget_j = 0.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// It takes what is there up to its budget, from its points only, and closes.
    #[test]
    fn takes_up_to_its_budget_and_closes() {
        let mut sink = CrackSink::with_room(3);
        let mass = [2.0, 2.0, 2.0];
        let mut v = [Vec3::x(), Vec3::x(), Vec3::x()];
        sink.open([0, 1, 1].into_iter(), 1.0);
        sink.begin_tick();
        // 2 J there, 1 J taken in a long step: half the energy, velocities by 1/√2.
        assert!((sink.absorb(&mut v, &mass, 1.0) - 1.0).abs() < 1e-15);
        assert!((v[0].x - 0.5f64.sqrt()).abs() < 1e-15);
        assert_eq!(v[2], Vec3::x());
        assert_eq!(sink.absorb(&mut v, &mass, 1.0), 0.0);
        // A retry starts from the tick's budget; a short step takes its share.
        sink.begin_attempt();
        v = [Vec3::x(), Vec3::x(), Vec3::x()];
        let h = 1e-4;
        let share = 1.0 - (-2.0 * SINK_RATE_PER_S * h).exp();
        assert!((sink.absorb(&mut v, &mass, h) - 2.0 * share).abs() < 1e-12);
        for _ in 0..SINK_TICKS {
            sink.end_tick();
        }
        sink.begin_tick();
        sink.open([2].into_iter(), 0.0);
        assert_eq!(sink.absorb(&mut v, &mass, 1.0), 0.0);
        // A jump while the sink is open adds its energy and its points.
        let mut v = [Vec3::x(), Vec3::x(), Vec3::x()];
        sink.open([1].into_iter(), 0.5);
        assert!((sink.absorb(&mut v, &mass, 1.0) - 0.5).abs() < 1e-15);
        assert_eq!(v[0], Vec3::x());
        for k in [1, 2] {
            assert!((v[k].x - 0.75f64.sqrt()).abs() < 1e-15);
        }
    }
}
