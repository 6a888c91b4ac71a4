//! The force on the tool read from the tissue (cutting-physics.md §2, §6): the blade's
//! contact reaction (`solver::blade`) while it presses; while cutting, the lips' push on
//! the flats and the fracture term of the force model. Also what the haptic loop's
//! local model needs from it: the tissue's 3 × 3 stiffness seen at the blade, measured as
//! the blade moves, and the energy the press stored.

use crate::force::{CutForce, CutPhase};
use crate::math::{Mat3, Vec3, clamp_eigenvalues};

/// The tissue's stiffness read at the blade is at most this (N/m): a bound on what a
/// reading can be, the stiffest device a station may be configured for (`[output]
/// max_stiffness_n_per_m`, up to 20000 N/m; the station bounds it by its device's).
pub const MAX_LOCAL_STIFFNESS_N_PER_M: f64 = 20_000.0;
/// A stiffness reading needs the blade to have moved this far (m) since the last one:
/// closer, the difference is the solver's tick-to-tick ripple.
const STIFFNESS_BASE_M: f64 = 2e-5;
/// The stiffness is fitted over this many readings (about 0.3–0.4 mm of travel).
const READINGS: usize = 16;
/// What the last estimate weighs in each fit, as this many readings' worth of spread
/// (m²): in directions the recent readings do not span, the estimate stays what it was.
const PRIOR_WEIGHT_M2: f64 = 4.0 * STIFFNESS_BASE_M * STIFFNESS_BASE_M;

/// What the force model keeps of the tissue's reaction between ticks.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TissueForce {
    /// The last readings (tip, the tissue's push on it), oldest overwritten first.
    readings: [(Vec3, Vec3); READINGS],
    /// Readings taken since the blade touched (the ring holds the last [`READINGS`]).
    taken: usize,
    /// The tip and the force on it last tick, for the stored energy.
    last: Option<(Vec3, Vec3)>,
    /// The tissue's stiffness seen at the blade (N/m): symmetric, positive semi-definite.
    stiffness: Mat3,
    stored_j: f64,
}

impl TissueForce {
    /// The tool's force for `cut` (the force model's tick) with the tissue's reaction
    /// `tissue` on the blade whose tip is at `tip`: the reaction while pressing, the
    /// reaction and the fracture term while cutting.
    pub fn combine(
        &mut self,
        cut: &CutForce,
        tissue: Vec3,
        tip: Vec3,
        by_energy: bool,
    ) -> CutForce {
        let mut f = *cut;
        match cut.phase {
            CutPhase::Free => *self = Self::default(),
            CutPhase::Loading => self.read_into(&mut f, tissue, tissue, tip),
            CutPhase::Cutting if by_energy => {
                // The crack front's push (the tissue's) and the friction on the faces.
                self.read_into(&mut f, tissue + cut.force_n, tissue, tip);
                // A fracture dissipates what the jump released: what is left to give back
                // is at most the push's own elastic energy, ½ f²/k.
                let k = self.stiffness.trace() / 3.0;
                let elastic = if k > 0.0 {
                    0.5 * tissue.norm_squared() / k
                } else {
                    0.0
                };
                self.stored_j = self.stored_j.min(elastic);
                f.stored_energy_j = self.stored_j;
            }
            CutPhase::Cutting => {
                // The lips' push on the flats (the tissue's; nothing while a press is being
                // let go: faces backing out are not the blade) and the fracture term. The
                // local model's stiffness stays the fracture term's: the lips' would be read
                // off a blade that moves along its cut, where the force changes with the
                // crack, not with the place.
                self.taken = 0;
                self.last = None;
                self.stored_j = 0.0;
                f.force_n = cut.force_n + tissue;
                f.magnitude_n = f.force_n.norm();
            }
        }
        f
    }

    /// `f` felt as `felt`, with the stiffness and the stored energy of the tissue's push
    /// `tissue` on the tip at `tip`.
    fn read_into(&mut self, f: &mut CutForce, felt: Vec3, tissue: Vec3, tip: Vec3) {
        f.force_n = felt;
        f.magnitude_n = felt.norm();
        f.stiffness_matrix_n_per_m = self.read_stiffness(tissue, tip);
        f.stored_energy_j = self.store(tissue, tip);
    }

    /// The tissue's stiffness seen at the blade: each time the blade has moved
    /// [`STIFFNESS_BASE_M`] since the last reading, the least-squares slope of the tissue's
    /// push against the tip's place over the last [`READINGS`] readings, pulled toward the
    /// last estimate by [`PRIOR_WEIGHT_M2`]. A press teaches the stiffness along the press,
    /// a sideways push the stiffness across (and how the press force changes with it); a
    /// single jump of the contact (a sample slipping) is one reading among sixteen. Kept
    /// symmetric with its eigenvalues within [0, [`MAX_LOCAL_STIFFNESS_N_PER_M`]]: never a
    /// stiffness that pulls the hand in.
    fn read_stiffness(&mut self, force: Vec3, tip: Vec3) -> Mat3 {
        let push = -force;
        let moved = match self.taken {
            0 => true,
            n => (tip - self.readings[(n - 1) % READINGS].0).norm() >= STIFFNESS_BASE_M,
        };
        if !moved {
            return self.stiffness;
        }
        self.readings[self.taken % READINGS] = (tip, push);
        self.taken += 1;
        let held = &self.readings[..self.taken.min(READINGS)];
        if held.len() < 2 {
            return self.stiffness;
        }
        let n = held.len() as f64;
        let x_mean = held.iter().map(|r| r.0).sum::<Vec3>() / n;
        let p_mean = held.iter().map(|r| r.1).sum::<Vec3>() / n;
        let (mut spread, mut covary) = (Mat3::zeros(), Mat3::zeros());
        for (x, p) in held {
            let dx = x - x_mean;
            spread += dx * dx.transpose();
            covary += (p - p_mean) * dx.transpose();
        }
        // K (D + αI) = C + α K_last: the regression where the readings span, the last
        // estimate where they do not. D + αI is positive definite, so the inverse exists.
        let regular = spread + Mat3::identity() * PRIOR_WEIGHT_M2;
        if let Some(inverse) = regular.try_inverse() {
            let fitted = (covary + self.stiffness * PRIOR_WEIGHT_M2) * inverse;
            self.stiffness = clamp_eigenvalues(&fitted, 0.0, MAX_LOCAL_STIFFNESS_N_PER_M);
        }
        self.stiffness
    }

    /// The work the hand has put into the press (J), never below zero: what backing out
    /// may give back.
    fn store(&mut self, force: Vec3, tip: Vec3) -> f64 {
        if let Some((at, before)) = self.last {
            self.stored_j = (self.stored_j - 0.5 * (force + before).dot(&(tip - at))).max(0.0);
        }
        self.last = Some((tip, force));
        self.stored_j
    }
}
