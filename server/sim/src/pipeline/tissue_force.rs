//! The force on the tool read from the tissue (cutting-physics.md §2, §6): the blade's
//! contact reaction (`solver::blade`) while it presses; while cutting, the fracture term of
//! the force model (the flats against the lips are not on yet). Also what the haptic loop's local model needs from it: the tissue's stiffness
//! along the press, measured as the blade moves, and the energy the press stored.

use crate::force::{CutForce, CutPhase};
use crate::math::Vec3;

/// The local model's stiffness is at most this (N/m): about what an impedance device of
/// the Phantom/Touch class renders stably at 1 kHz.
pub const MAX_LOCAL_STIFFNESS_N_PER_M: f64 = 1000.0;
/// A stiffness reading needs the blade to have moved this far along the press (m) since
/// the last one: closer, the difference is the solver's tick-to-tick ripple.
const STIFFNESS_BASE_M: f64 = 2e-5;
/// Each reading moves the estimate this fraction of the way.
const STIFFNESS_BLEND: f64 = 0.25;

/// What the force model keeps of the tissue's reaction between ticks.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TissueForce {
    /// Where the tip and the force along the press were at the last stiffness reading.
    reading: Option<(f64, f64)>,
    /// The tip and the force on it last tick, for the stored energy.
    last: Option<(Vec3, Vec3)>,
    stiffness_n_per_m: f64,
    stored_j: f64,
}

impl TissueForce {
    /// The tool's force for `cut` (the force model's tick) with the tissue's reaction
    /// `tissue` on the blade whose tip is at `tip`: the reaction while pressing, the
    /// fracture term while cutting.
    pub fn combine(&mut self, cut: &CutForce, tissue: Vec3, tip: Vec3) -> CutForce {
        let mut f = *cut;
        match cut.phase {
            CutPhase::Free => *self = Self::default(),
            CutPhase::Loading => {
                f.force_n = tissue;
                f.magnitude_n = tissue.norm();
                f.stiffness_n_per_m = self.read_stiffness(&f, tip);
                f.stored_energy_j = self.store(tissue, tip);
            }
            CutPhase::Cutting => {
                // The blade's faces hold nothing while cutting (what they held is being let
                // go by faces backing out, not by the blade): the fracture term alone.
                self.reading = None;
                self.last = None;
                self.stored_j = 0.0;
            }
        }
        f
    }

    /// The tissue's stiffness along the press: the change of its push back over the
    /// blade's travel, read once the blade has moved [`STIFFNESS_BASE_M`], blended, never
    /// negative and at most [`MAX_LOCAL_STIFFNESS_N_PER_M`].
    fn read_stiffness(&mut self, f: &CutForce, tip: Vec3) -> f64 {
        let d = f.direction;
        if d == Vec3::zeros() {
            return self.stiffness_n_per_m;
        }
        let (x, push) = (tip.dot(&d), -f.force_n.dot(&d));
        match self.reading {
            None => self.reading = Some((x, push)),
            Some((x0, push0)) if (x - x0).abs() >= STIFFNESS_BASE_M => {
                let k = ((push - push0) / (x - x0)).clamp(0.0, MAX_LOCAL_STIFFNESS_N_PER_M);
                self.stiffness_n_per_m += (k - self.stiffness_n_per_m) * STIFFNESS_BLEND;
                self.reading = Some((x, push));
            }
            Some(_) => {}
        }
        self.stiffness_n_per_m
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
