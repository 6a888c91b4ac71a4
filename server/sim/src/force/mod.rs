//! Cutting force model (the paper's eqs. 17–19, reinterpreted per physics.md §6).
//!
//! The paper multiplies an internal point force by `Γ = e^{−at} sin(bt) Y(d)`, which starts
//! and ends at zero and pulls the hand into the tissue half the time. Here the force on the
//! blade follows three phases:
//!
//! * **Loading** (blade pressing on intact capsule): the eq. 19 curve used as a *shape*,
//!   `F_pre(x) = F_r · f(x · 3.17/x_r) / 42.85`, which peaks at exactly the rupture force F_r
//!   at the rupture displacement x_r (physics.md §6.2: f peaks at 42.85 at x = 3.17). x is
//!   the indentation along the direction the blade moved when it touched: backing out
//!   unloads along the same curve (the capsule is elastic until it fails), so a press that
//!   stops short of rupture gives back what it took and no more.
//! * **Rupture**: once the blade has pressed x_r, or slid x_r across the capsule while
//!   pressing on it (a slice), the capsule fails.
//! * **Cutting**: the mean force is the fracture work per unit advance plus friction,
//!   `F_mean = J_c·d + F_friction(d)` (d = cut depth; friction grows with the rubbing area,
//!   in proportion to d up to a reference depth), with a decaying ripple in blade travel,
//!   `F = F_mean·(1 + ε e^{−τ/τ_d} sin(2π x_c/λ))`, τ and x_c measured from the rupture.
//!
//! The model is sans-IO: the caller passes time and the blade's contact state; it returns
//! the force on the tool and a local linear model (f₀, x₀, K) that the 1 kHz haptic loop
//! renders between simulation updates. Rate limiting of the rupture drop and passivity are
//! the haptic output stage's job (physics.md §7), not this model's.

use serde::Serialize;

use crate::math::{Mat3, Vec3, clamp_eigenvalues};
use crate::scene::ForceSpec;

/// Coefficients of eq. 19 (x in mm, f in the paper's units): two Gaussians.
const EQ19: [(f64, f64, f64); 2] = [(15.29, 3.164, 0.2933), (27.69, 3.288, 1.746)];
/// Where eq. 19 peaks (mm) and its value there (physics.md §6.2, t9).
const EQ19_PEAK_X: f64 = 3.17;
const EQ19_PEAK_F: f64 = 42.85;

/// eq. 19 and its derivative at x (mm).
fn eq19(x: f64) -> (f64, f64) {
    EQ19.iter().fold((0.0, 0.0), |(f, df), &(a, b, c)| {
        let t = (x - b) / c;
        let g = a * (-t * t).exp();
        (f + g, df - 2.0 * t / c * g)
    })
}

/// Which regime the blade is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CutPhase {
    /// Not touching the tissue.
    Free,
    /// Pressing on intact capsule, before rupture.
    Loading,
    /// Cutting after rupture.
    Cutting,
}

/// The blade's contact with the tissue this update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BladeContact {
    /// The cutting edge is inside the tissue (or pressing on its surface).
    pub in_tissue: bool,
    /// Depth of the cutting edge below the surface at entry (m).
    pub depth_m: f64,
    /// The tip's displacement since the last update (m): what loads and unloads the
    /// capsule (elastic, so every move counts, noise included — it cancels out).
    pub motion_m: Vec3,
    /// The same with the device's position noise taken out (m): the displacement of the
    /// tip's steady point (`pipeline::steady_motion`), zero while the tip only jitters.
    /// What advances the crack and its ripple and sets the press direction.
    pub steady_motion_m: Vec3,
    /// Cutting direction: the blade's recent motion, averaged over a short travel, at most
    /// unit length — shorter while the motion turns round, so that the resistance against
    /// it passes through zero on a reversal instead of flipping in one tick.
    pub direction: Vec3,
    /// The blade entered along an existing incision: no capsule to rupture.
    pub in_existing_cut: bool,
    /// The blade opens no new cut — it is pulling back along its own edge (toward its
    /// back), or moving back along the cut it made: the fracture term fades out and
    /// friction remains.
    pub withdrawing: bool,
    /// Width of the new crack the blade opens per unit of its motion, as a share of its
    /// depth (0–1): the fracture term is J_c × that share of the depth (a second pass along
    /// a cut opens only what lies below the first; a raked blade, its vertical depth).
    pub crack_share: f64,
    /// The tissue the blade presses is crushed (det F of a point a sample the blade holds
    /// follows below [`CRUSHED_DET_F`]): the capsule fails, whatever the indentation.
    pub crushed: bool,
}

/// The capsule fails where the tissue the pressing blade holds has lost this much of its
/// volume (det F below it), before the rupture displacement if need be: on a lattice fine
/// enough to draw the blade's dent, the tissue under a 0.4 mm tip end is crushed to
/// det F ≈ 0.1 well before it has been pressed 3 mm, and springs out at rupture.
pub const CRUSHED_DET_F: f64 = 0.5;

/// The force on the tool and its local linear model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CutForce {
    /// Regime after this update.
    pub phase: CutPhase,
    /// Magnitude of the resistance (N), ≥ 0.
    pub magnitude_n: f64,
    /// Force on the tool (N): `−direction · magnitude_n`.
    pub force_n: Vec3,
    /// Direction the resistance acts against: the (unit) direction the blade pressed in
    /// while loading; while cutting its averaged motion, at most unit length and shorter
    /// while it turns round; zero when free.
    pub direction: Vec3,
    /// The resistance's stiffness as a matrix (N/m): how the push back grows with the
    /// tool's displacement, for the haptic loop's local model. The tissue's, seen at the
    /// blade, when the force is read from the tissue (pressing, `pipeline::tissue_force`);
    /// the fracture term's dF/dx along `direction` otherwise (`k |d| d̂ d̂ᵀ`).
    pub stiffness_matrix_n_per_m: Mat3,
    /// Energy the contact would give back if the blade backed out (J): the loading curve's
    /// work over the current indentation; zero once cutting (fracture and friction give
    /// nothing back). The haptic output stage's passivity observer keeps at least this.
    pub stored_energy_j: f64,
    /// The update was a rupture (capsule failed this update).
    pub ruptured: bool,
}

impl CutForce {
    /// The local linear model for the haptic loop at tool position `x0`: the loop renders
    /// `f = f0 + K (x − x0)` with `K` minus [`Self::stiffness_matrix_n_per_m`] (the
    /// resistance grows as the tool advances, pushing back).
    pub fn local_model(&self, x0: Vec3) -> LocalForceModel {
        LocalForceModel {
            f0_n: self.force_n,
            x0_m: x0,
            stiffness_n_per_m: -self.stiffness_matrix_n_per_m,
            stored_energy_j: self.stored_energy_j,
        }
    }
}

/// A linearisation of the tool force around a position, published by the simulation and
/// rendered by the haptic loop at 1 kHz.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LocalForceModel {
    /// Force at x0 (N).
    pub f0_n: Vec3,
    /// Tool position the model is taken at (m).
    pub x0_m: Vec3,
    /// ∂f/∂x (N/m).
    pub stiffness_n_per_m: Mat3,
    /// Energy the contact would give back if the tool backed out (J), see
    /// [`CutForce::stored_energy_j`].
    pub stored_energy_j: f64,
}

/// How far from its origin a [`LocalForceModel`] is extrapolated (m): two simulation ticks
/// of the blade at a hand's quickest (2 m/s, `pipeline::blade_motion`), as far as a device
/// gets from the blade between two models. Farther — a device that jumped while the blade
/// follows at a hand's speed — the linearisation means nothing: the force changes from `f0`
/// at most as much as this displacement along the stiffest direction would change it (a jump
/// back out of a cut would otherwise read as a pull of stiffness × jump toward the tissue,
/// bounded only by the output stage).
pub const LOCAL_MODEL_REACH_M: f64 = 0.004;

impl LocalForceModel {
    /// The model with its stiffness made symmetric and each of its eigenvalues within
    /// ±`most` (N/m): what the device renders stably (`[output] max_stiffness_n_per_m`).
    /// Force and stored energy unchanged; a non-finite stiffness becomes zero.
    pub fn with_stiffness_at_most(&self, most: f64) -> Self {
        Self {
            stiffness_n_per_m: clamp_eigenvalues(&self.stiffness_n_per_m, -most, most),
            ..*self
        }
    }

    /// The force the model predicts at `x` (N): `f0 + K (x − x0)`, the change `K (x − x0)`
    /// bounded by ‖K‖ · [`LOCAL_MODEL_REACH_M`] (Frobenius norm: the largest stiffness for the
    /// rank-one models the cutting force gives). The bound is on the change, not on the
    /// offset: motion across the stiffness (along the edge, say) must not weaken the part
    /// along it. No allocation (the haptic thread calls it every tick); NaN in, NaN out (the
    /// output stage guards).
    pub fn force_at(&self, x: Vec3) -> Vec3 {
        let change = self.stiffness_n_per_m * (x - self.x0_m);
        let most = self.stiffness_n_per_m.norm() * LOCAL_MODEL_REACH_M;
        let size = change.norm();
        if size > most {
            self.f0_n + change * (most / size)
        } else {
            self.f0_n + change
        }
    }
}

/// The cutting force state machine.
#[derive(Debug, Clone, PartialEq)]
pub struct CuttingForceModel {
    spec: ForceSpec,
    ripple: bool,
    phase: CutPhase,
    /// Indentation of the intact capsule along `press_direction` while loading (m), ≥ 0.
    loading_m: f64,
    /// Unit direction the blade presses in along: the way it moved when it touched the
    /// capsule.
    press_direction: Vec3,
    /// The tip's displacement since it touched, while the press direction is not known
    /// yet (it touched without a steady motion): counted once the direction is.
    unaimed_m: Vec3,
    /// How far the blade has moved across the capsule while pressing on it (m): a slice
    /// ruptures it too. Summed as a vector, so that a hand's tremor cancels out and only a
    /// real slide adds up.
    slide_m: Vec3,
    /// The loading curve's work over the indentation (J): what backing out gives back.
    stored_j: f64,
    /// Time of the last rupture (s).
    rupture_s: f64,
    /// Blade travel since the last rupture (m).
    travel_m: f64,
    /// How much of the fracture term J_c·d the blade carries, 0–1: the new crack's width as
    /// a share of the depth (1 cutting fresh tissue upright, 0 pulling back or along its
    /// own cut), eased toward it over [`ENGAGEMENT_TRAVEL_M`] of travel, so the force moves
    /// between the regimes instead of jumping by J_c·d in one tick.
    engagement: f64,
    /// Factor on the tissue's stiffness (1: the scene's): scales the loading curve and the
    /// friction (the blade's faces press on stiffer walls), not the fracture toughness.
    stiffness: f64,
}

/// Travel over which the fracture term fades in and out (m).
const ENGAGEMENT_TRAVEL_M: f64 = 0.0005;

impl CuttingForceModel {
    /// A model with the scene's force parameters; `ripple` is the scene's feature flag.
    pub fn new(spec: &ForceSpec, ripple: bool) -> Self {
        Self {
            spec: *spec,
            ripple,
            phase: CutPhase::Free,
            loading_m: 0.0,
            press_direction: Vec3::zeros(),
            unaimed_m: Vec3::zeros(),
            slide_m: Vec3::zeros(),
            stored_j: 0.0,
            rupture_s: 0.0,
            travel_m: 0.0,
            engagement: 0.0,
            stiffness: 1.0,
        }
    }

    /// Scales the tissue's stiffness (an instructor's fault); 1 is the scene's.
    pub fn set_stiffness_factor(&mut self, factor: f64) {
        // The loading curve scales with it, and so does what a press holds.
        if self.stiffness > 0.0 && factor.is_finite() {
            self.stored_j *= factor / self.stiffness;
        }
        self.stiffness = factor;
    }

    /// Current regime.
    pub fn phase(&self) -> CutPhase {
        self.phase
    }

    /// J_c per unit of crack width (N/m).
    pub fn toughness_n_per_m(&self) -> f64 {
        self.spec.toughness_n_per_m
    }

    /// The crack tip's stiffening over E (`ForceSpec::crack_tip_stiffening`).
    pub fn crack_tip_stiffening(&self) -> f64 {
        self.spec.crack_tip_stiffening
    }

    /// The factor on the tissue's stiffness (1: the scene's).
    pub fn stiffness_factor(&self) -> f64 {
        self.stiffness
    }

    /// How far a blunt press indents the tissue before it ruptures (m).
    pub fn rupture_displacement_m(&self) -> f64 {
        self.spec.rupture_displacement_m
    }

    /// The crack advances by energy at its front (`ForceSpec::fracture_by_energy`).
    pub fn fracture_by_energy(&self) -> bool {
        self.spec.fracture_by_energy
    }

    /// The loading curve F_pre at indentation `x` (m) and its slope (N/m).
    pub fn loading_force(&self, x: f64) -> (f64, f64) {
        let scale = EQ19_PEAK_X / (self.spec.rupture_displacement_m * 1e3);
        let (f, df) = eq19(x.max(0.0) * 1e3 * scale);
        let to_newtons = self.stiffness * self.spec.rupture_force_n / EQ19_PEAK_F;
        // d/dx_m = d/dx_mm · 1000 · scale.
        (f * to_newtons, df * to_newtons * 1e3 * scale)
    }

    /// Friction on a blade `depth_m` deep (N): proportional to the rubbing area, up to
    /// `friction_n` at `friction_depth_m`.
    pub fn friction(&self, depth_m: f64) -> f64 {
        self.stiffness
            * self.spec.friction_n
            * (depth_m.max(0.0) / self.spec.friction_depth_m).min(1.0)
    }

    /// The mean cutting force at depth `depth_m` (N): J_c·d, as far as the blade carries
    /// its crack now, + friction.
    pub fn mean_cutting_force(&self, depth_m: f64) -> f64 {
        self.spec.toughness_n_per_m * depth_m.max(0.0) * self.engagement + self.friction(depth_m)
    }

    /// Advances the model to time `now_s` with this update's blade contact.
    pub fn update(&mut self, now_s: f64, contact: &BladeContact) -> CutForce {
        let finite = |v: Vec3| {
            if v.iter().all(|c| c.is_finite()) {
                v
            } else {
                Vec3::zeros()
            }
        };
        let motion = finite(contact.motion_m);
        let steady = finite(contact.steady_motion_m);
        let advance = steady.norm();
        let depth = if contact.depth_m.is_finite() {
            contact.depth_m.max(0.0)
        } else {
            0.0
        };
        let direction = if contact.direction.iter().all(|c| c.is_finite()) {
            contact.direction / contact.direction.norm().max(1.0)
        } else {
            Vec3::zeros()
        };
        let mut ruptured = false;
        if !contact.in_tissue {
            self.phase = CutPhase::Free;
            self.loading_m = 0.0;
            self.slide_m = Vec3::zeros();
            self.stored_j = 0.0;
        } else {
            if self.phase == CutPhase::Free {
                if contact.in_existing_cut {
                    self.start_cutting(now_s);
                } else {
                    self.phase = CutPhase::Loading;
                    self.loading_m = 0.0;
                    self.slide_m = Vec3::zeros();
                    self.stored_j = 0.0;
                    self.unaimed_m = Vec3::zeros();
                    // The way it moved on the tick it touched (it came in then), or else
                    // the way it had been moving (both without the device's noise); a blade
                    // that appeared in the tissue presses the way it first moves (below).
                    self.press_direction = steady
                        .try_normalize(1e-12)
                        .or_else(|| direction.try_normalize(1e-12))
                        .unwrap_or_else(Vec3::zeros);
                }
            }
            match self.phase {
                CutPhase::Loading => {
                    let mut motion = motion;
                    if self.press_direction == Vec3::zeros() {
                        // Until it moves steadily, only remember where it went.
                        self.unaimed_m += motion;
                        motion = Vec3::zeros();
                        if let Some(d) = steady.try_normalize(1e-12) {
                            self.press_direction = d;
                            motion = std::mem::take(&mut self.unaimed_m);
                        }
                    }
                    // Pressing in loads the capsule, backing out unloads it along the same
                    // curve; sliding across it while pressing slices it.
                    let before = self.loading_m;
                    let inward = motion.dot(&self.press_direction);
                    if before > 0.0 {
                        self.slide_m += motion - self.press_direction * inward;
                    }
                    self.loading_m = (before + inward).max(0.0);
                    let (f_before, _) = self.loading_force(before);
                    let (f_after, _) = self.loading_force(self.loading_m);
                    self.stored_j = (self.stored_j
                        + 0.5 * (f_before + f_after) * (self.loading_m - before))
                        .max(0.0);
                    let x_r = self.spec.rupture_displacement_m;
                    if self.loading_m >= x_r || self.slide_m.norm() >= x_r || contact.crushed {
                        self.start_cutting(now_s);
                        ruptured = true;
                    }
                }
                CutPhase::Cutting => {
                    self.travel_m += advance;
                    let target = match contact.crack_share {
                        _ if contact.withdrawing => 0.0,
                        share if share.is_finite() => share.clamp(0.0, 1.0),
                        _ => 1.0,
                    };
                    let blend = advance / (advance + ENGAGEMENT_TRAVEL_M);
                    self.engagement += (target - self.engagement) * blend;
                }
                CutPhase::Free => unreachable!("entering tissue leaves the free phase"),
            }
        }
        let (magnitude, stiffness) = match self.phase {
            CutPhase::Free => (0.0, 0.0),
            // Backed out to where it touched (to rounding), the blade rests on the capsule
            // without pressing (eq. 19's offset f(0) applies from the first touch on).
            CutPhase::Loading if self.loading_m > 1e-12 => self.loading_force(self.loading_m),
            CutPhase::Loading => (0.0, 0.0),
            // By energy, the fracture force is the tissue's (`pipeline::tissue_force`):
            // here, the friction on the blade's faces.
            CutPhase::Cutting if self.spec.fracture_by_energy => (self.friction(depth), 0.0),
            CutPhase::Cutting => {
                let mean = self.mean_cutting_force(depth);
                if self.ripple {
                    let tau = (now_s - self.rupture_s).max(0.0);
                    // The ripple is the crack's stick-slip: it goes with the fracture term.
                    let envelope = self.spec.ripple_amplitude
                        * self.engagement
                        * (-tau / self.spec.ripple_decay_s).exp();
                    let phase =
                        2.0 * std::f64::consts::PI * self.travel_m / self.spec.ripple_wavelength_m;
                    let slope = mean * envelope * 2.0 * std::f64::consts::PI
                        / self.spec.ripple_wavelength_m
                        * phase.cos();
                    (mean * (1.0 + envelope * phase.sin()), slope)
                } else {
                    (mean, 0.0)
                }
            }
        };
        let magnitude = magnitude.max(0.0);
        let (along, stored) = match self.phase {
            CutPhase::Free => (Vec3::zeros(), 0.0),
            CutPhase::Loading => (self.press_direction, self.stored_j),
            CutPhase::Cutting => (direction, 0.0),
        };
        // Scaled by |d| like the force: k |d| d̂ d̂ᵀ.
        let len = along.norm();
        let per_len = if len > 1e-12 { stiffness / len } else { 0.0 };
        CutForce {
            phase: self.phase,
            magnitude_n: magnitude,
            force_n: -along * magnitude,
            direction: along,
            stiffness_matrix_n_per_m: (along * along.transpose()) * per_len,
            stored_energy_j: stored,
            ruptured,
        }
    }

    fn start_cutting(&mut self, now_s: f64) {
        self.phase = CutPhase::Cutting;
        self.loading_m = 0.0;
        self.slide_m = Vec3::zeros();
        self.stored_j = 0.0;
        self.rupture_s = now_s;
        self.travel_m = 0.0;
        self.engagement = 1.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The device's bound keeps the model symmetric, each eigenvalue within it, and the
    /// force at the model's origin; a stiffness that is not finite renders as none.
    #[test]
    fn a_local_model_is_bounded_by_the_device_stiffness() {
        let k = Mat3::new(-3000.0, 200.0, 0.0, 100.0, -40.0, 0.0, 0.0, 0.0, -500.0);
        let model = LocalForceModel {
            f0_n: Vec3::new(0.1, 0.2, 0.3),
            x0_m: Vec3::new(0.01, 0.0, 0.0),
            stiffness_n_per_m: k,
            stored_energy_j: 1e-4,
        };
        let bounded = model.with_stiffness_at_most(1000.0);
        let b = bounded.stiffness_n_per_m;
        assert!((b - b.transpose()).norm() < 1e-9, "{b}");
        let eig = b.symmetric_eigen().eigenvalues;
        assert!(eig.iter().all(|l| l.abs() <= 1000.0 + 1e-9), "{eig}");
        // What was within the bound stays: the soft directions are the model's own.
        assert!((eig.iter().cloned().fold(f64::INFINITY, f64::min) + 1000.0).abs() < 1e-9);
        assert!(eig.iter().any(|l| (l + 500.0).abs() < 1e-9), "{eig}");
        assert_eq!(bounded.force_at(model.x0_m), model.f0_n);
        assert_eq!(bounded.stored_energy_j, model.stored_energy_j);
        let broken = LocalForceModel {
            stiffness_n_per_m: k * f64::NAN,
            ..model
        };
        assert_eq!(
            broken.with_stiffness_at_most(1000.0).stiffness_n_per_m,
            Mat3::zeros()
        );
    }

    /// In the tissue, moving `advance_m` along +x.
    fn contact(advance_m: f64, depth_m: f64) -> BladeContact {
        BladeContact {
            in_tissue: true,
            depth_m,
            motion_m: Vec3::x() * advance_m,
            steady_motion_m: Vec3::x() * advance_m,
            direction: Vec3::x(),
            in_existing_cut: false,
            withdrawing: false,
            crack_share: 1.0,
            crushed: false,
        }
    }

    /// A model that starts in an existing cut, 10 mm deep (no loading, no rupture).
    fn cutting_from_the_start(spec: &ForceSpec, ripple: bool) -> CuttingForceModel {
        let mut m = CuttingForceModel::new(spec, ripple);
        m.update(
            0.0,
            &BladeContact {
                in_existing_cut: true,
                ..contact(0.0, 0.01)
            },
        );
        m
    }

    #[test]
    fn eq19_peaks_where_physics_md_says() {
        assert!((eq19(3.17).0 - 42.85).abs() < 0.01);
        assert!((eq19(0.0).0 - 0.80).abs() < 0.01);
        assert!((eq19(5.0).0 - 10.59).abs() < 0.01);
        // Its derivative is the slope of the curve.
        let h = 1e-6;
        assert!(((eq19(2.5 + h).0 - eq19(2.5 - h).0) / (2.0 * h) - eq19(2.5).1).abs() < 1e-4);
    }

    #[test]
    fn loading_peaks_at_the_rupture_force_then_ruptures() {
        let spec = ForceSpec::default();
        let m = CuttingForceModel::new(&spec, true);
        let (peak, _) = m.loading_force(spec.rupture_displacement_m);
        assert!((peak / spec.rupture_force_n - 1.0).abs() < 1e-3, "{peak}");
        // Monotone rise up to the peak.
        let mut last = 0.0;
        for k in 0..=100 {
            let (f, _) = m.loading_force(spec.rupture_displacement_m * 0.99 * k as f64 / 100.0);
            assert!(f >= last - 1e-12);
            last = f;
        }
        let mut m = CuttingForceModel::new(&spec, true);
        let step = 1e-5;
        let mut t = 0.0;
        let mut ruptures = 0;
        let mut peak_seen: f64 = 0.0;
        while t < 2.0 {
            let f = m.update(t, &contact(step, 0.01));
            peak_seen = peak_seen.max(f.magnitude_n);
            ruptures += usize::from(f.ruptured);
            t += 1e-3;
        }
        assert_eq!(ruptures, 1);
        assert_eq!(m.phase(), CutPhase::Cutting);
        assert!(
            (peak_seen / spec.rupture_force_n - 1.0).abs() < 0.01,
            "{peak_seen}"
        );
    }

    #[test]
    fn a_press_that_backs_out_before_rupture_gives_back_what_it_took() {
        let spec = ForceSpec::default();
        let mut m = CuttingForceModel::new(&spec, true);
        let curve = m.clone();
        // In along +x to 80 % of the rupture displacement at 5 mm/s, hold, and back out
        // the same way (the averaged direction lags: it still says +x while backing out).
        let step = 5e-6;
        let n = (0.8 * spec.rupture_displacement_m / step) as usize;
        let (mut t, mut work, mut pressed) = (0.0, 0.0, Vec::new());
        let mut tick = |m: &mut CuttingForceModel, advance: f64, work: &mut f64| {
            t += 1e-3;
            let f = m.update(t, &contact(advance, 0.0));
            // Work the tissue does on the tool over this step.
            *work += f.force_n.x * advance;
            f
        };
        for _ in 0..n {
            pressed.push(tick(&mut m, step, &mut work));
        }
        let stored = pressed.last().unwrap().stored_energy_j;
        for _ in 0..500 {
            tick(&mut m, 0.0, &mut work);
        }
        for k in (0..n).rev() {
            let f = tick(&mut m, -step, &mut work);
            assert_eq!(f.phase, CutPhase::Loading, "no rupture while backing out");
            // Unloading retraces the loading curve.
            let expected = if k == 0 {
                0.0
            } else {
                curve.loading_force(k as f64 * step).0
            };
            assert!((f.magnitude_n - expected).abs() < 1e-9, "{k}: {f:?}");
            assert!(
                f.force_n.x <= 0.0,
                "it pushes the blade out, never pulls it in"
            );
        }
        // The loading curve's work, and all of it back: passive, not a source.
        let put_in = -pressed.iter().map(|f| f.force_n.x * step).sum::<f64>();
        assert!((stored / put_in - 1.0).abs() < 0.01, "{stored} vs {put_in}");
        // (Up to the rectangle rule's one step of force: ≈ F·step over the whole cycle.)
        assert!(work.abs() < 1e-2 * put_in, "net work {work} of {put_in}");
        assert!(m.update(t + 1e-3, &contact(0.0, 0.0)).stored_energy_j < 1e-12);
    }

    #[test]
    fn a_trembling_hand_holding_a_press_does_not_rupture_the_capsule() {
        let spec = ForceSpec::default();
        let mut m = CuttingForceModel::new(&spec, true);
        let step = 5e-6;
        let mut t = 0.0;
        for _ in 0..300 {
            t += 1e-3;
            m.update(t, &contact(step, 0.0));
        }
        // 5 s of a device's noise around the held pose: up to 30 µm a tick in every axis,
        // tens of millimetres of path in all, never more than 15 µm from the pose per axis.
        // The force follows the indentation: within the noise of the held one.
        let held = m.loading_force(300.0 * step).0;
        let mut at = Vec3::zeros();
        for k in 0..5000 {
            t += 1e-3;
            let x = k as f64;
            let target = Vec3::new((1.7 * x).sin(), (2.3 * x).sin(), (3.1 * x).cos()) * 15e-6;
            let f = m.update(
                t,
                &BladeContact {
                    motion_m: target - at,
                    ..contact(0.0, 0.0)
                },
            );
            at = target;
            assert_eq!(f.phase, CutPhase::Loading, "tick {k}");
            assert!((f.magnitude_n - held).abs() < 0.05 * held, "{k}: {f:?}");
        }
    }

    #[test]
    fn steady_cutting_averages_to_toughness_times_depth_plus_friction() {
        let spec = ForceSpec::default();
        let mut m = cutting_from_the_start(&spec, true);
        // 5 mm/s for 10 s at 1 kHz: 25 ripple wavelengths.
        let (mut sum, mut n, mut lo, mut hi) = (0.0, 0, f64::INFINITY, 0.0f64);
        for k in 1..=10_000 {
            let f = m.update(k as f64 * 1e-3, &contact(5e-6, 0.01));
            sum += f.magnitude_n;
            n += 1;
            lo = lo.min(f.magnitude_n);
            hi = hi.max(f.magnitude_n);
            assert!(f.force_n.x <= 0.0 && f.force_n.y == 0.0);
        }
        let mean = sum / n as f64;
        // 0.19 N/mm × 10 mm + 0.3 N.
        assert!((mean - 2.2).abs() < 0.02, "{mean}");
        assert!(hi - lo > 0.2 && hi <= 2.2 * 1.15 + 1e-9, "{lo} {hi}");
    }

    #[test]
    fn ripple_decays_and_can_be_switched_off() {
        let spec = ForceSpec::default();
        let amplitude = |ripple: bool, from: f64| {
            let mut m = cutting_from_the_start(&spec, ripple);
            let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
            for k in 1..=6000 {
                let t = k as f64 * 1e-3;
                let f = m.update(t, &contact(5e-6, 0.01));
                if t >= from && t < from + 1.0 {
                    lo = lo.min(f.magnitude_n);
                    hi = hi.max(f.magnitude_n);
                }
            }
            hi - lo
        };
        assert!(amplitude(true, 0.0) > 4.0 * amplitude(true, 5.0));
        assert!(amplitude(false, 0.0) < 1e-12);
    }

    #[test]
    fn leaving_the_tissue_releases_the_force() {
        let mut m = CuttingForceModel::new(&ForceSpec::default(), true);
        m.update(0.0, &contact(0.001, 0.01));
        let f = m.update(
            0.001,
            &BladeContact {
                in_tissue: false,
                ..contact(0.001, 0.0)
            },
        );
        assert_eq!(f.phase, CutPhase::Free);
        assert_eq!(f.magnitude_n, 0.0);
    }

    #[test]
    fn garbage_inputs_give_bounded_finite_forces() {
        let spec = ForceSpec::default();
        let mut m = CuttingForceModel::new(&spec, true);
        for (k, (adv, depth)) in [
            (f64::NAN, 0.01),
            (1.0, f64::INFINITY),
            (-5.0, -1.0),
            (1e9, 1e9),
        ]
        .into_iter()
        .enumerate()
        {
            let f = m.update(k as f64, &contact(adv, depth));
            assert!(f.magnitude_n.is_finite() && f.force_n.iter().all(|x| x.is_finite()));
        }
    }

    #[test]
    fn local_model_reproduces_the_force_at_its_origin_and_pushes_back() {
        let mut m = CuttingForceModel::new(&ForceSpec::default(), false);
        let f = m.update(0.0, &contact(0.002, 0.01));
        let model = f.local_model(Vec3::new(0.01, 0.0, 0.0));
        assert_eq!(model.force_at(model.x0_m), f.force_n);
        // Loading stiffens: advancing further along +x gives a larger force against +x.
        let ahead = model.force_at(model.x0_m + Vec3::new(1e-4, 0.0, 0.0));
        assert!(ahead.x < f.force_n.x);
        // Extrapolated no farther than its reach: a device 50 mm ahead feels what it would
        // 4 mm ahead ...
        let far = model.force_at(model.x0_m + Vec3::new(0.05, 0.0, 0.0));
        let reach = model.force_at(model.x0_m + Vec3::new(LOCAL_MODEL_REACH_M, 0.0, 0.0));
        assert!(
            (far - reach).norm() < 1e-12 && far.x < ahead.x,
            "{far:?} {reach:?}"
        );
        // ... and motion across the stiffness does not weaken the part along it.
        let across = model.force_at(model.x0_m + Vec3::new(1e-3, 0.0, 0.02));
        let along = model.force_at(model.x0_m + Vec3::new(1e-3, 0.0, 0.0));
        assert!((across - along).norm() < 1e-12, "{across:?} {along:?}");
    }
}
