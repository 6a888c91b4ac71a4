//! The blade's samples as a set: laid (surface, lip, crack-front and spine samples),
//! kept or dropped in order, carried into a rebuild with the faces that hold them.

use super::{BladeBody, Face};
use crate::math::Vec3;

impl BladeBody {
    /// Takes every sample away (the blade left the tissue).
    pub fn clear(&mut self) {
        self.hold = 1.0;
        self.samples.clear();
        for v in [
            &mut self.start_local,
            &mut self.start_world,
            &mut self.impulse,
        ] {
            v.clear();
        }
        self.near.clear();
        self.face.clear();
        self.face_at_tick.clear();
        self.anchor.clear();
        self.anchor_at_tick.clear();
        self.cut.clear();
        self.cut_at_tick.clear();
        self.normal_impulse.clear();
        self.capture.clear();
        self.spine.clear();
        self.slack.clear();
        self.slack_at_tick.clear();
        self.side.clear();
        self.on_blade = Vec3::zeros();
    }

    /// Keeps only the samples `keep(s)` says, in order (no allocation): lips left behind
    /// the spine dropped, or the crack front rebuilt with the lips kept.
    pub fn retain(&mut self, keep: impl Fn(&Self, usize) -> bool) {
        let mut flags = std::mem::take(&mut self.keep);
        flags.clear();
        flags.extend((0..self.len()).map(|s| keep(self, s)));
        if flags.iter().all(|&k| k) {
            self.keep = flags;
            return;
        }
        self.samples.retain(&flags, &mut self.seen);
        fn squeeze<T: Copy>(v: &mut Vec<T>, flags: &[bool]) {
            let mut kept = 0;
            for s in 0..v.len() {
                if flags[s] {
                    v[kept] = v[s];
                    kept += 1;
                }
            }
            v.truncate(kept);
        }
        squeeze(&mut self.face, &flags);
        squeeze(&mut self.face_at_tick, &flags);
        squeeze(&mut self.anchor, &flags);
        squeeze(&mut self.anchor_at_tick, &flags);
        squeeze(&mut self.cut, &flags);
        squeeze(&mut self.cut_at_tick, &flags);
        squeeze(&mut self.start_local, &flags);
        squeeze(&mut self.start_world, &flags);
        squeeze(&mut self.near, &flags);
        squeeze(&mut self.normal_impulse, &flags);
        squeeze(&mut self.impulse, &flags);
        squeeze(&mut self.capture, &flags);
        squeeze(&mut self.spine, &flags);
        squeeze(&mut self.slack, &flags);
        squeeze(&mut self.slack_at_tick, &flags);
        squeeze(&mut self.side, &flags);
        self.keep = flags;
    }

    /// Whether a sample following `entries` points still fits.
    pub fn fits(&self, entries: usize) -> bool {
        self.samples.fits(entries) && self.face.len() < self.face.capacity()
    }

    /// Adds a sample at rest position `rest` following `row` over points at `rest_points`
    /// (`finish` after the last).
    pub fn push(&mut self, row: &[(u32, f64)], rest: Vec3, rest_points: &[Vec3]) {
        self.samples.push(row, rest, rest_points, &mut self.seen);
        self.face.push(None);
        self.face_at_tick.push(None);
        self.anchor.push(Vec3::zeros());
        self.anchor_at_tick.push(Vec3::zeros());
        self.cut.push(false);
        self.cut_at_tick.push(false);
        self.start_local.push(Vec3::zeros());
        self.start_world.push(Vec3::zeros());
        self.near.push(false);
        self.normal_impulse.push(0.0);
        self.impulse.push(Vec3::zeros());
        self.capture.push(0.0);
        self.spine.push(false);
        self.slack.push(0.0);
        self.slack_at_tick.push(0.0);
        self.side.push(0.0);
    }

    /// Adds a lip sample: material of one side of Σ (`side` +1 or −1, the flat that holds
    /// it), `depth` (m) inside its lip at rest `rest`, following `row` (its side's points
    /// only), pressed with `stiffness` (N/m, [`Self::lip_forces`]) over a patch `pitch`
    /// (m) on a side. Only its own flat holds it, from the edge's grind to the spine
    /// (`finish` after the last).
    #[allow(clippy::too_many_arguments)]
    pub fn push_lip(
        &mut self,
        row: &[(u32, f64)],
        rest: Vec3,
        rest_points: &[Vec3],
        side: f64,
        depth: f64,
        stiffness: f64,
        pitch: f64,
    ) {
        self.push(row, rest, rest_points);
        self.lip_pitch = pitch;
        if let Some(d) = self.side.last_mut() {
            *d = side.signum();
        }
        self.lip_depth = depth;
        self.lip_stiffness = stiffness;
    }

    /// Adds a crack-front sample: material just ahead of the crack front (rest `rest`,
    /// `row` its embedding), which only the edge holds, wherever it is across the flats
    /// within `capture` (m): the wedge of a real blade pushes what lies ahead of its edge,
    /// and a sample a hair off the 0.4 mm steel must not slip past it.
    pub fn push_front(
        &mut self,
        row: &[(u32, f64)],
        rest: Vec3,
        rest_points: &[Vec3],
        capture: f64,
    ) {
        self.push(row, rest, rest_points);
        if let Some(c) = self.capture.last_mut() {
            *c = capture;
        }
    }

    /// Adds a spine sample: uncut material just beyond the spine (rest `rest`, `row` its
    /// embedding), which only the spine holds, within `capture` (m) across the flats, with
    /// a compliant contact of `stiffness` (N/m) over a patch `pitch` (m) on a side as the
    /// lips' ([`Self::lip_forces`]): a blade moved back meets the tissue past its wound's
    /// start with its blunt back, which pushes it and cannot cut it.
    pub fn push_spine(
        &mut self,
        row: &[(u32, f64)],
        rest: Vec3,
        rest_points: &[Vec3],
        capture: f64,
        stiffness: f64,
        pitch: f64,
    ) {
        self.push_front(row, rest, rest_points, capture);
        if let Some(b) = self.spine.last_mut() {
            *b = true;
        }
        self.spine_stiffness = stiffness;
        self.spine_pitch = pitch;
    }

    /// Copies into `into` (cleared first, placed at this blade's slab) every sample a face
    /// holds now, with its face and where it stuck, so that a rebuild around a moving blade
    /// does not drop the tissue it is pushing; `row` is scratch. Returns how many.
    pub fn carry_held_into(
        &self,
        into: &mut BladeBody,
        rest_points: &[Vec3],
        row: &mut Vec<(u32, f64)>,
    ) -> usize {
        into.clear();
        into.place(self.to);
        for s in 0..self.len() {
            let Some(face) = self.face[s] else { continue };
            row.clear();
            row.extend(self.samples.row(s).map(|(k, w)| (k as u32, w)));
            if !into.fits(row.len()) {
                break;
            }
            let rest = self.samples.position(s, rest_points);
            into.push(row, rest, rest_points);
            let t = into.len() - 1;
            into.face[t] = Some(face);
            into.anchor[t] = self.anchor[s];
            into.capture[t] = self.capture[s];
            into.spine[t] = self.spine[s];
            into.side[t] = self.side[s];
        }
        into.len()
    }

    /// Sample s's rest position.
    pub fn rest_position(&self, s: usize, rest_points: &[Vec3]) -> Vec3 {
        self.samples.position(s, rest_points)
    }

    /// Ends a batch of a build (the samples from `from` on) with the points at `p`: a
    /// sample already deeper than `tolerance` inside the blade is not the blade's to push out (the blade is in a cut there, or
    /// appeared in the tissue): the crack's, as if cut.
    pub fn finish(&mut self, p: &[Vec3], tolerance: f64, from: usize) {
        self.samples.finish(&mut self.seen);
        let at = self.to;
        for s in from..self.len() {
            if self.face[s].is_some() || self.capture[s] > 0.0 || self.side[s] != 0.0 {
                continue;
            }
            let l = at.local(&self.samples.position(s, p));
            self.cut[s] = at.inside(&l) && Face::ALL.iter().all(|&f| at.gap(&l, f).0 < -tolerance);
        }
    }
}
