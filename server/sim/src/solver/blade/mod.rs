//! The blade as a kinematic body in the running tick (cutting-physics.md §2): material
//! samples of the surface around it follow the points (`embedded`) and are kept out of the
//! blade's slab — its tip end, edge, spine and both flats — by one-sided constraints with
//! Coulomb friction, solved in every explicit sub-step after the points move.
//!
//! Why constraints and not the probe's penalties: a penalty stiff enough to hold the
//! tissue within a few % of the press (100 E/h per area) is about a hundred times stiffer
//! than the points it reaches, and ω_max (∝ √k) and the explicit sub-step go with it (an
//! estimate, not measured); a constraint costs nothing
//! in the step (docs/CUTTING-DECISIONS.md, "The blade in the tick"). Each sub-step's
//! correction is the impulse the blade gives the tissue; the force on the blade is minus
//! its mean over the tick, so the tool and the tissue balance exactly.

use super::embedded::EmbeddedRows;
use crate::math::Vec3;

/// Coulomb friction between the blade's steel and wet tissue: a chosen value, not fitted
/// to a measurement here (a scene key once one is).
pub const BLADE_FRICTION: f64 = 0.2;

/// A sample is pushed only if at least this share of its row (by squared weight) is on
/// points that can move.
const FREE_SHARE: f64 = 0.5;

/// Gauss–Seidel passes over the samples per sub-step (samples share points: a second pass
/// settles what the first one's neighbours pushed back in).
const PASSES: usize = 2;
/// How fast the edge takes up a crack-front sample that starts inside it (m/s): put out in
/// one pass, the speed dp/h that gives its points carries them as far again in the next
/// sub-step, past the guard's limit whatever the sub-steps (docs/CUTTING-DECISIONS.md, "a
/// crack front built inside the edge").
const FRONT_CATCH_UP_M_PER_S: f64 = 0.05;
/// The bevel at the edge's tip end for crack-front samples, in capture bands (a capture
/// band is a sample pitch): half a pitch.
const TIP_BEVEL_CAPTURES: f64 = 0.5;
/// A flat holds its lip fully while its outward normal is at most this far along the
/// blade's heading (cosine) ...
const LIP_HELD_LEAD: f64 = 0.3;
/// ... and not at all from this far on: a flat that leads the motion (the blade pushed
/// across its flats) is cutting there, the swept edge's crack, not pushing a lip ahead.
const LIP_LET_GO_LEAD: f64 = 0.7;
/// How far back from the edge the flats' grind reaches the blade's full thickness (m): a
/// scalpel's edge is ground over about a millimetre, so the lips are wedged apart over
/// that much of its travel, not pushed the blade's half thickness at once.
const EDGE_GRIND_M: f64 = 0.001;
/// The lips' springs together give the points at most ω² = this share of 1/h² (a bound
/// over every point, however many lip samples share it: `lips`): the step's stability
/// bound for an explicit contact spring, as explicit codes' mass-based penalty (LS-DYNA's
/// SOFT=1 takes 0.5·m/Δt²). With the field's own ω·h ≤ 1 that stays at ω·h ≤ 1.23, below
/// symplectic Euler's 2.
const LIP_STABLE_SHARE: f64 = 0.5;

/// A surface sample met deeper in the steel than twice the steel's move in the sub-step and
/// this was built inside it (re-sampled where the blade had got to): caught up like a
/// crack-front sample, not launched.
const DEEP_MEET_M: f64 = 2e-5;

/// A sample met by the blade ([`BladeBody::meet`]): where it is (world, and blade frame),
/// whether it took its face just now, its gap to that face and the face's outward normal
/// (blade frame).
struct Meeting {
    x: Vec3,
    l: Vec3,
    newly: bool,
    gap: f64,
    normal: Vec3,
}

/// The surface samples around the blade, what holds each, and what the blade gave them.
#[derive(Debug, Clone)]
pub struct BladeBody {
    samples: EmbeddedRows,
    /// The face holding each sample, at the tick's start for a retry.
    face: Vec<Option<Face>>,
    face_at_tick: Vec<Option<Face>>,
    /// Where each held sample stuck to its face (blade frame): friction pulls it back.
    anchor: Vec<Vec3>,
    anchor_at_tick: Vec<Vec3>,
    /// Samples that are not the blade's to push: built inside it, or coming in while it
    /// lets go; at the tick's start for a retry.
    cut: Vec<bool>,
    cut_at_tick: Vec<bool>,
    /// Each sample at the sub-step's start: in the blade's frame then, and in the world;
    /// and whether it can reach the blade within the sub-step (the others are skipped).
    start_local: Vec<Vec3>,
    start_world: Vec<Vec3>,
    near: Vec<bool>,
    /// The impulse each sample got this sub-step: normal (kg m), and all of it.
    normal_impulse: Vec<f64>,
    impulse: Vec<Vec3>,
    /// The slab at the tick's start and end, and in the sub-step.
    from: Slab,
    to: Slab,
    at: Slab,
    /// Per point, for building (all false between builds).
    seen: Vec<bool>,
    /// The sum over the tick's sub-steps of the force on the tissue, and how many.
    force_sum: Vec3,
    substeps: u32,
    /// Mean force on the blade over the last tick (N).
    on_blade: Vec3,
    /// 1 while the faces hold, down to 0 while the tissue they held is let go (`release`).
    hold: f64,
    /// Per sample: 0 for a surface sample; for a crack-front or spine sample (`push_front`,
    /// `push_spine`), how far across the flats (m) the edge or the spine catches it.
    capture: Vec<f64>,
    /// Per sample: held by the spine alone (`push_spine`).
    spine: Vec<bool>,
    /// Per sample, how deep in the steel its face lets it be (m): a crack-front sample, or
    /// a surface sample met deeper than the steel moved ([`DEEP_MEET_M`]), was built where
    /// the blade had already got to and is pushed out at [`FRONT_CATCH_UP_M_PER_S`], not in
    /// one pass. At the tick's start for a retry.
    slack: Vec<f64>,
    slack_at_tick: Vec<f64>,
    /// How far the steel moves in the sub-step (m): deeper than this a sample met is one
    /// built where the blade had already got to, not one it ran into.
    substep_move: f64,
    /// While the blade is lifted out along its edge, how fast it lets go of the crack front
    /// (m/s; zero otherwise): see [`Self::let_go_front`].
    letting_go_front: f64,
    /// Per sample: 0, or for a lip sample (`push_lip`) the side of Σ it is on, +1 on the
    /// +side flat's, −1 on the other's.
    side: Vec<f64>,
    /// How far inside its lip a lip sample sits (m): its flat holds it that much out.
    lip_depth: f64,
    /// Each lip sample's contact stiffness (N/m), and the side of the patch of lip it
    /// stands for (m): see [`Self::lip_forces`].
    lip_stiffness: f64,
    lip_pitch: f64,
    /// The same for the spine samples (`push_spine`).
    spine_stiffness: f64,
    spine_pitch: f64,
    /// How deep the spine pressed its deepest sample in the last sub-step (m, its push over
    /// its full stiffness), and the sum over the tick's sub-steps of the spine's own force
    /// on the tissue.
    spine_indentation: f64,
    spine_force: Vec3,
    spine_force_sum: Vec3,
    /// The spine's own mean force on the blade over the last tick (N).
    on_spine: Vec3,
    /// The lips' force on the tissue this sub-step (N), and the points it was put on.
    lip_force: Vec3,
    written: Vec<u32>,
    /// Scratch for [`Self::lip_forces`]: the lip samples pressed this sub-step, and per
    /// point the sum its stability bound is taken over (zero between calls).
    pressed: Vec<lips::Pressed>,
    reach: Vec<f64>,
    /// The blade's heading (unit, or zero when it is not moving): see [`LIP_LET_GO_LEAD`].
    heading: Vec3,
    /// Scratch for [`Self::retain`].
    keep: Vec<bool>,
}

impl BladeBody {
    /// No samples yet, with room for `samples` of them over `points` points (`entries`
    /// row terms in all); the blade at `slab`.
    pub fn with_room(points: usize, samples: usize, entries: usize, slab: Slab) -> Self {
        Self {
            samples: EmbeddedRows::with_room(points, samples, entries),
            face: Vec::with_capacity(samples),
            face_at_tick: Vec::with_capacity(samples),
            anchor: Vec::with_capacity(samples),
            anchor_at_tick: Vec::with_capacity(samples),
            cut: Vec::with_capacity(samples),
            cut_at_tick: Vec::with_capacity(samples),
            start_local: Vec::with_capacity(samples),
            start_world: Vec::with_capacity(samples),
            near: Vec::with_capacity(samples),
            normal_impulse: Vec::with_capacity(samples),
            impulse: Vec::with_capacity(samples),
            from: slab,
            to: slab,
            at: slab,
            seen: vec![false; points],
            force_sum: Vec3::zeros(),
            substeps: 0,
            on_blade: Vec3::zeros(),
            hold: 1.0,
            capture: Vec::with_capacity(samples),
            spine: Vec::with_capacity(samples),
            slack: Vec::with_capacity(samples),
            slack_at_tick: Vec::with_capacity(samples),
            substep_move: 0.0,
            letting_go_front: 0.0,
            side: Vec::with_capacity(samples),
            lip_depth: 0.0,
            lip_stiffness: 0.0,
            lip_pitch: 0.0,
            spine_stiffness: 0.0,
            spine_pitch: 0.0,
            spine_indentation: 0.0,
            spine_force: Vec3::zeros(),
            spine_force_sum: Vec3::zeros(),
            on_spine: Vec3::zeros(),
            lip_force: Vec3::zeros(),
            heading: Vec3::zeros(),
            written: Vec::with_capacity(points),
            pressed: Vec::with_capacity(samples),
            reach: vec![0.0; points],
            keep: Vec::with_capacity(samples),
        }
    }

    /// Lets the tissue go over ticks: no face takes hold of anything new, and `step` of
    /// the way is done each tick (the caller backs the blade's faces out as it goes); at
    /// the end the samples are taken away. Returns how much of the way is left (0: none,
    /// the samples gone). (Let go at once, the dent a soft organ stored springs back
    /// within a sub-step: on the tumour scan it moved points over the guard's 0.3 spacings
    /// in one, a rollback.)
    pub fn release(&mut self, step: f64) -> f64 {
        self.hold -= step;
        if self.hold <= 0.0 {
            self.clear();
            return 0.0;
        }
        self.hold
    }

    /// The blade is lifted out along its edge and lets go of the crack front at `pace`
    /// (m/s; zero: it is not). The tissue it had pushed ahead springs back into the track
    /// the blade leaves, from the tip up, as it rises; the samples, a pitch apart, stand for
    /// that edge a pitch at a time, so each is let go at this pace instead of at once as
    /// the tip passes it.
    pub fn let_go_front(&mut self, pace: f64) {
        self.letting_go_front = pace.max(0.0);
    }

    /// Whether sample `s` is a crack-front sample the lifted blade is letting go.
    fn letting_go(&self, s: usize) -> bool {
        self.letting_go_front > 0.0 && self.capture[s] > 0.0 && !self.spine[s]
    }

    /// The change of sample `s`'s slack over a step of `h` (m): let out while the lifted
    /// blade lets it go, else taken up.
    fn slack_step(&self, s: usize, h: f64) -> f64 {
        match self.letting_go(s) {
            true => self.letting_go_front * h,
            false => -FRONT_CATCH_UP_M_PER_S * h,
        }
    }

    /// The way the blade is heading (unit, or zero), for the lips: see
    /// [`LIP_LET_GO_LEAD`].
    pub fn set_heading(&mut self, heading: Vec3) {
        self.heading = heading;
    }

    /// Whether sample `s` is a lip sample.
    pub fn is_lip(&self, s: usize) -> bool {
        self.side[s] != 0.0
    }

    /// Whether sample `s` is a spine sample.
    pub fn is_spine(&self, s: usize) -> bool {
        self.spine[s]
    }

    /// How many lip samples there are.
    pub fn lips(&self) -> usize {
        self.side.iter().filter(|&&d| d != 0.0).count()
    }

    /// Whether the faces are letting go of what a press held (`release`).
    pub fn releasing_press(&self) -> bool {
        self.hold < 1.0
    }

    /// Sample `s` in the frame of the blade at `slab`, with the points at `p`.
    pub fn local_in(&self, slab: &Slab, s: usize, p: &[Vec3]) -> Vec3 {
        slab.local(&self.samples.position(s, p))
    }

    /// Whether sample `s`, at local `l`, is inside what holds it: the steel, or for a
    /// crack-front (spine) sample the edge's (spine's) capture band.
    fn contains(&self, at: &Slab, s: usize, l: &Vec3) -> bool {
        if self.side[s] != 0.0 {
            // (Half a patch beyond the tip and the spine: see `lip_forces`.)
            let half = 0.5 * self.lip_pitch;
            return l.x > -half
                && l.x < at.length
                && l.y > 0.0
                && l.y < at.width + half
                && self.lip_gap(at, s, l).0 < 0.0;
        }
        match self.capture[s] {
            // (Half a patch beyond the tip, as a lip's: see `lip_forces`.)
            capture if capture > 0.0 && self.spine[s] => {
                l.x > -0.5 * self.spine_pitch
                    && l.x < at.length
                    && l.y > 0.0
                    && l.y < at.width
                    && l.z.abs() < capture
            }
            capture if capture > 0.0 => at.inside_across(l, capture) && l.y > self.bevel(s, l),
            _ => at.inside(l),
        }
    }

    /// How far back from the edge line the steel starts at local `l` for crack-front
    /// sample `s`: the edge's last stretch before the tip is bevelled at 45° over
    /// [`TIP_BEVEL_CAPTURES`] of the capture band, so that a sample the tip passes (a
    /// withdrawing blade) is let go over that much of the blade's travel, while the next
    /// sample up the edge takes the tissue over, not in one tick.
    fn bevel(&self, s: usize, l: &Vec3) -> f64 {
        (TIP_BEVEL_CAPTURES * self.capture[s] - l.x).max(0.0)
    }

    /// Sample `s` with the points at `p`, against the blade where it is in the step: the
    /// face holding it (taken now if it had none), or `None` if it is outside what holds it
    /// (its face let go when `let_go`) or no face takes it. The caller's slack and push
    /// start from this.
    fn meet(&mut self, s: usize, p: &[Vec3], let_go: bool) -> Option<Meeting> {
        let at = self.at;
        let x = self.samples.position(s, p);
        let l = at.local(&x);
        if !self.contains(&at, s, &l) {
            if let_go {
                self.face[s] = None;
            }
            return None;
        }
        let newly = self.face[s].is_none();
        let face = self.take_face(s, &l)?;
        let (gap, normal) = self.gap_to(&at, s, &l, face);
        Some(Meeting {
            x,
            l,
            newly,
            gap,
            normal,
        })
    }

    /// Sample `s`'s gap at local `l` to `face` of the slab `at` and the face's normal, as
    /// [`Slab::gap`] with the edge's bevel for crack-front samples.
    fn gap_to(&self, at: &Slab, s: usize, l: &Vec3, face: Face) -> (f64, Vec3) {
        if self.side[s] != 0.0 {
            return self.lip_gap(at, s, l);
        }
        let (gap, normal) = at.gap(l, face);
        match face {
            Face::Edge => (gap + self.bevel(s, l), normal),
            _ => (gap, normal),
        }
    }

    /// Lip sample `s`'s gap at local `l` to its flat (m, negative inside) and the flat's
    /// outward normal in the blade's frame: from the edge the flat is ground at the angle
    /// that reaches the half thickness [`EDGE_GRIND_M`] back, then flat; the sample sits
    /// [`Self::lip_depth`] inside its lip.
    fn lip_gap(&self, at: &Slab, s: usize, l: &Vec3) -> (f64, Vec3) {
        let side = self.side[s];
        let half = 0.5 * at.thickness;
        let slope = half / EDGE_GRIND_M;
        if l.y * slope < half {
            let norm = (1.0 + slope * slope).sqrt();
            let gap = (side * l.z - l.y * slope) / norm - self.lip_depth;
            (gap, Vec3::new(0.0, -slope, side) / norm)
        } else {
            (
                side * l.z - half - self.lip_depth,
                Vec3::new(0.0, 0.0, side),
            )
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.face.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.face.is_empty()
    }

    /// The points the samples follow.
    pub fn reached(&self) -> &[u32] {
        self.samples.reached()
    }

    /// The blade moves to `slab` over the next tick.
    pub fn move_to(&mut self, slab: Slab) {
        self.from = self.to;
        self.to = slab;
        self.at = self.from;
    }

    /// Puts the blade at `slab` without moving it there (it appeared, or the samples were
    /// rebuilt around it).
    pub fn place(&mut self, slab: Slab) {
        self.from = slab;
        self.to = slab;
        self.at = slab;
    }

    /// The blade at the end of the tick.
    pub fn slab(&self) -> &Slab {
        &self.to
    }

    /// The points the samples a face holds now follow (a point may come more than once).
    pub fn held_points(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.len())
            .filter(|&s| self.face[s].is_some())
            .flat_map(move |s| self.samples.points_of(s).iter().copied())
    }

    /// The points the crack-front samples follow (a point may come more than once).
    pub fn front_points(&self) -> impl Iterator<Item = u32> + '_ {
        (0..self.len())
            .filter(|&s| self.capture[s] > 0.0 && !self.spine[s])
            .flat_map(move |s| self.samples.points_of(s).iter().copied())
    }

    /// The points the spine samples follow, only those its spine holds if `held` (a point
    /// may come more than once).
    pub fn spine_points(&self, held: bool) -> impl Iterator<Item = u32> + '_ {
        (0..self.len())
            .filter(move |&s| self.spine[s] && (!held || self.face[s].is_some()))
            .flat_map(move |s| self.samples.points_of(s).iter().copied())
    }

    /// How deep the spine pressed the tissue it holds in the last sub-step (m): the
    /// indentation of its compliant contact, below what the lattice draws.
    pub fn spine_indentation(&self) -> f64 {
        self.spine_indentation
    }

    /// The mean force the tissue put on the spine over the last tick (N): its share of
    /// [`Self::force_on_blade`].
    pub fn force_on_spine(&self) -> Vec3 {
        self.on_spine
    }

    /// Samples the blade holds now.
    pub fn touching(&self) -> usize {
        self.face.iter().filter(|f| f.is_some()).count()
    }

    /// The mean force the tissue put on the blade over the last tick (N).
    pub fn force_on_blade(&self) -> Vec3 {
        self.on_blade
    }

    /// Keeps the contact state for a retry of the tick.
    pub(super) fn begin_tick(&mut self) {
        self.face_at_tick.copy_from_slice(&self.face);
        self.anchor_at_tick.copy_from_slice(&self.anchor);
        self.cut_at_tick.copy_from_slice(&self.cut);
        self.slack_at_tick.copy_from_slice(&self.slack);
    }

    /// A (re)try of the tick starts from its start's contacts.
    pub(super) fn begin_attempt(&mut self) {
        self.face.copy_from_slice(&self.face_at_tick);
        self.anchor.copy_from_slice(&self.anchor_at_tick);
        self.cut.copy_from_slice(&self.cut_at_tick);
        self.slack.copy_from_slice(&self.slack_at_tick);
        self.force_sum = Vec3::zeros();
        self.spine_force_sum = Vec3::zeros();
        self.substeps = 0;
    }

    /// Where the samples are at the start of a sub-step that ends a fraction `frac` of the
    /// way through the tick, against the blade where it was then; a sample farther outside
    /// it than the blade moves in the sub-step plus `tissue_reach` (the most a point may
    /// move in one) cannot touch it and is skipped.
    pub(super) fn begin_substep(
        &mut self,
        frac_before: f64,
        frac: f64,
        p: &[Vec3],
        tissue_reach: f64,
    ) {
        let before = Slab::between(&self.from, &self.to, frac_before);
        self.at = Slab::between(&self.from, &self.to, frac);
        self.substep_move = (self.at.tip - before.tip).norm()
            + 0.5 * self.at.length * (self.at.edge - before.edge).norm()
            + 0.5 * self.at.width * (self.at.back - before.back).norm();
        let reach = self.substep_move + tissue_reach;
        for s in 0..self.len() {
            let x = self.samples.position(s, p);
            let l = before.local(&x);
            self.start_world[s] = x;
            self.start_local[s] = l;
            self.normal_impulse[s] = 0.0;
            self.impulse[s] = Vec3::zeros();
            let outside = Face::ALL
                .iter()
                .map(|&f| before.gap(&l, f).0)
                .fold(f64::NEG_INFINITY, f64::max)
                .max(l.x - before.length);
            self.near[s] = !self.cut[s]
                && (self.face[s].is_some() || self.capture[s] > 0.0 || outside <= reach);
        }
    }

    /// Pushes the samples out of the blade after the points moved in a sub-step of `h`:
    /// positions `p` and velocities `v` change by the correction of each point whose
    /// inverse mass `inv_mass` gives is not zero (`mass` for the kinetic energy, which
    /// changes by the returned amount). Returns (the change in kinetic energy, the work
    /// the blade did on the tissue).
    pub(super) fn project(
        &mut self,
        p: &mut [Vec3],
        v: &mut [Vec3],
        mass: &[f64],
        h: f64,
        inv_mass: impl Fn(usize) -> f64,
    ) -> (f64, f64) {
        let mut kinetic = 0.0;
        let at = self.at;
        for pass in 0..PASSES {
            for s in 0..self.len() {
                if !self.near[s] || self.side[s] != 0.0 || self.spine[s] {
                    continue;
                }
                let Some(Meeting {
                    l,
                    newly,
                    mut gap,
                    normal: normal_local,
                    ..
                }) = self.meet(s, p, pass == 0)
                else {
                    continue;
                };
                if newly && (self.capture[s] > 0.0 || -gap > 2.0 * self.substep_move + DEEP_MEET_M)
                {
                    // A crack-front sample first met already inside (built where the edge
                    // had passed, or come in from beyond the tip, which then holds it): as
                    // deep as it is, it may stay, and is caught up.
                    self.slack[s] = (-gap).max(0.0);
                }
                if self.slack[s] > 0.0 || self.letting_go(s) {
                    // Taken up (or let out) once a sub-step at a hand's pace, and never
                    // looser than it now is.
                    if pass == 0 {
                        let step = self.slack_step(s, h);
                        let left = (self.slack[s] + step).max(0.0);
                        self.slack[s] = left.min((-gap).max(0.0) + step.max(0.0));
                    }
                    gap += self.slack[s];
                }
                if gap >= 0.0 || !self.mostly_free(s, |k| inv_mass(k) > 0.0) {
                    continue;
                }
                let weight: f64 = self.samples.row(s).map(|(k, w)| w * w * inv_mass(k)).sum();
                let normal = at.world(&normal_local);
                let dl = -gap / weight;
                self.normal_impulse[s] += dl;
                // Friction: back toward where it stuck, at most μ × the normal impulse;
                // past that it slides, and sticks again where it got to.
                let on_face = l - normal_local * gap;
                let most = BLADE_FRICTION * self.normal_impulse[s];
                let tangent = self.friction(s, on_face, normal_local, most, |slip| {
                    at.world(&slip) / weight
                });
                let push = normal * dl + tangent;
                self.impulse[s] += push;
                for (k, w) in self.samples.row(s) {
                    let im = inv_mass(k);
                    if im > 0.0 {
                        let dp = push * (w * im);
                        let before = v[k].norm_squared();
                        p[k] += dp;
                        v[k] += dp / h;
                        kinetic += 0.5 * mass[k] * (v[k].norm_squared() - before);
                    }
                }
            }
        }
        // The work of the sub-step's force on the tissue over the samples' moves, and the
        // force itself for the tick's mean.
        let mut work = 0.0;
        // The lips' push is a force in the step (its work is the applied loads').
        let mut force = std::mem::take(&mut self.lip_force);
        self.spine_force_sum += std::mem::take(&mut self.spine_force);
        for s in 0..self.len() {
            if self.impulse[s] != Vec3::zeros() {
                let f = self.impulse[s] / (h * h);
                force += f;
                work += f.dot(&(self.samples.position(s, p) - self.start_world[s]));
            }
        }
        self.force_sum += force;
        self.substeps += 1;
        (kinetic, work)
    }

    /// Sample `s`'s friction on its face, where it is at `on_face` (blade frame; `normal`
    /// the face's): `pull` of the slip back to where it stuck, at most `most` — past that
    /// it slides, and sticks again where the pull leaves it.
    fn friction(
        &mut self,
        s: usize,
        on_face: Vec3,
        normal: Vec3,
        most: f64,
        pull: impl Fn(Vec3) -> Vec3,
    ) -> Vec3 {
        let mut slip = self.anchor[s] - on_face;
        slip -= normal * slip.dot(&normal);
        let full = pull(slip);
        let size = full.norm();
        if size > most {
            let kept = most / size.max(1e-300);
            self.anchor[s] = on_face + slip * kept;
            full * kept
        } else {
            full
        }
    }

    /// The face holding sample `s`, now at local `l` inside the steel: the one that held
    /// it, else the one it came in through (it sticks there). While letting go no face
    /// takes hold of anything new: the sample is the crack's from then on.
    fn take_face(&mut self, s: usize, l: &Vec3) -> Option<Face> {
        if let Some(f) = self.face[s] {
            return Some(f);
        }
        if self.side[s] != 0.0 {
            // A lip is its own flat's, whatever the faces are doing with a press.
            let f = match self.side[s] > 0.0 {
                true => Face::FlatPlus,
                false => Face::FlatMinus,
            };
            self.face[s] = Some(f);
            self.anchor[s] = *l;
            return Some(f);
        }
        if self.spine[s] {
            // A spine sample is the spine's (its patch let go as the tip passes it).
            self.face[s] = Some(Face::Spine);
            self.anchor[s] = *l;
            return Some(Face::Spine);
        }
        if self.hold < 1.0 {
            self.cut[s] = true;
            return None;
        }
        // A crack-front sample is the edge's, unless it comes in from beyond the tip's end
        // (tissue below a withdrawing blade springs back into its track): the tip's end
        // puts that out, where the edge would take it up across the whole blade.
        let f = match self.capture[s] > 0.0 {
            true if self.start_local[s].x > 0.0 => Face::Edge,
            true => Face::Tip,
            false => self.at.entry_face(l, &self.start_local[s]),
        };
        self.face[s] = Some(f);
        self.anchor[s] = *l;
        Some(f)
    }

    /// Whether at least [`FREE_SHARE`] of sample `s`'s row (by squared weight) is on
    /// points `free` says can move. One that mostly follows points that cannot (asleep,
    /// fixed, virtual) is not pushed: its few free points would take the whole correction,
    /// many times its gap.
    fn mostly_free(&self, s: usize, free: impl Fn(usize) -> bool) -> bool {
        let (mut on_free, mut all) = (0.0, 0.0);
        for (k, w) in self.samples.row(s) {
            all += w * w;
            if free(k) {
                on_free += w * w;
            }
        }
        all > 0.0 && on_free >= FREE_SHARE * all
    }

    /// Sample `s`'s row: (point, weight).
    pub(super) fn row(&self, s: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.samples.row(s)
    }

    /// Sample `s`'s place with the points at `p`.
    pub(super) fn position(&self, s: usize, p: &[Vec3]) -> Vec3 {
        self.samples.position(s, p)
    }

    /// The tick is done: its mean force on the blade.
    pub(super) fn end_tick(&mut self) {
        let mean = |sum: Vec3| match self.substeps {
            0 => Vec3::zeros(),
            n => -sum / f64::from(n),
        };
        self.on_blade = mean(self.force_sum);
        self.on_spine = mean(self.spine_force_sum);
    }

    /// The work the blade did on the tissue over the last tick (J): its mean force on the
    /// tissue over its move (the steel is rigid and what it holds moves with it; its turn
    /// within one tick is left out), the same in every mode — the energy it stored in what
    /// it holds, or, negative, what the tissue gave back. Read before the next `move_to`.
    pub fn work_on_tissue(&self) -> f64 {
        -self.on_blade.dot(&(self.to.tip - self.from.tip))
    }
}

mod lips;
mod projective;
mod samples;
mod slab;
pub(in crate::solver) use lips::Field;
pub use slab::{Face, Slab};
#[cfg(test)]
mod tests;
