//! B15, a slit in a stretched plate opens as Griffith says (cutting-physics.md §4): a thin
//! slab pulled at its ends, then cut through by Σ (the product's visibility criterion) along
//! 2a across the load. What opens the slit is the field alone, so its shape is the test of
//! "the wound opens as a deformation": the crack faces part into Inglis' ellipse, half-opening
//! 2σ/E·√(a² − x²) on each face in plane stress.

use super::BenchmarkResult;
use super::bodies::{BoxBody, box_body, static_config};
use crate::math::Vec3;
use crate::scene::Material;

/// The slit's half-length in lattice spacings: its ends fall between lattice columns, so no
/// pair crosses Σ exactly at its edge.
pub const HALF_LENGTH_SPACINGS: f64 = 6.5;
/// The slab is this many half-lengths wide (across the load) and long (along it): the
/// issue's ≥ 8a, where the finite width opens the slit 3.9 % more than an infinite plate
/// (Tada's V(a/b) at a/b = 0.25).
const SIZE_HALF_LENGTHS: f64 = 8.0;
/// Points through the thickness (2 spacings: a thin slab, t = 0.31a).
const THICKNESS_POINTS: usize = 3;
/// Remote stress over E: small enough that the answer is linear elasticity's.
const STRAIN: f64 = 1e-3;

/// The slab's material: the liver's, undamped (a static solve).
const MATERIAL: Material = Material {
    damping_per_s: 0.0,
    ..Material::LIVER
};

/// Tada, Paris & Irwin's V1(a/b) (The Stress Analysis of Cracks Handbook, 3rd ed., 2.2):
/// how much more a centre slit of half-length a opens in a strip of half-width b than in an
/// infinite plate (within 1 % for any a/b).
pub fn finite_width_opening_factor(a_over_b: f64) -> f64 {
    let r = a_over_b;
    -0.071 - 0.535 * r + 0.169 * r * r + 0.020 * r.powi(3) - 1.071 / r * (1.0 - r).ln()
}

/// The opening the cut added along the slit, and the analytic one.
#[derive(Debug, Clone)]
pub struct SlitOpening {
    /// Rest x of each lattice column along the slit (m), |x| < a.
    pub x_m: Vec<f64>,
    /// Half-opening on each column: half the jump of u_y across the slit that the cut
    /// added (m), the mean over the thickness.
    pub half_opening_m: Vec<f64>,
    /// Inglis' half-opening 2σ/E·√(a² − x²) at the same x (m).
    pub analytic_m: Vec<f64>,
    /// The slit's half-length a (m).
    pub half_length_m: f64,
    /// Whether both static solves converged.
    pub converged: bool,
    /// Neighbour pairs the slit cut.
    pub pairs_cut: usize,
}

impl SlitOpening {
    /// The measured half-opening at the centre over the analytic 2σa/E.
    pub fn centre_ratio(&self) -> f64 {
        let centre = self.centre();
        self.half_opening_m[centre] / (self.analytic_m[centre])
    }

    /// RMS over the slit of the measured profile, scaled to its own centre, against the
    /// ellipse √(1 − x²/a²): the shape, apart from the size.
    pub fn shape_rms(&self) -> f64 {
        let centre = self.centre();
        let (m0, a0) = (self.half_opening_m[centre], self.analytic_m[centre]);
        let sum: f64 = self
            .half_opening_m
            .iter()
            .zip(&self.analytic_m)
            .map(|(m, a)| (m / m0 - a / a0).powi(2))
            .sum();
        (sum / self.x_m.len() as f64).sqrt()
    }

    fn centre(&self) -> usize {
        (0..self.x_m.len())
            .min_by(|&i, &j| self.x_m[i].abs().total_cmp(&self.x_m[j].abs()))
            .expect("the slit spans columns")
    }
}

/// A slab 8a square and two spacings thick on a 1 mm lattice, with a slit of half-length
/// `half_length_spacings` spacings, pulled to σ = STRAIN·E and then cut: the slit's opening.
/// `hourglass` false drops the hourglass control (the bare discretisation).
pub fn slit_in_stretched_plate(half_length_spacings: f64, hourglass: bool) -> SlitOpening {
    let spacing_m = 0.001;
    let a = half_length_spacings * spacing_m;
    let side = SIZE_HALF_LENGTHS * a;
    let thickness = (THICKNESS_POINTS - 1) as f64 * spacing_m;
    let config = static_config(hourglass);
    let size = Vec3::new(side, side, thickness);
    let mut body = box_body(size, THICKNESS_POINTS, &MATERIAL, 2.0, config);
    let sigma = STRAIN * MATERIAL.youngs_modulus_pa;
    hold_and_pull(&mut body, sigma * side * thickness);
    let first = body.solver.solve_static();
    let before = jumps_across_slit(&body, a);
    let pairs_cut = cut_slit(&mut body, a);
    let second = body.solver.solve_static();
    let after = jumps_across_slit(&body, a);
    let x_m: Vec<f64> = after.iter().map(|&(x, _)| x).collect();
    let half_opening_m = after
        .iter()
        .zip(&before)
        .map(|(&(_, j1), &(_, j0))| 0.5 * (j1 - j0))
        .collect();
    let analytic_m = x_m
        .iter()
        .map(|x| 2.0 * STRAIN * (a * a - x * x).sqrt())
        .collect();
    SlitOpening {
        x_m,
        half_opening_m,
        analytic_m,
        half_length_m: a,
        converged: first.converged && second.converged,
        pairs_cut,
    }
}

/// Rollers on the −y end (y held; one point held in x and z, one far along x in z: the
/// rigid motions), and the +y end pulled by `load_n` along +y, by point volume.
fn hold_and_pull(body: &mut BoxBody, load_n: f64) {
    body.on_rollers(1);
    let end = body.face(1, 1.0);
    let volume = &body.model.points.volume_m3;
    let total: f64 = end.iter().map(|&i| volume[i]).sum();
    for &i in &end {
        let share = volume[i] / total;
        body.solver
            .set_external_force(i, Vec3::new(0.0, load_n * share, 0.0));
    }
}

/// The slit's plane: half a spacing above the middle row, so no point lies on it.
fn slit_y(body: &BoxBody) -> f64 {
    0.5 * body.model.lattice.spacing
}

/// Σ for the slit: two triangles over |x| ≤ a at y = `slit_y`, through the thickness and
/// beyond; every neighbour pair crossing it is cut. How many were.
fn cut_slit(body: &mut BoxBody, a: f64) -> usize {
    let y = slit_y(body);
    let z = body.size.z;
    let corners = [
        Vec3::new(-a, y, -z),
        Vec3::new(a, y, -z),
        Vec3::new(a, y, z),
        Vec3::new(-a, y, z),
    ];
    body.cut_by(&[
        [corners[0], corners[1], corners[2]],
        [corners[0], corners[2], corners[3]],
    ])
    .0
}

/// Along the slit (|x| < a), for each lattice column: its rest x and the jump of u_y from
/// the row just below the slit's plane to the row just above, the mean over the thickness.
fn jumps_across_slit(body: &BoxBody, a: f64) -> Vec<(f64, f64)> {
    let s = body.model.lattice.spacing;
    let y = slit_y(body);
    let rest = &body.model.points.rest;
    let p = body.solver.positions();
    // Columns at whole spacings from the middle one (x = 0), inside the slit.
    let half = (a / s).floor() as i64;
    (-half..=half)
        .map(|c| {
            let x = c as f64 * s;
            let (mut jump, mut count) = (0.0, 0.0_f64);
            for (i, r) in rest.iter().enumerate() {
                if (r.x - x).abs() > 1e-6 * s {
                    continue;
                }
                let dy = r.y - y;
                let side = if (dy - 0.5 * s).abs() < 1e-6 * s {
                    1.0
                } else if (dy + 0.5 * s).abs() < 1e-6 * s {
                    -1.0
                } else {
                    continue;
                };
                jump += side * (p[i].y - r.y);
                count += 0.5;
            }
            (x, jump / count.max(1.0))
        })
        .collect()
}

/// B15: the slit's centre half-opening within 15 % of 2σa/E and its shape within 20 % RMS
/// of the ellipse, at a = 6.5 spacings (the bare discretisation, α = 0, beside it).
pub fn b15_griffith_slit() -> BenchmarkResult {
    let run = slit_in_stretched_plate(HALF_LENGTH_SPACINGS, true);
    let bare = slit_in_stretched_plate(HALF_LENGTH_SPACINGS, false);
    let centre = run.centre_ratio() - 1.0;
    let shape = run.shape_rms();
    // Both bands in one figure: each error over its own band, times the centre's band.
    let error = if run.converged && bare.converged {
        centre.abs().max(shape * 0.15 / 0.20)
    } else {
        f64::INFINITY
    };
    let strip = finite_width_opening_factor(2.0 / SIZE_HALF_LENGTHS);
    let profile: Vec<String> = run
        .x_m
        .iter()
        .zip(&run.half_opening_m)
        .zip(&run.analytic_m)
        .filter(|((x, _), _)| **x >= -1e-12)
        .map(|((x, m), an)| format!("{:.1}: {:.4}/{:.4}", x * 1e3, m * 1e3, an * 1e3))
        .collect();
    BenchmarkResult::new(
        "B15",
        "slit in a stretched plate: Inglis' ellipse, centre half-opening 2σa/E",
        error,
        0.15,
        format!(
            "a = {:.1} mm ({HALF_LENGTH_SPACINGS} spacings), σ/E = {STRAIN}: centre ratio {:.3} (α = 0: {:.3}; against the strip {SIZE_HALF_LENGTHS}a wide, Tada's V1 = {strip:.3}: {:.3}), shape RMS {:.1} % (α = 0: {:.1} %){}; {} pairs cut; half-opening mm, x: measured/ellipse {}",
            run.half_length_m * 1e3,
            run.centre_ratio(),
            bare.centre_ratio(),
            run.centre_ratio() / strip,
            100.0 * shape,
            100.0 * bare.shape_rms(),
            if run.converged && bare.converged {
                ""
            } else {
                " (a static solve did not converge)"
            },
            run.pairs_cut,
            profile.join(", ")
        ),
    )
}
