//! The cutting-affected region: points around the blade woken, quiet ones put to sleep, the
//! solver's active set kept.

use super::*;

impl CuttingStage {
    /// The affected region: the points around the blade's edge woken (again once it has
    /// moved, or a while has passed), the quiet ones put to sleep, the solver's active set
    /// updated.
    pub(super) fn update_region(
        &mut self,
        edge_rest: Option<[Vec3; 2]>,
        plunge_normal: Option<Vec3>,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        if let Some(edge) = edge_rest {
            let due = match self.last_mark {
                None => true,
                Some((last, at)) => {
                    self.moved_enough(&last, &edge) || self.tick - at >= REMARK_AFTER_TICKS
                }
            };
            if due {
                self.mark_affected(&edge, plunge_normal, solver.rest(), grid);
                self.last_mark = Some((edge, self.tick));
            }
        } else {
            self.last_mark = None;
        }
        if self.tick.is_multiple_of(SLEEP_CHECK_EVERY) {
            self.put_to_sleep(solver.velocities());
        }
        if self.active_dirty {
            solver.set_active(&self.awake_list);
            self.active_dirty = false;
        }
    }

    /// Integrates point `i` from the next tick on (it falls asleep again once at rest and
    /// out of the tool's reach).
    pub fn wake_point(&mut self, i: u32) {
        self.wake(i);
    }

    pub(super) fn wake(&mut self, i: u32) {
        self.last_near[i as usize] = self.tick;
        if !std::mem::replace(&mut self.awake[i as usize], true) {
            self.awake_list.push(i);
            self.active_dirty = true;
        }
    }

    /// Wakes every point within R_aff of the rest edge; `plunge_normal` is the blade's
    /// flat's while it goes in point first.
    pub(super) fn mark_affected(
        &mut self,
        edge: &[Vec3; 2],
        plunge_normal: Option<Vec3>,
        rest: &[Vec3],
        grid: &RestGrid,
    ) {
        let centre = (edge[0] + edge[1]) * 0.5;
        let reach = (edge[0] - edge[1]).norm() * 0.5 + self.r_aff;
        let r2 = self.r_aff * self.r_aff;
        self.candidates.clear();
        let candidates = &mut self.candidates;
        grid.for_each_within(rest, &centre, reach, |i, _| {
            if distance_sq_to_segment(&rest[i as usize], &edge[0], &edge[1]) < r2 {
                candidates.push(i);
            }
        });
        // Left/right (physics.md §4.4): the sign of φ(X) = n_b·(X − P), n_b the blade
        // plane's normal, up the edge × the way it moves (+ is the left hand of someone
        // looking along the cut with the edge pointing up), while the blade moves across
        // its edge; plunging, the plane of its flat; lifting leaves the plane undefined
        // (pulling back would flip it).
        let up = (edge[1] - edge[0])
            .try_normalize(1e-12)
            .unwrap_or_else(Vec3::z);
        let across = up.cross(&self.direction);
        let normal = (across.norm() > 0.5 && self.direction.dot(&up) <= 0.7)
            .then(|| across.normalize())
            .or(plunge_normal);
        for r in 0..self.candidates.len() {
            let i = self.candidates[r];
            self.wake(i);
            if let Some(n) = normal {
                let phi = n.dot(&(rest[i as usize] - edge[0]));
                if phi.abs() > 1e-9 * self.spacing_m {
                    self.side[i as usize] = if phi > 0.0 { 1 } else { -1 };
                }
            }
        }
    }

    /// Points out of the tool's reach that have come to rest stop being integrated.
    pub(super) fn put_to_sleep(&mut self, v: &[Vec3]) {
        let v2 = SLEEP_SPEED_M_PER_S * SLEEP_SPEED_M_PER_S;
        let before = self.awake_list.len();
        let (tick, awake, last_near) = (self.tick, &mut self.awake, &self.last_near);
        self.awake_list.retain(|&i| {
            let i = i as usize;
            let asleep = tick - last_near[i] > SLEEP_AFTER_TICKS && v[i].norm_squared() < v2;
            if asleep {
                awake[i] = false;
            }
            !asleep
        });
        if self.awake_list.len() != before {
            self.active_dirty = true;
        }
    }
}
