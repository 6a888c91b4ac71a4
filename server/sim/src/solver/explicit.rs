//! Explicit symplectic Euler with automatic sub-stepping and the divergence guard
//! (physics.md §2.1, §2.5).

use super::blade::Field;
use super::events::{DivergenceReason, SolverEvent, StepReport};
use super::{ForceBuffer, MAX_SUBSTEPS, Solver, held};
use crate::math::Vec3;
use crate::mls::forces::ForceStats;

/// Energy below this is treated as zero by the growth test (J): a gram at 1.4 mm/s. Near
/// rest the little energy left is in the fastest modes, whose measured energy swings by
/// half within a tick at 0.5 dt_crit with nothing wrong; at 1e-12 J that swing rolled
/// ticks back (the shoulder's 16-stroke session: 1.2e-10 → 1.9e-10 J, no work put in). A
/// real divergence grows past this within sub-steps, and the speed test stands beside it.
pub(super) const ENERGY_FLOOR: f64 = 1e-9;
/// Allowed growth of total energy within a tick beyond the work put in.
const ENERGY_GROWTH: f64 = 1.5;
/// A point may move at most this many lattice spacings in one sub-step.
const MAX_MOVE_SPACINGS: f64 = 0.3;
/// Sub-steps added by rollbacks are halved again after this many calm ticks.
const CALM_TICKS_BEFORE_RELAXING: u32 = 1000;
/// How much a strain-stiffening tissue's tangent may grow within a tick over the last
/// tick's largest (the blade loads the crack tip over many ticks).
const STIFFENING_GROWTH: f64 = 1.5;

impl Solver {
    pub(super) fn tick_explicit(&mut self, dt: f64) -> StepReport {
        self.plan_substeps(dt);
        self.follow_stiffening();
        for &i in &self.active_list {
            let i = i as usize;
            self.snap_p[i] = self.p[i];
            self.snap_v[i] = self.v[i];
        }
        if let Some(blade) = &mut self.blade {
            blade.begin_tick();
        }
        self.crack_sink.begin_tick();
        let mut rollbacks = 0;
        loop {
            if let Some(blade) = &mut self.blade {
                blade.begin_attempt();
            }
            self.crack_sink.begin_attempt();
            match self.run_substeps(dt) {
                Ok((stats, work, kinetic)) => {
                    if let Some(blade) = &mut self.blade {
                        blade.end_tick();
                    }
                    self.crack_sink.end_tick();
                    self.max_stiffening = stats.max_stiffening;
                    // Slaved nodes where the tick's last positions put them.
                    self.slaves.interpolate(&mut self.p);
                    self.note_clamping(&stats);
                    self.relax_substeps(rollbacks);
                    return StepReport {
                        substeps: self.substeps,
                        dt_sub_s: dt / self.substeps as f64,
                        rollbacks,
                        diverged: false,
                        // Points outside the active set are at rest (their velocity is
                        // zeroed when they leave it): O(active), not O(body).
                        kinetic_energy: kinetic,
                        elastic_energy: stats.energy(),
                        min_det_f: stats.min_det_f,
                        clamped_points: stats.clamped_points,
                        iterations: 0,
                        work_j: work,
                    };
                }
                Err((reason, at)) => {
                    for &i in &self.active_list {
                        let i = i as usize;
                        self.p[i] = self.snap_p[i];
                        self.v[i] = self.snap_v[i];
                    }
                    if rollbacks >= self.config.max_rollbacks || self.substeps >= MAX_SUBSTEPS {
                        // Keep the last good state, at rest: nothing non-finite leaves. The
                        // state may be stiffer than at the last estimate: re-plan the step.
                        self.v.iter_mut().for_each(|v| *v = Vec3::zeros());
                        self.events.push(SolverEvent::Diverged {
                            tick: self.tick,
                            reason,
                        });
                        self.dt_crit = None;
                        self.calm_ticks = 0;
                        return StepReport {
                            substeps: self.substeps,
                            dt_sub_s: dt / self.substeps as f64,
                            rollbacks,
                            diverged: true,
                            ..StepReport::default()
                        };
                    }
                    rollbacks += 1;
                    self.substeps = (self.substeps * 2).min(MAX_SUBSTEPS);
                    self.events.push(SolverEvent::Rollback {
                        tick: self.tick,
                        reason,
                        detected_at_substep: at,
                        substeps: self.substeps,
                    });
                }
            }
        }
    }

    /// After a run of calm ticks, gives back one doubling that a rollback added.
    fn relax_substeps(&mut self, rollbacks: u32) {
        if rollbacks > 0 {
            self.calm_ticks = 0;
            return;
        }
        self.calm_ticks += 1;
        if self.calm_ticks >= CALM_TICKS_BEFORE_RELAXING && self.substeps > self.planned_substeps {
            self.substeps = (self.substeps / 2).max(self.planned_substeps);
            self.calm_ticks = 0;
        }
    }

    /// A strain-stiffening tissue is stiffer where it is strained (at the crack tip, under
    /// the blade) than when dt_crit was estimated: ω goes as the square root of the
    /// tangent's factor, so the sub-steps do too. Raised at once, relaxed like a rollback's.
    fn follow_stiffening(&mut self) {
        if self.params.stiffening <= 0.0 || self.config.dt_override_s.is_some() {
            return;
        }
        let factor = self.max_stiffening * STIFFENING_GROWTH / self.stiffening_at_estimate;
        if factor > 1.0 {
            let wanted = (f64::from(self.planned_substeps) * factor.sqrt()).ceil();
            self.substeps = self.substeps.max((wanted as u32).min(MAX_SUBSTEPS));
        }
    }

    /// Sets the sub-step count for ticks of `dt`, from dt_crit (computed when missing) or the
    /// override. Kept across ticks, so rollbacks' halvings persist (until calm returns).
    pub(super) fn plan_substeps(&mut self, dt: f64) {
        if self.dt_crit.is_some() && self.substeps_for_dt == dt {
            return;
        }
        let fresh = self.dt_crit.is_none();
        let mut dt_crit = self.dt_crit();
        if !std::mem::replace(&mut self.whole_steps_tried, true) {
            dt_crit = self.scale_mass_to_whole_substeps(dt, dt_crit);
        }
        let h = self
            .config
            .dt_override_s
            .unwrap_or(self.config.safety * dt_crit);
        self.substeps = ((dt / h).ceil() as u32).clamp(1, MAX_SUBSTEPS);
        self.planned_substeps = self.substeps;
        self.keep_planned_substeps(dt, self.substeps);
        self.substeps_for_dt = dt;
        if fresh {
            self.events.push(SolverEvent::TimeStep {
                tick: self.tick,
                dt_crit_s: dt_crit,
                substeps: self.substeps,
            });
        }
    }

    /// One attempt at the tick. Fixed dofs move linearly from their tick-start positions to
    /// their targets. Returns the last force statistics, the work put in and the kinetic
    /// energy at the end, or why the attempt diverged and in which sub-step.
    fn run_substeps(&mut self, dt: f64) -> Result<(ForceStats, f64, f64), (DivergenceReason, u32)> {
        let n = self.substeps;
        let h = dt / n as f64;
        let decay = (-self.config.damping_per_s * h).exp();
        let max_move = MAX_MOVE_SPACINGS * self.spacing_m;
        let gravity = self.config.gravity;
        let mut reference: Option<(f64, f64)> = None;
        let mut work = 0.0;
        let mut stats = None;
        let mut kinetic = 0.0;
        // Moves of the fixed dofs in the previous sub-step: their work is the trapezoid
        // −½(f_before + f_after)·d, completed once the force after the move is known.
        // A free point's entry stays zero all tick (only fixed dofs move by constraint).
        let mut moved_fixed = std::mem::take(&mut self.scratch[2]);
        self.fixed_active.clear();
        for &i in &self.active_list {
            moved_fixed[i as usize] = Vec3::zeros();
            if self.fixed[i as usize] != [false; 3] {
                self.fixed_active.push(i);
            }
        }
        let result = self.substep_loop(
            n,
            h,
            decay,
            max_move,
            gravity,
            &mut reference,
            &mut work,
            &mut stats,
            &mut moved_fixed,
            &mut kinetic,
        );
        self.scratch[2] = moved_fixed;
        result?;
        Ok((
            stats.expect("a tick has at least one sub-step"),
            work,
            kinetic,
        ))
    }

    #[allow(clippy::too_many_arguments)]
    fn substep_loop(
        &mut self,
        n: u32,
        h: f64,
        decay: f64,
        max_move: f64,
        gravity: Vec3,
        reference: &mut Option<(f64, f64)>,
        work: &mut f64,
        stats: &mut Option<ForceStats>,
        moved_fixed: &mut [Vec3],
        kinetic_out: &mut f64,
    ) -> Result<(), (DivergenceReason, u32)> {
        // The kinetic energy of the state each sub-step starts from: summed once here, then
        // by the integration loop as it sets the velocities (the same terms in the same
        // order as `active_kinetic_energy`, without a second pass over the points).
        let mut kinetic = self.active_kinetic_energy();
        for s in 0..n {
            if let Some(blade) = &mut self.blade {
                blade.begin_substep(
                    s as f64 / n as f64,
                    (s + 1) as f64 / n as f64,
                    &self.p,
                    max_move,
                );
            }
            let st = self.evaluate_elastic(ForceBuffer::Force);
            if let Some(held) = &mut self.held {
                // Their work is counted with the applied loads' below.
                held.forces(&self.p, &mut self.held_force, true, held::Vertices::Awake);
            }
            if let Some(blade) = &mut self.blade {
                // Their work is counted with the applied loads' below, too.
                blade.lip_forces(&self.p, &self.mass, &mut self.lip_force, h, Field::Explicit);
            }
            if !st.finite {
                return Err((DivergenceReason::NonFinite, s));
            }
            for &i in &self.fixed_active {
                let i = i as usize;
                *work -= 0.5 * self.force[i].dot(&moved_fixed[i]);
            }
            // The growth is measured on the total energy, and allowed in proportion to its
            // part that cannot be negative: a layer's prestress energy S₀ : E is below zero
            // where the layer has shortened (without prestress the two are the same).
            let energy = kinetic + st.energy();
            let (e0, scale) = *reference.get_or_insert((energy, kinetic + st.unsigned_energy()));
            let bound = ENERGY_GROWTH * (scale + *work) + (e0 - scale) + ENERGY_FLOOR;
            if energy.is_nan() || energy > bound {
                return Err((DivergenceReason::EnergyGrowth, s));
            }
            let frac = (s + 1) as f64 / n as f64;
            kinetic = 0.0;
            for idx in 0..self.active_list.len() {
                let i = self.active_list[idx] as usize;
                let applied = self.external[i]
                    + gravity * self.base_mass[i]
                    + self.held_force[i]
                    + self.lip_force[i];
                let mass = self.mass[i];
                let moved = if self.fixed[i] == [false; 3] {
                    // A free point (nearly all of them): its three dofs at once.
                    let total = self.force[i] + applied;
                    let v = (self.v[i] + total * (h / mass)) * decay;
                    let d = v * h;
                    *work += applied.dot(&d);
                    self.v[i] = v;
                    self.p[i] += d;
                    kinetic += 0.5 * mass * v.x * v.x;
                    kinetic += 0.5 * mass * v.y * v.y;
                    kinetic += 0.5 * mass * v.z * v.z;
                    d
                } else {
                    let mut moved = Vec3::zeros();
                    for a in 0..3 {
                        if self.fixed[i][a] {
                            let goal =
                                self.snap_p[i][a] + frac * (self.target[i][a] - self.snap_p[i][a]);
                            let d = goal - self.p[i][a];
                            // The constraint holds the dof against the elastic force, so it
                            // does −f_elastic·d of work on the body (the applied load's own
                            // work cancels); this is the first half of the trapezoid.
                            *work -= 0.5 * self.force[i][a] * d;
                            moved_fixed[i][a] = d;
                            self.p[i][a] = goal;
                            self.v[i][a] = d / h;
                        } else {
                            moved_fixed[i][a] = 0.0;
                            let total = self.force[i][a] + applied[a];
                            self.v[i][a] = (self.v[i][a] + h * total / mass) * decay;
                            let d = h * self.v[i][a];
                            *work += applied[a] * d;
                            self.p[i][a] += d;
                            moved[a] = d;
                            kinetic += 0.5 * mass * self.v[i][a] * self.v[i][a];
                        }
                    }
                    moved
                };
                // Squared: no root per point (an overflow of a finite move is a move too far).
                let step = moved.norm_squared();
                if !step.is_finite() || step > max_move * max_move {
                    return Err(if moved.iter().all(|c| c.is_finite()) {
                        (DivergenceReason::Speed, s)
                    } else {
                        (DivergenceReason::NonFinite, s)
                    });
                }
            }
            let (gained, done) = self.project_blade(h, true);
            kinetic += gained - self.crack_sink.absorb(&mut self.v, &self.mass, h);
            *work += done;
            *stats = Some(st);
        }
        *kinetic_out = kinetic;
        Ok(())
    }

    pub(super) fn note_clamping(&mut self, stats: &ForceStats) {
        let clamping = stats.clamped_points > 0;
        if clamping && !self.clamping {
            self.events.push(SolverEvent::ExtremeDeformation {
                tick: self.tick,
                points: stats.clamped_points,
                min_det_f: stats.min_det_f,
            });
        }
        self.clamping = clamping;
        self.last_stats = Some(*stats);
    }
}
