//! The blade's contacts in stiff mode's projective step (`solver::projective_contact`):
//! each held sample a one-sided constraint of the global solve, its slack taken up by
//! the step, its friction anchor moved where it slid.

use super::{BladeBody, Face, Meeting};
use crate::math::Vec3;

impl BladeBody {
    /// For the projective step's global solve: sample `s`'s one-sided constraint at the
    /// points `p`, against the blade where the tick ends — its face's outward normal (world)
    /// and the offset with gap = n · x − offset at the sample's place x — if the blade holds
    /// it (inside the steel, taking a face as [`Self::project`] does; none while letting
    /// go); `None` if outside, not the blade's, or mostly on points `free` says cannot move.
    pub(in crate::solver) fn constraint(
        &mut self,
        s: usize,
        p: &[Vec3],
        free: impl Fn(usize) -> bool,
    ) -> Option<(Vec3, f64)> {
        if self.cut[s] || self.side[s] != 0.0 || self.spine[s] {
            return None;
        }
        let Meeting {
            x,
            newly,
            mut gap,
            normal: normal_local,
            ..
        } = self.meet(s, p, true)?;
        if !self.mostly_free(s, free) {
            return None;
        }
        // A crack-front sample met behind the edge keeps its slack as in `project`; the
        // step takes it up (`take_up_slack`), and it is never looser than the sample is.
        if newly && (self.capture[s] > 0.0 || self.side[s] != 0.0) {
            self.slack[s] = (-gap).max(0.0);
        }
        // (Let out while lifted out: `take_up_slack` bounds it by the lift's time.)
        if !self.letting_go(s) {
            self.slack[s] = self.slack[s].min((-gap).max(0.0));
        }
        gap += self.slack[s];
        let n = self.at.world(&normal_local);
        Some((n, n.dot(&x) - gap))
    }

    /// A step of `h` with the contacts in its solve (projective) takes up the crack-front
    /// samples' slack at `FRONT_CATCH_UP_M_PER_S`, as `project` does each sub-step.
    pub(in crate::solver) fn take_up_slack(&mut self, h: f64) {
        for s in 0..self.slack.len() {
            self.slack[s] = (self.slack[s] + self.slack_step(s, h)).max(0.0);
        }
    }

    /// For stiff mode's friction: the world displacement along its face that takes held
    /// sample `s` (at the points `p`) back to where it stuck.
    pub(in crate::solver) fn back_to_anchor(&self, s: usize, p: &[Vec3]) -> Option<Vec3> {
        let face = self.face[s]?;
        let (on_face, normal_local) = self.on_face(s, face, p);
        let mut slip = self.anchor[s] - on_face;
        slip -= normal_local * slip.dot(&normal_local);
        Some(self.at.world(&slip))
    }

    /// Held sample `s` slid: it sticks again where it is on its face (at the points `p`).
    pub(in crate::solver) fn stick_here(&mut self, s: usize, p: &[Vec3]) {
        if let Some(face) = self.face[s] {
            self.anchor[s] = self.on_face(s, face, p).0;
        }
    }

    /// Sample `s`'s place (blade frame) projected onto `face`, and the face's normal.
    fn on_face(&self, s: usize, face: Face, p: &[Vec3]) -> (Vec3, Vec3) {
        let l = self.at.local(&self.samples.position(s, p));
        let (gap, normal_local) = self.gap_to(&self.at, s, &l, face);
        (l - normal_local * gap, normal_local)
    }

    /// The force the tissue got from the blade over a whole step (N): a projective step's
    /// contact forces (and the lips' push), counted as the tick's one sub-step.
    pub(in crate::solver) fn add_step_force(&mut self, on_tissue: Vec3) {
        self.force_sum += on_tissue + std::mem::take(&mut self.lip_force);
        self.spine_force_sum += std::mem::take(&mut self.spine_force);
        self.substeps += 1;
    }
}
