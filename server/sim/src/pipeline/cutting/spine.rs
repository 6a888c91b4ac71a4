//! The blade's spine against uncut tissue (cutting-physics.md §2): a blade moved back,
//! toward its spine, past where its wound starts meets the tissue with its blunt back. The
//! spine pushes it — spine samples, uncut material just past the spine, held by the spine
//! alone (`solver::blade`, `push_spine`) — and cannot cut it: while the blade backs, the
//! crack does not grow (`advance`: backing is withdrawing), and what the hand feels is the
//! tissue's push. Where the tissue the spine holds is crushed (det F below
//! [`CRUSHED_DET_F`] at a point a held spine sample follows, the capsule's own criterion
//! under a press) it tears: Σ grows over the blade's footprint and a little past the spine
//! (`tear_rest`), and the spine meets the tissue beyond it.

use super::fracture::{AHEAD_PITCHES, CAPTURE_PITCHES};
use super::*;
use crate::model::embedding::Blockers;

/// The blade backs while its averaged motion is within 60° of its back, across its edge.
const BACKING_COS: f64 = 0.5;
/// Most spine samples along the spine.
const MOST_SPINE_SAMPLES: usize = 16;
/// With nothing held, the spine looks again for uncut tissue past it once the tip has
/// moved this many sample pitches.
const PROBE_PITCHES: f64 = 0.25;
/// A spine sample this many pitches past the spine (the blade moved on, edge first) is
/// dropped.
const DROP_PITCHES: f64 = 2.0;
/// A tear opens this many sample pitches past the spine.
const TEAR_PITCHES: f64 = 2.0;

/// Where the spine last looked for tissue past it.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct SpineHold {
    probed_at: Option<Vec3>,
}

impl CuttingStage {
    /// Whether blade `b` is moving back, toward its spine.
    pub(super) fn backing(&self, b: &Blade) -> bool {
        touch::front_ahead(b).is_some_and(|ahead| self.direction.dot(&ahead) < -BACKING_COS)
    }

    /// Whether the tissue the spine holds tears: indented as far as a blunt press ruptures
    /// it (the capsule's rupture displacement), or crushed.
    pub(super) fn spine_tears(&self, solver: &Solver) -> bool {
        solver.blade().is_some_and(|body| {
            body.spine_indentation() >= self.force.rupture_displacement_m()
                || body
                    .spine_points(true)
                    .any(|i| solver.deformation_gradient(i as usize).determinant() < CRUSHED_DET_F)
        })
    }

    /// The quad a tear opens (rest): from the edge `[tip, top]` back past the spine.
    pub(super) fn tear_rest(&self, edge: &[Vec3; 2], b: &Blade) -> Option<[Vec3; 4]> {
        let back = -touch::front_ahead(b)?;
        let across = back * (self.tool.blade_width_m + TEAR_PITCHES * self.pitch());
        // A quarter spacing above the surface, as the sweep's (`grow_sigma`).
        let up = (edge[1] - edge[0]).try_normalize(1e-12)?;
        let top = edge[1] + up * (0.25 * self.spacing_m);
        Some([edge[0], top, edge[0] + across, top + across])
    }

    /// The spine tears through the tissue it pushed: Σ grows over `quad` (`tear_rest`).
    /// Returns the slit it opens at the surface (rest, from the edge's entry back), drawn as
    /// a plunge's.
    pub(super) fn tear_through(&mut self, quad: [Vec3; 4]) -> Vec3 {
        let [tip, top, tip_back, top_back] = quad;
        self.sigma.add_sweep(tip, top, tip_back, top_back);
        top_back - top
    }

    /// While cutting, the spine against the tissue past it: samples built there while the
    /// blade backs and has none, those the blade has moved away from dropped
    /// (all of them once the tissue `torn`), the points they follow awake.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn follow_spine(
        &mut self,
        b: &Blade,
        edge_rest: Option<[Vec3; 2]>,
        depth_m: f64,
        backing: bool,
        torn: bool,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let slab = slab_of(b, &self.tool);
        let pitch = self.pitch();
        if let Some((body, _, _, p)) = solver.blade_with_rows() {
            let far = slab.width + DROP_PITCHES * pitch;
            body.retain(|body, s| {
                !body.is_spine(s) || (!torn && body.local_in(&slab, s, p).y < far)
            });
        }
        let some = solver
            .blade()
            .is_some_and(|body| body.spine_points(false).next().is_some());
        let moved = self
            .spine
            .probed_at
            .is_none_or(|at| (b.tip - at).norm() >= PROBE_PITCHES * pitch);
        if !backing || torn {
            self.spine.probed_at = None;
        } else if let (false, true, Some(edge), Some(ahead)) =
            (some, moved, edge_rest, touch::front_ahead(b))
        {
            self.spine.probed_at = Some(b.tip);
            self.build_spine(&edge, depth_m, -ahead, solver, grid);
        }
        let material = self.material_points as u32;
        let Some(body) = solver.blade() else {
            return;
        };
        for k in body.spine_points(false) {
            if k < material {
                self.wake(k);
            }
        }
    }

    /// Builds the spine samples along the spine of the blade whose edge is at `edge` (rest:
    /// tip, top), `back` (unit) past it: every pitch from the tip up to the surface, where
    /// the tissue past the spine is not cut, each held by the spine alone. Replaces the
    /// spine samples there were.
    fn build_spine(
        &mut self,
        edge: &[Vec3; 2],
        depth_m: f64,
        back: Vec3,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let along = edge[1] - edge[0];
        let Some(up) = along.try_normalize(1e-12) else {
            return;
        };
        let depth = depth_m.min(along.norm());
        // The lips' pitch and patch: the spine's contact is compliant as theirs is.
        let pitch = self.lip_pitch(depth);
        let stiffness = self.lip_stiffness(pitch, solver);
        let count = ((depth / pitch).round() as usize).clamp(1, MOST_SPINE_SAMPLES);
        let reach = 2.0 * self.sigma_plane_tolerance();
        let offset = AHEAD_PITCHES * self.pitch();
        let capture = CAPTURE_PITCHES * self.pitch();
        let mut at = [None; MOST_SPINE_SAMPLES];
        for (k, slot) in at.iter_mut().enumerate().take(count) {
            let on_spine = edge[0]
                + up * (depth * (k as f64 + 0.5) / count as f64)
                + back * self.tool.blade_width_m;
            // In the wound (the blade backing along its own cut) the spine meets nothing.
            if !self.cut_beyond(&on_spine, &back, offset)
                && !self.cut_beyond(&on_spine, &back, reach)
            {
                *slot = Some(on_spine + back * offset);
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
        let from = {
            body.retain(|body, s| !body.is_spine(s));
            body.len()
        };
        for x in at.iter().flatten() {
            if touch.row_at(x, rest, grid, &kernel, blockers, op) && body.fits(touch.row.len()) {
                body.push_spine(&touch.row, *x, rest, capture, stiffness, pitch);
            }
        }
        body.finish(positions, 0.0, from);
    }

    /// Takes the spine's samples away (the blade left, or presses again).
    pub(super) fn drop_spine(&mut self, solver: &mut Solver) {
        self.spine.probed_at = None;
        if let Some(body) = solver.blade_mut() {
            body.retain(|body, s| !body.is_spine(s));
        }
    }
}
