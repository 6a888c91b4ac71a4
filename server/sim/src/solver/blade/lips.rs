//! The lips against the flats: a compliant contact with friction between each flat and the
//! lip of its own side of the incision (`pipeline/cutting/lips.rs` lays the samples), and
//! the bound that keeps its springs within what the step resolves. The spine's samples
//! (`pipeline/cutting/spine.rs`) are pushed by the spine with the same contact.

use super::{BLADE_FRICTION, BladeBody, DEEP_MEET_M, FRONT_CATCH_UP_M_PER_S, Meeting};
use super::{LIP_HELD_LEAD, LIP_LET_GO_LEAD, LIP_STABLE_SHARE};
use crate::math::Vec3;

/// How the step that takes the lips' push integrates the points' own field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(in crate::solver) enum Field {
    /// Explicitly, in sub-steps: the lips' springs are bounded by what one resolves.
    Explicit,
    /// Implicitly (the projective step): the field holds the points the lips push, and
    /// no mass-based bound is put on the springs (docs/CUTTING-DECISIONS.md, "The lips'
    /// springs and the step").
    Implicit,
}

/// A lip (spine) sample pressed into its flat (the spine) this sub-step, before its spring
/// is bounded.
#[derive(Debug, Clone, Copy)]
pub(super) struct Pressed {
    sample: usize,
    /// How deep it is in its flat (m, negative), the flat's outward normal and where the
    /// sample is on the flat (blade frame).
    gap: f64,
    normal: Vec3,
    on_face: Vec3,
    /// Its spring (N/m) as the flat's hold and cover give it.
    stiffness: f64,
}

impl BladeBody {
    /// The lips' push on the tissue at the points `p` for a sub-step of `h`, into `out`
    /// (what it put there last sub-step cleared first): a lip sample inside its flat is
    /// pushed out by `lip_stiffness` × how deep it is, and held along the flat toward where
    /// it stuck by a spring as stiff, at most μ × the push (past that it slides and sticks
    /// again where it got to). A spine sample inside the spine likewise, with
    /// `spine_stiffness`. The blade gets the opposite ([`Self::project`] or
    /// [`Self::add_step_force`] books it).
    ///
    /// A force, not a constraint: a lip sample follows a lattice's worth of tissue (grams
    /// on the liver), and held rigidly every contact it made or broke was that mass
    /// stopped within a sub-step — 0.1 N of chatter a tick on the liver. The lip gives way
    /// at the blade over a patch far below the lattice's spacing, which the field cannot
    /// draw; the stiffness is that patch's (`lips`), in series with the field. With an
    /// explicit `field`, on light points (a sliver's corner: a quarter of a milligram on the
    /// tumour scan, where a gram is usual) the springs are bounded so that together they
    /// give no point more than what a sub-step of `h` resolves
    /// ([`Self::bound_lip_springs`]): stiffer, a single sub-step flung it.
    pub(in crate::solver) fn lip_forces(
        &mut self,
        p: &[Vec3],
        mass: &[f64],
        out: &mut [Vec3],
        h: f64,
        field: Field,
    ) {
        for &k in &self.written {
            out[k as usize] = Vec3::zeros();
        }
        self.written.clear();
        self.lip_force = Vec3::zeros();
        self.spine_force = Vec3::zeros();
        self.press_lips(p, h);
        if field == Field::Explicit {
            self.bound_lip_springs(mass, h);
        }
        let mut pressed = std::mem::take(&mut self.pressed);
        for c in &pressed {
            let push = -c.gap * c.stiffness;
            let most = BLADE_FRICTION * push;
            let tangent = self.friction(c.sample, c.on_face, c.normal, most, |slip| {
                slip * c.stiffness
            });
            let f = self.at.world(&(c.normal * push + tangent));
            self.lip_force += f;
            if self.spine[c.sample] {
                self.spine_force += f;
            }
            for (k, w) in self.samples.row(c.sample) {
                if !std::mem::replace(&mut self.seen[k], true) {
                    self.written.push(k as u32);
                }
                out[k] += f * w;
            }
        }
        pressed.clear();
        self.pressed = pressed;
        for &k in &self.written {
            self.seen[k as usize] = false;
        }
    }

    /// Finds the lip samples inside their flats, and the spine samples inside the spine, at
    /// the points `p` (a sub-step of `h` taking up the slack of those laid inside the
    /// steel) into `self.pressed`; the spine's deepest into `spine_indentation`.
    fn press_lips(&mut self, p: &[Vec3], h: f64) {
        let at = self.at;
        self.pressed.clear();
        self.spine_indentation = 0.0;
        for s in 0..self.len() {
            if (self.side[s] == 0.0 && !self.spine[s]) || self.cut[s] {
                continue;
            }
            let Some(Meeting {
                l,
                newly,
                mut gap,
                normal,
                ..
            }) = self.meet(s, p, true)
            else {
                continue;
            };
            if newly && -gap > 2.0 * self.substep_move + DEEP_MEET_M {
                // Laid where the steel already was: taken up at a hand's pace.
                self.slack[s] = -gap;
            }
            if self.slack[s] > 0.0 {
                let left = (self.slack[s] - FRONT_CATCH_UP_M_PER_S * h).max(0.0);
                self.slack[s] = left.min((-gap).max(0.0));
                gap += self.slack[s];
            }
            if gap >= 0.0 {
                continue;
            }
            // The share of the sample's patch the steel covers: a patch crossing the spine,
            // or the tip passing it, lets go over its width, not at once.
            let patch = match self.spine[s] {
                true => self.spine_pitch,
                false => self.lip_pitch,
            };
            let covered = |inside: f64| (inside / patch + 0.5).clamp(0.0, 1.0);
            let stiffness = if self.spine[s] {
                // As deep as its push says: a patch the tip is letting go is pressed by
                // what of it the steel still covers.
                let cover = covered(l.x);
                self.spine_indentation = self.spine_indentation.max(-gap * cover);
                self.spine_stiffness * cover
            } else {
                let lead = at.side().dot(&self.heading) * self.side[s];
                let held =
                    ((LIP_LET_GO_LEAD - lead) / (LIP_LET_GO_LEAD - LIP_HELD_LEAD)).clamp(0.0, 1.0);
                self.lip_stiffness * held * covered(l.x).min(covered(at.width - l.y))
            };
            if stiffness > 0.0 {
                self.pressed.push(Pressed {
                    sample: s,
                    gap,
                    normal,
                    on_face: l - normal * gap,
                    stiffness,
                });
            }
        }
    }

    /// Bounds the pressed samples' springs so that together they give the points at most
    /// ω² = [`LIP_STABLE_SHARE`]/h² (`mass` per point), however many samples share a point.
    ///
    /// Sample s's spring k_s on its row w_s adds k_s·w_s·w_sᵀ (times the identity across
    /// the three axes while it sticks: the push and the friction; sliding, the friction's
    /// pull along the slip couples the normal in, a block of norm √(1+μ²), and the hold
    /// and cover ramps add a little: both within the margin, not in the bound) to K; in
    /// M^{-½}KM^{-½} that is
    /// k_s·a_s·a_sᵀ with a_sk = w_sk/√m_k. Gershgorin: every eigenvalue is at most the
    /// largest row sum, point k's Σ_s k_s·|a_sk|·‖a_s‖₁. With R_k = Σ_s |a_sk|·‖a_s‖₁ over
    /// the pressed samples, k_s ≤ share/(h²·max over its row of R_k) keeps every row sum,
    /// and so ω², within share/h². (One sample on one point: k ≤ share·m/h² exactly.)
    /// Marks the points it reaches in `seen` and `written`; [`Self::lip_forces`] clears
    /// `seen` after its own pass over the same points.
    fn bound_lip_springs(&mut self, mass: &[f64], h: f64) {
        let spread = |w: f64, k: usize| w.abs() / mass[k].max(1e-300).sqrt();
        for c in &self.pressed {
            let l1: f64 = self.samples.row(c.sample).map(|(k, w)| spread(w, k)).sum();
            for (k, w) in self.samples.row(c.sample) {
                if !std::mem::replace(&mut self.seen[k], true) {
                    self.written.push(k as u32);
                }
                self.reach[k] += spread(w, k) * l1;
            }
        }
        let share = LIP_STABLE_SHARE / (h * h);
        for c in &mut self.pressed {
            let widest = self
                .samples
                .row(c.sample)
                .filter(|&(_, w)| w != 0.0)
                .map(|(k, _)| self.reach[k])
                .fold(0.0, f64::max);
            if widest > 0.0 {
                c.stiffness = c.stiffness.min(share / widest);
            }
        }
        // (`lip_forces` clears `seen` after its own pass over the same points.)
        for &k in &self.written {
            self.reach[k as usize] = 0.0;
        }
    }
}
