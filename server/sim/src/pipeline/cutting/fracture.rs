//! Fracture at the crack front by energy (cutting-physics.md §3, Mahvash & Hayward 2001).
//!
//! While cutting, the blade's edge pushes *crack-front samples*: material just ahead of
//! the end of Σ, embedded in the field like the surface's vertices and held by the edge
//! alone (`solver::blade`, `push_front`). What they push back with is the tissue's: it rises
//! with its stiffness as the blade indents the uncut tissue ahead. The crack advances only
//! when the energy the advance releases pays for the new crack: a jump of Δa at the blade's
//! place releases f·Δa − ½k·Δa² (f the push along the blade's facing, k the tissue's
//! stiffness there, the loading slope), and costs J_c·w·Δa (w the width of fresh tissue
//! the edge engages). So it jumps when f − ½k·Δa ≥ J_c·w, and the mean force over the
//! deformation–fracture cycles is J_c·w whatever the stiffness. Where the edge has got
//! further past the front than Δa, the release is taken over that span instead, so the
//! catch-up jumps are paid for too.
//!
//! Δa is the process zone's length, below the lattice: the tissue at the edge strain-
//! stiffens, so the zone that loads the crack tip is `crack_tip_stiffening` times stiffer than
//! the small-strain modulus E, and it fails after J_c/(c·E) of indentation (2 mm on the
//! liver at the default 19). That sets the sawtooth's period; its drop is about k·Δa.

use super::*;
use crate::model::embedding::Blockers;

/// The crack-front samples sit this many sample pitches ahead of Σ's end (rest): on the
/// uncut side, so their rows see the tissue ahead.
const AHEAD_PITCHES: f64 = 0.5;
/// Most crack-front samples along the edge.
const MOST_FRONT_SAMPLES: usize = 16;
/// The edge catches a front sample within this many pitches across its flats.
const CAPTURE_PITCHES: f64 = 1.0;
/// A blade whose edge has got this many support radii past the crack front (rest) without
/// breaking it — nothing ahead held it: a sliver, a front the field did not reach — takes the
/// crack to its edge.
const MOST_LAG_SUPPORTS: f64 = 2.5;

/// The crack front's state: how its samples stand, and what the last tick read.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct CrackFront {
    /// The blade holds crack-front samples ...
    pub(super) built: bool,
    /// ... built for a front that has moved since.
    pub(super) stale: bool,
    /// The tissue's stiffness along the blade's facing (N/m), read by the force stage.
    pub(super) tissue_k: f64,
}

/// How far the edge (rest: tip, top) has got past the crack front `front` along `ahead`.
fn lag_past(front: &[Vec3; 2], edge: &[Vec3; 2], ahead: Vec3) -> f64 {
    (edge[1] - front[1]).dot(&ahead)
}

impl CuttingStage {
    /// The tissue's stiffness seen at the blade along its facing (N/m), from the force
    /// stage's reading: the loading slope the fracture criterion takes off the release.
    pub fn note_tissue_stiffness(&mut self, k: f64) {
        self.front.tissue_k = if k.is_finite() { k.max(0.0) } else { 0.0 };
    }

    /// The jump Δa (m) if the crack advances this tick: the energy criterion on what the
    /// edge's samples pushed with over the last step (`force_on_blade`), `width_m` of fresh
    /// tissue engaged. Where the edge (`edge_rest`: tip, top) has got past the front by more
    /// than the process zone (the tissue beside it flowed by), the release is taken over
    /// that whole span, so a run of catch-up jumps is paid for (the mean force stays J_c·w);
    /// the front still moves by Δa a jump.
    pub(super) fn fracture_due(
        &self,
        phase: CutPhase,
        blade: Option<&Blade>,
        width_m: f64,
        edge_rest: Option<[Vec3; 2]>,
        solver: &Solver,
    ) -> Option<f64> {
        let (CutPhase::Cutting, Some(b), Some(body), true) =
            (phase, blade, solver.blade(), self.front.built)
        else {
            return None;
        };
        if body.is_empty() || width_m <= 0.0 {
            return None;
        }
        // The tissue pushes the blade toward its spine.
        let push = body.force_on_blade().dot(&b.toward_back);
        let lag = match (self.last_sweep, edge_rest, touch::front_ahead(b)) {
            (Some(front), Some(edge), Some(ahead)) => lag_past(&front, &edge, ahead),
            _ => 0.0,
        };
        let jump = self.process_zone(solver);
        let span = jump.max(lag.min(self.most_lag()));
        let toughness = self.force.toughness_n_per_m();
        (push - 0.5 * self.front.tissue_k * span >= toughness * width_m).then_some(jump)
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
        let pitch = self.pitch();
        let along = front[1] - front[0];
        let Some(up) = along.try_normalize(1e-12) else {
            return;
        };
        let depth = depth_m.min(along.norm());
        let count = ((depth / pitch).round() as usize).clamp(1, MOST_FRONT_SAMPLES);
        let reach = 2.0 * self.sigma_plane_tolerance();
        // Where the tissue ahead is cut already (a second pass above its floor), there is
        // nothing to break.
        let mut at = [None; MOST_FRONT_SAMPLES];
        for (k, slot) in at.iter_mut().enumerate().take(count) {
            let on_front = front[0] + up * (depth * (k as f64 + 0.5) / count as f64);
            let probe = on_front + ahead * reach;
            let cut_ahead = self
                .sigma
                .triangles
                .iter()
                .zip(&self.sigma.boxes)
                .any(|(tri, b)| {
                    b.expanded(reach).contains(&probe)
                        && self.on_triangle_along(&probe, tri, &ahead)
                });
            if !cut_ahead {
                *slot = Some(on_front + ahead * (AHEAD_PITCHES * pitch));
            }
        }
        let kernel = self.kernel;
        let blockers = Blockers {
            triangles: &self.sigma.triangles,
            boxes: &self.sigma.boxes,
        };
        let touch = &mut self.touch;
        let Some((body, op, rest, positions)) = solver.blade_with_rows() else {
            return;
        };
        body.clear();
        for x in at.iter().flatten() {
            if touch.row_at(x, rest, grid, &kernel, blockers, op) && body.fits(touch.row.len()) {
                body.push_front(&touch.row, *x, rest, CAPTURE_PITCHES * pitch);
            }
        }
        body.finish(positions, 0.0, 0);
        self.front.built = true;
        self.front.stale = false;
    }
}
