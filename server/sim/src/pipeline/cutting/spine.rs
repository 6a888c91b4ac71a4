//! The blade's spine against uncut tissue (cutting-physics.md §2): a blade moved back,
//! toward its spine, past where its wound starts (or under a plunge's slit floor) meets the
//! tissue with its blunt back. The spine pushes it — spine samples, uncut material just
//! past the spine, held by the spine alone with the lips' compliant contact
//! (`solver::blade`, `push_spine`, `lip_forces`) — and cannot cut it: while the blade backs
//! the crack does not grow (`advance`: backing is withdrawing), and what the hand feels is
//! the tissue's push. Where the spine has indented the tissue as far as a blunt press
//! ruptures it (the capsule's rupture displacement), or crushed a point it holds (det F
//! below [`CRUSHED_DET_F`], the press's criterion), the tissue tears: Σ grows over the
//! blade's footprint and a little past the spine (`tear_rest`), a fracture tick, and the
//! spine meets the tissue beyond.

use super::fracture::{AHEAD_PITCHES, CAPTURE_PITCHES};
use super::*;
use crate::solver::blade::BladeBody;

/// The blade backs while its averaged motion is within 60° of its back, across its edge
/// (and is not going in point first, which slits: `grow_sigma`).
const BACKING_COS: f64 = 0.5;
/// While backing, the spine looks again for uncut tissue past it (rows with no sample)
/// once the tip has moved this many sample pitches.
const PROBE_PITCHES: f64 = 0.25;
/// A spine sample this many pitches off the spine (the blade moved on edge first, or
/// across its flats, or past it along its edge) is dropped.
const DROP_PITCHES: f64 = 2.0;
/// A tear opens this many sample pitches past the spine.
const TEAR_PITCHES: f64 = 2.0;

/// Where the spine last looked for tissue past it.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct SpineHold {
    probed_at: Option<Vec3>,
}

impl CuttingStage {
    /// Whether blade `b` is moving back, toward its spine (and not in point first).
    pub(super) fn backing(&self, b: &Blade) -> bool {
        let point_first = self.direction.dot(&b.edge) < -BACKING_COS;
        !point_first
            && touch::front_ahead(b).is_some_and(|ahead| self.direction.dot(&ahead) < -BACKING_COS)
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

    /// The quad a tear opens (rest): from the edge `[tip, top]` back past the spine, a
    /// quarter spacing above the surface as the sweep's (`grow_sigma`).
    pub(super) fn tear_rest(&self, edge: &[Vec3; 2], b: &Blade) -> Option<[Vec3; 4]> {
        let back = -touch::front_ahead(b)?;
        let across = back * (self.tool.blade_width_m + TEAR_PITCHES * self.pitch());
        let up = (edge[1] - edge[0]).try_normalize(1e-12)?;
        let top = edge[1] + up * (0.25 * self.spacing_m);
        Some([edge[0], top, edge[0] + across, top + across])
    }

    /// The spine tears through the tissue it pushed: Σ grows over `quad` (`tear_rest`).
    /// The field parts there; the drawn wound is the edge's path and is not extended by it
    /// (docs/CUTTING.md, "Not done yet").
    pub(super) fn tear_through(&mut self, quad: [Vec3; 4]) {
        let [tip, top, tip_back, top_back] = quad;
        self.sigma.add_sweep(tip, top, tip_back, top_back);
    }

    /// While cutting, the spine against the tissue past it: samples laid there while the
    /// blade backs, on the rows that have none, every [`PROBE_PITCHES`] of its travel;
    /// those the blade has moved away from dropped (all of them once the tissue `torn`);
    /// the points they follow awake. Nothing while a press is being let go.
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
        if solver.blade().is_some_and(|body| body.releasing_press()) {
            return;
        }
        let slab = slab_of(b, &self.tool);
        // (In lip pitches, as the lips' and the spine's patches are.)
        let far = DROP_PITCHES * self.lip_pitch(depth_m);
        if let Some((body, _, _, p)) = solver.blade_with_rows() {
            body.retain(|body, s| {
                if !body.is_spine(s) {
                    return true;
                }
                let l = body.local_in(&slab, s, p);
                !torn
                    && l.y < slab.width + far
                    && l.y > -far
                    && l.x > -far
                    && l.x < slab.length + far
                    && l.z.abs() < 0.5 * slab.thickness + far
            });
        }
        let moved = self
            .spine
            .probed_at
            .is_none_or(|at| (b.tip - at).norm() >= PROBE_PITCHES * self.pitch());
        if !backing || torn {
            self.spine.probed_at = None;
        } else if let (true, Some(edge), Some(ahead)) = (moved, edge_rest, touch::front_ahead(b)) {
            self.spine.probed_at = Some(b.tip);
            self.lay_spine(&edge, depth_m, -ahead, solver, grid);
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

    /// Lays spine samples along the spine of the blade whose edge is at `edge` (rest: tip,
    /// top), `back` (unit) past it: one every lip pitch from the tip up, where the tissue
    /// past the spine is not cut and no spine sample is on that row already (within half a
    /// pitch along the edge, at rest: one row's samples stacked across the spine would each
    /// push its whole patch), each held by the spine alone with the lips' compliant contact
    /// (their pitch and patch).
    fn lay_spine(
        &mut self,
        edge: &[Vec3; 2],
        depth_m: f64,
        back: Vec3,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let Some(up) = (edge[1] - edge[0]).try_normalize(1e-12) else {
            return;
        };
        let depth = depth_m.min((edge[1] - edge[0]).norm());
        let pitch = self.lip_pitch(depth);
        let stiffness = self.lip_stiffness(pitch, solver);
        let width = back * self.tool.blade_width_m;
        let spine = [edge[0] + width, edge[1] + width];
        // Half a sample pitch past the spine; in the wound (the blade backing along its
        // own cut) the spine meets nothing.
        let offset = AHEAD_PITCHES * self.pitch();
        let reach = 2.0 * self.sigma_plane_tolerance();
        let mut at = self.along_line(&spine, depth, pitch, back, &[offset, reach], offset);
        // A row with a spine sample already (its height along the edge, at rest) keeps it.
        if let Some(body) = solver.blade() {
            let height = |x: &Vec3| (x - spine[0]).dot(&up);
            let laid = |x: &Vec3| {
                (0..body.len()).any(|s| {
                    body.is_spine(s)
                        && (height(&body.rest_position(s, solver.rest())) - height(x)).abs()
                            < 0.5 * pitch
                })
            };
            for slot in &mut at {
                if slot.as_ref().is_some_and(laid) {
                    *slot = None;
                }
            }
        }
        let capture = CAPTURE_PITCHES * self.pitch();
        let all = |_: &BladeBody, _| true;
        self.lay_samples(&at, all, solver, grid, |body, row, x, rest, _| {
            body.push_spine(row, x, rest, capture, stiffness, pitch);
        });
    }

    /// Takes the spine's samples away (the blade left, or presses again).
    pub(super) fn drop_spine(&mut self, solver: &mut Solver) {
        self.spine.probed_at = None;
        if let Some(body) = solver.blade_mut() {
            body.retain(|body, s| !body.is_spine(s));
        }
    }
}
