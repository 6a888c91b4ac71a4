//! Fracture at the crack front by energy (cutting-physics.md §3, Mahvash & Hayward 2001).
//!
//! While cutting, the blade's edge pushes *crack-front samples*: material just ahead of
//! the end of Σ, embedded in the field like the surface's vertices and held by the edge
//! alone (`solver::blade`, `push_front`). What they push back with is the tissue's: it rises
//! with its stiffness as the blade indents the uncut tissue ahead. The crack advances only
//! when the energy the blade has put into the tissue ahead pays for the new crack: the work
//! the edge did since the last advance (what the tissue ahead stores, less what it gave
//! back) against J_c·w·Δa for a jump of Δa over the width w of fresh tissue the edge
//! engages. Each jump spends its J_c·w·Δa and the rest stays to the next, so over many
//! jumps the blade's work is the crack's energy: the mean force is J_c·w whatever the
//! stiffness (the energy balance of steady cutting), and the stiffness only sets how long
//! the tissue loads between jumps and how much it gives back at one — the sawtooth.
//!
//! Δa is the process zone's length, below the lattice: J_c/(c·E) with c =
//! `crack_tip_stiffening` (2 mm on the liver at the default 19); the strain-stiffening of
//! the tissue itself (`[material] stiffening`) is what lets the front load to J_c·w within
//! millimetres of push on soft tissue.

use super::sigma::near_region;
use super::*;
use crate::solver::blade::BladeBody;

/// The crack-front samples sit this many sample pitches ahead of Σ's end (rest): on the
/// uncut side, so their rows see the tissue ahead.
pub(super) const AHEAD_PITCHES: f64 = 0.5;
/// Most samples along a line of the blade (its edge's crack front, its spine).
pub(super) const MOST_LINE_SAMPLES: usize = 16;
/// The edge catches a front sample within this many pitches across its flats.
pub(super) const CAPTURE_PITCHES: f64 = 1.0;
/// A blade whose edge has got this many support radii past the crack front (rest) without
/// breaking it — nothing ahead held it: a sliver, a front the field did not reach — takes the
/// crack to its edge.
const MOST_LAG_SUPPORTS: f64 = 2.5;
/// Over how long a blade lifted out along its edge lets go of the crack front's
/// indentation scale (s): see `let_go_pace`.
const LET_GO_S: f64 = 0.76;

/// The crack front's state: how its samples stand, and what the last tick read.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct CrackFront {
    /// The blade holds crack-front samples ...
    pub(super) built: bool,
    /// ... built for a front that has moved since.
    pub(super) stale: bool,
    /// The work the edge has put into the tissue ahead and no fracture has spent yet (J).
    pub(super) work_j: f64,
}

/// How far the edge (rest: tip, top) has got past the crack front `front` along `ahead`.
fn lag_past(front: &[Vec3; 2], edge: &[Vec3; 2], ahead: Vec3) -> f64 {
    (edge[1] - front[1]).dot(&ahead)
}

impl CuttingStage {
    /// The jump Δa (m) if the crack advances this tick: the work the edge's samples did
    /// on the tissue over the last step (`work_on_tissue`) goes to the front's account, and
    /// a jump is due when the account pays for Δa of crack over `width_m` of fresh tissue.
    pub(super) fn fracture_due(
        &mut self,
        phase: CutPhase,
        blade: Option<&Blade>,
        width_m: f64,
        solver: &mut Solver,
    ) -> Option<f64> {
        let (CutPhase::Cutting, Some(_), Some(body), true) =
            (phase, blade, solver.blade(), self.front.built)
        else {
            return None;
        };
        // What the tissue gives back (the blade backing off) comes off the account; it
        // never owes.
        self.front.work_j = (self.front.work_j + body.work_on_tissue()).max(0.0);
        if body.is_empty() || width_m <= 0.0 {
            return None;
        }
        let jump = self.process_zone(solver);
        let cost = self.force.toughness_n_per_m() * width_m * jump;
        if self.front.work_j < cost {
            return None;
        }
        self.front.work_j -= cost;
        solver.sink_crack_energy(cost);
        Some(jump)
    }

    /// The process zone's length (m): J_c / (c·E), within a quarter of a sample pitch and a
    /// spacing.
    pub(super) fn process_zone(&self, solver: &Solver) -> f64 {
        let e = solver.params().youngs_modulus_pa * self.force.stiffness_factor();
        let zone = self.force.toughness_n_per_m() / (self.force.crack_tip_stiffening() * e);
        if zone.is_finite() {
            zone.clamp(0.25 * self.pitch(), self.spacing_m)
        } else {
            self.spacing_m
        }
    }

    /// How fast a blade lifted out along its edge lets go of the crack front (m/s): the
    /// tissue's own indentation scale J_c / E (how far a tissue of stiffness E is pushed
    /// ahead to store J_c; 38 mm on the 5 kPa liver, 0.19 mm at 1 MPa) over
    /// [`LET_GO_S`] — 50 mm/s on the liver. At one pace for every tissue, the 1 MPa
    /// liver's front let go of 0.49 N in its lift's first tick.
    pub(super) fn let_go_pace(&self, solver: &Solver) -> f64 {
        let e = solver.params().youngs_modulus_pa * self.force.stiffness_factor();
        let pace = self.force.toughness_n_per_m() / e / LET_GO_S;
        if pace.is_finite() { pace } else { 0.0 }
    }

    /// Where the crack front goes from `last` (Σ's end, rest: tip, top) with the blade's
    /// edge now at `edge` (rest), pushing along `ahead` (unit, across the edge): by the jump
    /// when it fractures, to the edge if the blade has got a support radius past the front
    /// unheld, else nowhere.
    pub(super) fn front_target(
        &self,
        last: &[Vec3; 2],
        edge: &[Vec3; 2],
        ahead: Vec3,
        jump: Option<f64>,
    ) -> Option<[Vec3; 2]> {
        if let Some(da) = jump {
            // The front's new place, the blade's depth and lean.
            let top = last[1] + ahead * da;
            return Some([top + (edge[0] - edge[1]), top]);
        }
        (lag_past(last, edge, ahead) > self.most_lag()).then_some(*edge)
    }

    /// How far past the front (rest) the edge may get unheld before it takes the crack.
    fn most_lag(&self) -> f64 {
        MOST_LAG_SUPPORTS * self.kernel.support_m
    }

    /// Places along a line of the blade, `line` (rest: from the tip up), into the tissue
    /// `toward` (unit) it faces: one every `pitch` over `depth_m` of it (at most
    /// [`MOST_LINE_SAMPLES`]), `offset` past the line, where the tissue at each of
    /// `probes` past the line is not cut already (a Σ triangle there that runs along
    /// `toward`): a second pass above its floor, the blade backing along its own wound.
    pub(super) fn along_line(
        &mut self,
        line: &[Vec3; 2],
        depth_m: f64,
        pitch: f64,
        toward: Vec3,
        probes: &[f64],
        offset: f64,
    ) -> [Option<Vec3>; MOST_LINE_SAMPLES] {
        let mut at = [None; MOST_LINE_SAMPLES];
        let along = line[1] - line[0];
        let Some(up) = along.try_normalize(1e-12) else {
            return at;
        };
        let depth = depth_m.min(along.norm());
        let count = ((depth / pitch).round() as usize).clamp(1, MOST_LINE_SAMPLES);
        // The Σ triangles near the line and its probes, once; past the scratch's
        // capacity, all of them.
        let far = probes.iter().copied().fold(0.0, f64::max);
        let ends = [
            line[0],
            line[1],
            line[0] + toward * far,
            line[1] + toward * far,
        ];
        let region = Aabb::around(&ends).expanded(far);
        let every = !near_region(
            &self.sigma.boxes,
            &region,
            &mut self.probe_candidates,
            MAX_PROBE_CANDIDATES,
        );
        let cut = |x: &Vec3, reach: f64| {
            let probe = x + toward * reach;
            let on = |t: usize| {
                self.sigma.boxes[t].expanded(reach).contains(&probe)
                    && self.on_triangle_along(&probe, &self.sigma.triangles[t], &toward)
            };
            match every {
                true => (0..self.sigma.triangles.len()).any(on),
                false => self.probe_candidates.iter().any(|&t| on(t as usize)),
            }
        };
        for (k, slot) in at.iter_mut().enumerate().take(count) {
            let x = line[0] + up * (depth * (k as f64 + 0.5) / count as f64);
            if probes.iter().all(|&reach| !cut(&x, reach)) {
                *slot = Some(x + toward * offset);
            }
        }
        at
    }

    /// Builds the crack-front samples along Σ's end `front` (rest: tip, top), `ahead` of it:
    /// every pitch from the tip up to the surface, where the tissue ahead is not cut
    /// already, each held by the blade's edge alone. Replaces what the blade held.
    pub(super) fn build_front(
        &mut self,
        front: &[Vec3; 2],
        depth_m: f64,
        ahead: Vec3,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        if (front[1] - front[0]).try_normalize(1e-12).is_none() {
            return;
        }
        let pitch = self.pitch();
        let reach = 2.0 * self.sigma_plane_tolerance();
        // Where the tissue ahead is cut already (a second pass above its floor), there is
        // nothing to break.
        let offset = AHEAD_PITCHES * pitch;
        let at = self.along_line(front, depth_m, pitch, ahead, &[reach], offset);
        let capture = CAPTURE_PITCHES * pitch;
        let others = |body: &BladeBody, s| body.is_lip(s) || body.is_spine(s);
        let laid = self.lay_samples(&at, others, solver, grid, |body, row, x, rest, _| {
            body.push_front(row, x, rest, capture);
        });
        if !laid {
            return;
        }
        self.front.built = true;
        self.front.stale = false;
    }
}
