//! What the solver reports: events in a fixed-capacity queue (no allocation on the real-time
//! path) and a per-tick report.

use serde::Serialize;

/// Why a step was judged divergent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DivergenceReason {
    /// A position, velocity or force was NaN or infinite.
    NonFinite,
    /// Total energy grew beyond 1.5× its value at the tick start plus the work put in.
    EnergyGrowth,
    /// A point moved more than 0.3 lattice spacings in one sub-step.
    Speed,
}

/// Something the caller should know about.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SolverEvent {
    /// A tick diverged; the state was rolled back to the tick start and retried with more
    /// sub-steps.
    Rollback {
        /// Tick number.
        tick: u64,
        /// What was detected.
        reason: DivergenceReason,
        /// The sub-step (0-based) of the failed attempt in which it was detected.
        detected_at_substep: u32,
        /// Sub-steps per tick from now on.
        substeps: u32,
    },
    /// The tick could not be made stable; the state was restored to the tick start with
    /// velocities zeroed (nothing non-finite leaves the solver).
    Diverged {
        /// Tick number.
        tick: u64,
        /// What was detected last.
        reason: DivergenceReason,
    },
    /// The stable time step was (re)computed.
    TimeStep {
        /// Tick number.
        tick: u64,
        /// Critical step 2/ω_max (s).
        dt_crit_s: f64,
        /// Sub-steps per tick.
        substeps: u32,
    },
    /// The uncut body was given a little mass so that ticks take fewer sub-steps (see
    /// `Solver::whole_step_mass`).
    MassScaled {
        /// Tick number.
        tick: u64,
        /// Points given mass.
        points: u32,
        /// Mass added (kg).
        added_kg: f64,
        /// Sub-steps per tick with it.
        substeps: u32,
    },
    /// Some points left det F ∈ [0.2, 5]; their stress was evaluated with clamped singular
    /// values.
    ExtremeDeformation {
        /// Tick number.
        tick: u64,
        /// Points clamped in the tick's last sub-step.
        points: u32,
        /// Smallest det F seen.
        min_det_f: f64,
    },
}

/// A ring of events with a fixed capacity; the oldest is dropped when full.
#[derive(Debug, Clone)]
pub struct EventQueue {
    items: [Option<SolverEvent>; Self::CAPACITY],
    head: usize,
    len: usize,
    dropped: u64,
}

impl Default for EventQueue {
    fn default() -> Self {
        Self {
            items: [None; Self::CAPACITY],
            head: 0,
            len: 0,
            dropped: 0,
        }
    }
}

impl EventQueue {
    /// Events held before the oldest is dropped.
    pub const CAPACITY: usize = 64;

    /// Adds an event (never allocates).
    pub fn push(&mut self, e: SolverEvent) {
        if self.len == Self::CAPACITY {
            self.head = (self.head + 1) % Self::CAPACITY;
            self.len -= 1;
            self.dropped += 1;
        }
        self.items[(self.head + self.len) % Self::CAPACITY] = Some(e);
        self.len += 1;
    }

    /// Takes the oldest event.
    pub fn pop(&mut self) -> Option<SolverEvent> {
        if self.len == 0 {
            return None;
        }
        let e = self.items[self.head].take();
        self.head = (self.head + 1) % Self::CAPACITY;
        self.len -= 1;
        e
    }

    /// Events dropped because nobody polled.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// Outcome of one tick.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct StepReport {
    /// Sub-steps taken in the successful attempt.
    pub substeps: u32,
    /// Sub-step length (s).
    pub dt_sub_s: f64,
    /// Rollbacks during this tick.
    pub rollbacks: u32,
    /// True if the tick could not be stabilised (state restored, velocities zeroed).
    pub diverged: bool,
    /// Kinetic energy at the end (J).
    pub kinetic_energy: f64,
    /// Elastic energy at the last force evaluation (J).
    pub elastic_energy: f64,
    /// Smallest det F at the last force evaluation.
    pub min_det_f: f64,
    /// Points with clamped F at the last force evaluation.
    pub clamped_points: u32,
    /// Iterations used (projective dynamics' local/global rounds, Newton's, the implicit
    /// mode's conjugate gradients) where applicable.
    pub iterations: u32,
    /// Work done on the body by applied loads and moving constraints during the tick (J).
    pub work_j: f64,
}

impl StepReport {
    /// The tick's work in passes over its points: a sub-step or an iteration each (the
    /// implicit mode's CG iteration is one force evaluation, as a sub-step is).
    pub fn passes(&self) -> u32 {
        self.substeps + self.iterations
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queue_keeps_the_newest_and_counts_drops() {
        let mut q = EventQueue::default();
        for t in 0..100 {
            q.push(SolverEvent::TimeStep {
                tick: t,
                dt_crit_s: 1.0,
                substeps: 1,
            });
        }
        assert_eq!(q.dropped(), 36);
        let Some(SolverEvent::TimeStep { tick, .. }) = q.pop() else {
            panic!()
        };
        assert_eq!(tick, 36);
        let mut n = 1;
        while q.pop().is_some() {
            n += 1;
        }
        assert_eq!(n, 64);
    }
}
