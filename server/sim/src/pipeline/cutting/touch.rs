//! The blade against the tissue: surface samples around it, which the solver keeps out of
//! the blade's slab in every sub-step (`solver::blade`). Built when the blade touches the
//! surface, rebuilt around it as it moves across its flats, taken away when the capsule
//! fails or the blade leaves. Every face holds the tissue: the dent is the tissue pressed
//! by the tip's end, and a blade slid sideways drags it by friction.

use super::*;
use crate::mls::MlsOperator;
use crate::model::SurfaceEmbedding;
use crate::model::embedding::Blockers;
use crate::solver::blade::{BladeBody, Slab};

/// Rows of samples beyond each flat ...
const ROWS_BEYOND: usize = 2;
/// ... and beyond its edge and its spine, along it.
const COLUMNS_BEYOND: i64 = 2;
/// The samples' pitch: a quarter of the lattice spacing, within [1.5 × the blade's
/// thickness, 1 mm] (the field is smooth at the spacing: finer samples only add cost).
const PITCH_PER_SPACING: f64 = 0.25;
const MOST_PITCH_M: f64 = 0.001;
/// Once the capsule fails or the blade is gone, the tissue it held is let go over this
/// time (s): the crack opening under the blade, at a tissue's pace.
const RELEASE_S: f64 = 0.1;
/// Grid cells a build lays samples on per tick.
const CELLS_PER_TICK: usize = 16;
/// Columns along the blade from its edge to its spine, at least.
const COLUMNS_ACROSS_WIDTH: f64 = 8.0;
/// Most samples, and row terms over all of them (room made once: no allocation after).
pub(crate) const MAX_BLADE_SAMPLES: usize = 224;
pub(crate) const MAX_BLADE_ENTRIES: usize = MAX_BLADE_SAMPLES * 768;
/// Scratch for one sample's row before its terms are merged.
pub(super) const MAX_ROW_TERMS: usize = 1 << 15;
/// A sample built deeper than this many pitches inside the blade is the crack's.
const BUILT_INSIDE_PITCHES: f64 = 0.1;
/// The samples are rebuilt around the blade once its tip has moved this many pitches
/// across its edge from where they were built.
const REBUILD_PITCHES: f64 = 0.25;

/// The way the blade's edge faces, across the edge: where it pushes the crack front.
pub(super) fn front_ahead(b: &Blade) -> Option<Vec3> {
    let ahead = -b.toward_back;
    (ahead - b.edge * ahead.dot(&b.edge)).try_normalize(1e-9)
}

/// The blade's slab for `blade` with the scene's tool.
pub(crate) fn slab_of(blade: &Blade, tool: &ToolSpec) -> Slab {
    Slab {
        tip: blade.tip,
        edge: blade.edge,
        back: blade.toward_back,
        length: tool.blade_length_m,
        width: tool.blade_width_m,
        thickness: tool.blade_thickness_m,
    }
}

/// The scratch a build uses (room made once).
pub(super) struct TouchScratch {
    crossings: Vec<crate::pipeline::surface::Crossing>,
    within: Vec<u32>,
    zero: Vec<(u32, f64)>,
    /// The last row [`TouchScratch::row_at`] made.
    pub(super) row: Vec<(u32, f64)>,
    /// Where the tip was when the samples were last built.
    built_at: Option<Vec3>,
    /// The next build goes here, and is swapped with the solver's (room made once).
    spare: Option<BladeBody>,
    /// The build under way: the blade it is laid out around, the next cell of its grid,
    /// and how many samples it carried over.
    pending: Option<(Slab, usize, usize)>,
    /// Where the tip touched the surface, and where the blade let go of the tissue and
    /// how far it had pressed.
    touched_at: Option<Vec3>,
    letting_go: Option<(Slab, f64)>,
    /// The samples are a press's (built while loading), to be let go once it ends.
    pressed: bool,
}

impl TouchScratch {
    pub(super) fn new() -> Self {
        Self {
            crossings: Vec::with_capacity(64),
            within: Vec::with_capacity(4096),
            zero: Vec::with_capacity(4096),
            row: Vec::with_capacity(MAX_ROW_TERMS),
            built_at: None,
            spare: None,
            pending: None,
            touched_at: None,
            letting_go: None,
            pressed: false,
        }
    }

    /// The field's first-order row at rest point `x` for a sample that follows it, into
    /// `self.row`: the kernel's weights of the points that see `x` without crossing Σ
    /// (`blockers`), normalised. `false` where no point sees it.
    pub(super) fn row_at(
        &mut self,
        x: &Vec3,
        rest: &[Vec3],
        grid: &RestGrid,
        kernel: &Kernel,
        blockers: Blockers<'_>,
        op: &MlsOperator,
    ) -> bool {
        let zero = &mut self.zero;
        SurfaceEmbedding::row_into(x, rest, grid, kernel, blockers, &mut self.within, zero);
        let total: f64 = zero.iter().map(|(_, w)| w).sum();
        if total.is_nan() || total <= 0.0 {
            return false;
        }
        zero.iter_mut().for_each(|(_, w)| *w /= total);
        op.linear_row(zero, x, rest, &mut self.row);
        true
    }
}

impl CuttingStage {
    /// Room for rebuilding the blade's samples: a body like the solver's (made once, before
    /// the first tick).
    pub(crate) fn give_blade_room(&mut self, spare: BladeBody) {
        self.touch.spare = Some(spare);
    }

    /// Lays samples at the places `at` (rest) after `keep` has chosen which of the blade's
    /// samples stay: each place's row made (`row_at`, not seeing across Σ) and, while it
    /// fits, handed to `lay(body, row, place, rest, positions)` to push; the batch
    /// finished. `false` when the body has no blade.
    pub(super) fn lay_samples(
        &mut self,
        at: &[Option<Vec3>],
        keep: impl Fn(&BladeBody, usize) -> bool,
        solver: &mut Solver,
        grid: &RestGrid,
        mut lay: impl FnMut(&mut BladeBody, &[(u32, f64)], Vec3, &[Vec3], &[Vec3]),
    ) -> bool {
        let kernel = self.kernel;
        let blockers = Blockers {
            triangles: &self.sigma.triangles,
            boxes: &self.sigma.boxes,
        };
        let touch = &mut self.touch;
        let Some((body, op, rest, positions)) = solver.blade_with_rows() else {
            return false;
        };
        body.retain(keep);
        let from = body.len();
        for x in at.iter().flatten() {
            if touch.row_at(x, rest, grid, &kernel, blockers, op) && body.fits(touch.row.len()) {
                lay(body, &touch.row, *x, rest, positions);
            }
        }
        body.finish(positions, 0.0, from);
        true
    }

    /// The blade's pitch of samples (m).
    pub(super) fn pitch(&self) -> f64 {
        (PITCH_PER_SPACING * self.spacing_m)
            .min(MOST_PITCH_M)
            .max(1.5 * self.tool.blade_thickness_m)
    }

    /// The blade against the tissue this tick: samples built when it touches (and rebuilt
    /// as it travels while cutting), the faces that hold for the phase, the blade moved to
    /// where it is, the points the samples follow woken; all taken away when it leaves.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn touch_tissue(
        &mut self,
        dt: f64,
        force: &CutForce,
        blade: Option<&Blade>,
        depth_m: f64,
        surface: &CurrentSurface,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        // Pressing, every face holds the tissue. Once the capsule fails the press is let go
        // over RELEASE_S; then the edge holds the crack front's samples (`fracture`, by
        // energy) and each flat its lip (`lips`).
        let (Some(b), true) = (blade, force.phase == CutPhase::Loading) else {
            self.touch.built_at = None;
            self.touch.pending = None;
            if !self.front.built && self.let_go(dt, solver) {
                return;
            }
            let by_energy = self.force.fracture_by_energy();
            match (blade, force.phase) {
                (Some(b), CutPhase::Cutting) => {
                    if by_energy {
                        self.follow_front(b, depth_m, solver, grid);
                    }
                    self.follow_lips(b, depth_m, !by_energy, solver, grid);
                    if !by_energy {
                        self.wake_held(solver);
                    }
                }
                _ => {
                    self.drop_front(solver);
                    self.drop_lips(solver);
                }
            }
            return;
        };
        self.drop_front(solver);
        self.drop_lips(solver);
        self.touch.letting_go = None;
        let slab = slab_of(b, &self.tool);
        let rebuild = self.touch.built_at.is_none_or(|at| {
            // A grid a pitch apart would let the tip's end (a blade's thickness wide) slip
            // between its rows as it moves across its flats.
            let moved = b.tip - at;
            let across = moved - b.edge * moved.dot(&b.edge);
            across.norm() > REBUILD_PITCHES * self.pitch()
        });
        if rebuild {
            if self.touch.built_at.is_none() {
                self.touch.touched_at = Some(b.tip);
            }
            self.start_build(&slab, solver);
            self.touch.built_at = Some(b.tip);
        } else if let Some(body) = solver.blade_mut() {
            body.move_to(slab);
        }
        let grew = self.build_some(surface, solver, grid);
        // What the samples follow moves, and so does what holds it: asleep, a neighbour
        // would take the dent's whole strain at the rim of the moving patch. (Sleep is
        // checked every SLEEP_CHECK_EVERY ticks, and waking keeps a point awake for
        // SLEEP_AFTER_TICKS: the neighbours need waking only that often.)
        self.wake_under_blade(solver, grew);
    }

    /// Lets go of what a press held, a step of `dt`: the faces back out along the edge to
    /// where it touched, so the dent relaxes as the crack opens under the blade. Returns
    /// whether some of it is still held.
    fn let_go(&mut self, dt: f64, solver: &mut Solver) -> bool {
        let Some(body) = solver.blade_mut() else {
            return false;
        };
        if body.is_empty() || !self.touch.pressed {
            self.touch.letting_go = None;
            return false;
        }
        let (at, depth) = *self.touch.letting_go.get_or_insert_with(|| {
            let at = *body.slab();
            let depth = self
                .touch
                .touched_at
                .map_or(0.0, |t| (t - at.tip).dot(&at.edge));
            (at, depth.max(0.0))
        });
        let left = body.release(dt / RELEASE_S);
        body.move_to(Slab {
            tip: at.tip + at.edge * (depth * (1.0 - left)),
            ..at
        });
        if left > 0.0 {
            self.wake_under_blade(solver, false);
            true
        } else {
            self.touch.letting_go = None;
            self.touch.pressed = false;
            false
        }
    }

    /// While cutting, the edge against the crack front: its samples built where Σ ends
    /// (again after each jump), the blade moved to where it is, the points they follow awake.
    fn follow_front(&mut self, b: &Blade, depth_m: f64, solver: &mut Solver, grid: &RestGrid) {
        let slab = slab_of(b, &self.tool);
        let fresh = !self.front.built || self.front.stale;
        if fresh {
            let Some((front, ahead)) = self.last_sweep.zip(front_ahead(b)) else {
                return;
            };
            self.build_front(&front, depth_m, ahead, solver, grid);
            if let Some(body) = solver.blade_mut() {
                body.place(slab);
            }
        } else if let Some(body) = solver.blade_mut() {
            body.move_to(slab);
        }
        self.wake_under_blade(solver, fresh);
    }

    /// Keeps the points awake that the samples a face holds follow (the lips the flats
    /// press): a lip held on points asleep would push the blade and move nothing. Only
    /// those: most lips touch nothing (a wound opens under its residual tension), and what
    /// a lip moves wakes the rest as it moves.
    fn wake_held(&mut self, solver: &Solver) {
        let Some(body) = solver.blade() else {
            return;
        };
        let material = self.material_points as u32;
        for k in body.held_points() {
            if k < material {
                self.wake(k);
            }
        }
    }

    /// Takes the crack front's samples away (the blade left, or presses again).
    fn drop_front(&mut self, solver: &mut Solver) {
        self.front.work_j = 0.0;
        if std::mem::take(&mut self.front.built)
            && let Some(body) = solver.blade_mut()
        {
            body.retain(|body, s| body.is_lip(s) || body.is_spine(s));
        }
    }

    /// Wakes the points the blade's samples follow, and their neighbours when `grew` (new
    /// samples) or every SLEEP_CHECK_EVERY ticks.
    fn wake_under_blade(&mut self, solver: &Solver, grew: bool) {
        let neighbours_too = grew || self.tick.is_multiple_of(SLEEP_CHECK_EVERY);
        let (Some(body), op) = (solver.blade(), solver.operator()) else {
            return;
        };
        for &k in body.reached() {
            if (k as usize) >= self.material_points {
                continue;
            }
            self.wake(k);
            if neighbours_too {
                for &j in op.neighbours(k as usize) {
                    if (j as usize) < self.material_points {
                        self.wake(j);
                    }
                }
            }
        }
    }

    /// Starts a build of the samples around the blade at `slab`: those a face holds now go
    /// on (their force and friction with them), the grid fills in around them over the
    /// next ticks ([`Self::build_some`]).
    fn start_build(&mut self, slab: &Slab, solver: &mut Solver) {
        let TouchScratch { row, spare, .. } = &mut self.touch;
        let Some((body, _, rest, _)) = solver.blade_with_rows() else {
            return;
        };
        let Some(next) = spare.as_mut() else {
            return;
        };
        body.carry_held_into(next, rest, row);
        std::mem::swap(body, next);
        self.touch.pressed = true;
        body.place(*slab);
        self.touch.pending = Some((*slab, 0, body.len()));
    }

    /// Adds up to [`CELLS_PER_TICK`] samples of the build under way: a grid in the blade's
    /// frame, columns from beyond its edge to beyond its spine, rows across its flats (the
    /// mid-plane's first, where the tip's end presses), each dropped along the edge onto
    /// the skin below and following the points by the surface's first-order map there
    /// (not seeing across the cut). A build takes a few ticks: at once it was up to 0.9 ms
    /// of one tick on the liver.
    /// Returns whether it added any.
    fn build_some(
        &mut self,
        surface: &CurrentSurface,
        solver: &mut Solver,
        grid: &RestGrid,
    ) -> bool {
        let Some((slab, first, kept)) = self.touch.pending else {
            return false;
        };
        let pitch = self.pitch();
        let along_pitch = pitch.max(slab.width / COLUMNS_ACROSS_WIDTH);
        let columns = (slab.width / along_pitch).round() as usize + 2 * COLUMNS_BEYOND as usize;
        // Rows across: under the tip's end and ROWS_BEYOND beyond each flat.
        let across_pitch = pitch.max(slab.thickness / 4.0);
        let each_side = (0.5 * slab.thickness / across_pitch).ceil() as usize + ROWS_BEYOND;
        let rows = 2 * each_side + 1;
        let reach = slab.length.max(2.0 * self.kernel.support_m);
        let side = slab.side();
        let kernel = surface.kernel();
        let blockers = Blockers {
            triangles: &self.sigma.triangles,
            boxes: &self.sigma.boxes,
        };
        let touch = &mut self.touch;
        let Some((body, op, rest, positions)) = solver.blade_with_rows() else {
            return false;
        };
        let from = body.len();
        let last = (first + CELLS_PER_TICK).min(rows * columns);
        for cell in first..last {
            // Rows 0, −1, 1, −2, 2, …; half a pitch off the edge and the spine, where a
            // sample on a face's plane would be held by whichever face rounding picks.
            let k = (cell / columns) as i64;
            let r = if k % 2 == 0 { k / 2 } else { -(k + 1) / 2 };
            let c = (cell % columns) as i64;
            let back = ((c - COLUMNS_BEYOND) as f64 + 0.5) * along_pitch;
            let foot = slab.tip + slab.back * back + side * (r as f64 * across_pitch);
            let (from_x, to_x) = (foot + slab.edge * reach, foot - slab.edge * reach);
            let Some((t, bary, _)) = surface.first_entry(&from_x, &to_x, &mut touch.crossings)
            else {
                continue;
            };
            let x = surface.rest_point(t, bary);
            if (0..kept).any(|s| (body.rest_position(s, rest) - x).norm() < 0.5 * pitch) {
                continue;
            }
            if touch.row_at(&x, rest, grid, &kernel, blockers, op) && body.fits(touch.row.len()) {
                body.push(&touch.row, x, rest);
            }
        }
        body.finish(positions, BUILT_INSIDE_PITCHES * pitch, from);
        self.touch.pending = (last < rows * columns).then_some((slab, last, kept));
        body.len() > from
    }
}
