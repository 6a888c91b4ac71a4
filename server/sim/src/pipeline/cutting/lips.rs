//! The lips against the blade's flats while it cuts (cutting-physics.md §2): material of
//! each side of Σ, sampled on Σ where the blade's footprint lies and pushed out by its own
//! flat alone, with friction (`solver::blade`: `push_lip`, `lip_forces`). Columns are laid
//! on Σ as the crack grows past the edge (and over the whole footprint when the blade
//! starts cutting); those the spine has left behind are dropped. The flats' ground edge
//! wedges the lips apart as the blade passes; a blade leaned or pushed sideways presses one
//! lip, and the lip pushes back — a lateral force read from the tissue, with its friction
//! along the flats.
//!
//! Columns are born from the crack's growth, not rebuilt around the blade: a sample keeps
//! its contact (and its friction anchor) for as long as the blade passes over it, so the
//! force does not step when samples are renewed (a grid rebuilt every two pitches did:
//! docs/CUTTING-DECISIONS.md, "The blade in the tick"). The contact is compliant, not
//! rigid: docs/CUTTING-DECISIONS.md, "The lips against the flats".

use super::*;
use crate::model::embedding::Blockers;

/// Most lip rows along the blade's depth in the tissue ...
const MOST_ROWS: usize = 6;
/// ... and columns across its width at least this far apart (width / this).
const COLUMNS_PER_WIDTH: f64 = 4.0;
/// A lip sample sits this many lip pitches inside its lip (off Σ), so that its row sees its
/// own side's points only.
const DEPTH_PITCHES: f64 = 0.05;
/// A row is laid where Σ faces the flats within 45° (cosine).
const LEAST_FACING: f64 = std::f64::consts::FRAC_1_SQRT_2;
/// Most columns laid in one tick as the crack grows (a fracture's jump lays several).
const COLUMNS_PER_TICK: usize = 3;
/// A lip sample this many lip pitches outside the blade's footprint is dropped.
const DROP_PITCHES: f64 = 2.0;

/// Where the lips' columns are.
#[derive(Debug, Clone)]
pub(super) struct Lips {
    /// The top (rest) of the newest column; `None` before the first.
    last_column: Option<Vec3>,
    /// The Σ triangles near the column being laid (room made once).
    candidates: Vec<u32>,
}

impl Lips {
    pub(super) fn new() -> Self {
        Self {
            last_column: None,
            candidates: Vec::with_capacity(MAX_PROBE_CANDIDATES),
        }
    }
}

impl CuttingStage {
    /// The lips' pitch (m) for a blade `depth_m` in the tissue: at least the blade's sample
    /// pitch, and few enough that [`MOST_ROWS`] rows and the width's columns cover it.
    pub(super) fn lip_pitch(&self, depth_m: f64) -> f64 {
        self.pitch()
            .max(self.tool.blade_width_m / COLUMNS_PER_WIDTH)
            .max(depth_m / MOST_ROWS as f64)
    }

    /// A lip sample's contact stiffness (N/m). The field draws the lips' give at its
    /// spacing and above; what it cannot draw is the give within a patch of lip a spacing
    /// on a side, which yields like a half-space under a flat punch of that area
    /// (2aE/(1−ν²), a = side/√π: B14's law), in series with the field. Each sample stands
    /// for its pitch² share of that patch's area (the whole patch when the pitch is the
    /// coarser).
    pub(super) fn lip_stiffness(&self, pitch: f64, solver: &Solver) -> f64 {
        let params = solver.params();
        let e = params.youngs_modulus_pa * self.force.stiffness_factor();
        let (lambda, mu) = (params.lame.lambda, params.lame.mu);
        let nu = lambda / (2.0 * (lambda + mu));
        let side = self.spacing_m.max(pitch);
        let patch = 2.0 * side / std::f64::consts::PI.sqrt() * e / (1.0 - nu * nu);
        patch * (pitch / side).powi(2)
    }

    /// While cutting, the lips against the flats: those left behind dropped, new columns
    /// laid where the crack has grown, the blade moved to `b` when `move_blade` (nothing
    /// else moved it this tick).
    pub(super) fn follow_lips(
        &mut self,
        b: &Blade,
        depth_m: f64,
        move_blade: bool,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let slab = slab_of(b, &self.tool);
        let pitch = self.lip_pitch(depth_m);
        let was_empty = solver.blade().is_none_or(|body| body.is_empty());
        if let Some((body, _, _, p)) = solver.blade_with_rows() {
            let far = DROP_PITCHES * pitch;
            body.retain(|body, s| {
                if !body.is_lip(s) {
                    return true;
                }
                let l = body.local_in(&slab, s, p);
                l.x > -far
                    && l.x < slab.length + far
                    && l.y > -far
                    && l.y < slab.width + far
                    && l.z.abs() < slab.thickness + far
            });
        }
        self.lay_columns(b, &slab, depth_m, pitch, solver, grid);
        if let Some(body) = solver.blade_mut() {
            body.set_heading(self.direction);
            match (move_blade, was_empty) {
                (false, _) => {}
                (true, true) => body.place(slab),
                (true, false) => body.move_to(slab),
            }
        }
    }

    /// Takes the lips away (the blade left its cut, or presses again).
    pub(super) fn drop_lips(&mut self, solver: &mut Solver) {
        self.lips.last_column = None;
        if let Some(body) = solver.blade_mut() {
            body.retain(|body, s| !body.is_lip(s));
        }
    }

    /// Lays the columns due: over the footprint, edge to spine, when there are none yet;
    /// else each lip pitch the crack has grown past the newest, at most
    /// [`COLUMNS_PER_TICK`]. A column runs from the entry down to the tip (rest), half a
    /// pitch behind the edge; a row is laid where it is on Σ.
    fn lay_columns(
        &mut self,
        b: &Blade,
        slab: &Slab,
        depth_m: f64,
        pitch: f64,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let (Some([tip, entry]), Some(ahead)) = (self.last_edge, touch::front_ahead(b)) else {
            return;
        };
        let newest = entry - ahead * (0.5 * pitch);
        match self.lips.last_column {
            None => {
                let columns = (slab.width / pitch).ceil() as usize + 1;
                for k in 0..columns {
                    let top = newest - ahead * (k as f64 * pitch);
                    self.lay_column(top, tip - entry, depth_m, pitch, slab, solver, grid);
                }
                self.lips.last_column = Some(newest);
            }
            Some(_) => {
                for _ in 0..COLUMNS_PER_TICK {
                    let last = self.lips.last_column.unwrap_or(newest);
                    let grown = (newest - last).dot(&ahead);
                    if grown < pitch {
                        break;
                    }
                    let top = newest - ahead * (grown - pitch);
                    self.lay_column(top, tip - entry, depth_m, pitch, slab, solver, grid);
                    self.lips.last_column = Some(top);
                }
                // A crack grown past the blade's width in one go goes on from the blade.
                if self
                    .lips
                    .last_column
                    .is_some_and(|last| (newest - last).dot(&ahead) > slab.width)
                {
                    self.lips.last_column = Some(newest);
                }
            }
        }
    }

    /// Lays one column of lip samples from `top` (rest) down `down` as far as `depth_m`:
    /// at each row, the nearest place on Σ within its tolerance, and a sample a little
    /// inside each lip there.
    #[allow(clippy::too_many_arguments)]
    fn lay_column(
        &mut self,
        top: Vec3,
        down: Vec3,
        depth_m: f64,
        pitch: f64,
        slab: &Slab,
        solver: &mut Solver,
        grid: &RestGrid,
    ) {
        let Some(down_unit) = down.try_normalize(1e-12) else {
            return;
        };
        let depth = depth_m.min(down.norm());
        let rows = ((depth / pitch).round() as usize).clamp(1, MOST_ROWS);
        let inside = DEPTH_PITCHES * pitch;
        let side = slab.side();
        let kernel = self.kernel;
        let blockers = Blockers {
            triangles: &self.sigma.triangles,
            boxes: &self.sigma.boxes,
        };
        let tolerance = self.sigma_tolerance();
        let stiffness = self.lip_stiffness(pitch, solver);
        // One pass over Σ for the column (a session's Σ has thousands of triangles).
        let bottom = top + down_unit * depth;
        let region = Aabb::around([&top, &bottom, &bottom]).expanded(tolerance);
        let candidates = &mut self.lips.candidates;
        let every =
            !sigma::near_region(&self.sigma.boxes, &region, candidates, MAX_PROBE_CANDIDATES);
        let near: &[u32] = if every { &[] } else { candidates };
        let touch = &mut self.touch;
        let Some((body, op, rest, positions)) = solver.blade_with_rows() else {
            return;
        };
        let from = body.len();
        for r in 0..rows {
            let x = top + down_unit * (depth * (r as f64 + 0.5) / rows as f64);
            let Some((on, normal)) = nearest_on_sigma(&x, &self.sigma, near, every, tolerance)
            else {
                continue;
            };
            // Σ swept by a blade pushed across its flats is not a flat's lip.
            if normal.dot(&side).abs() < LEAST_FACING {
                continue;
            }
            let normal = if normal.dot(&side) < 0.0 {
                -normal
            } else {
                normal
            };
            for sign in [1.0, -1.0] {
                let at = on + normal * (sign * inside);
                if touch.row_at(&at, rest, grid, &kernel, blockers, op)
                    && body.fits(touch.row.len())
                {
                    body.push_lip(&touch.row, at, rest, sign, inside, stiffness, pitch);
                }
            }
        }
        body.finish(positions, 0.0, from);
    }
}

/// The nearest place on Σ to `x` (rest) within `tolerance`, and that triangle's unit
/// normal: among the triangles `near` lists, or all of them when `every`.
fn nearest_on_sigma(
    x: &Vec3,
    sigma: &SweptSurface,
    near: &[u32],
    every: bool,
    tolerance: f64,
) -> Option<(Vec3, Vec3)> {
    let mut best: Option<(f64, Vec3, Vec3)> = None;
    let listed = near.iter().map(|&t| t as usize);
    let all = 0..if every { sigma.triangles.len() } else { 0 };
    for t in listed.chain(all) {
        let (tri, bounds) = (&sigma.triangles[t], &sigma.boxes[t]);
        if !bounds.expanded(tolerance).contains(x) {
            continue;
        }
        let on = closest_point_on_triangle(x, tri);
        let d = (on - x).norm();
        if d > tolerance || best.is_some_and(|(b, ..)| b <= d) {
            continue;
        }
        let Some(n) = (tri[1] - tri[0])
            .cross(&(tri[2] - tri[0]))
            .try_normalize(1e-18)
        else {
            continue;
        };
        best = Some((d, on, n));
    }
    best.map(|(_, on, n)| (on, n))
}
