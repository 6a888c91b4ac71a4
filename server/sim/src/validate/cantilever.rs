//! The cantilever benchmarks B5, B5T, B5b and B6 of physics.md §8: a square beam clamped at
//! its root with a tip load, against a converged 3D reference (the project's own, from
//! tools/reference/fem_reference.py), against Timoshenko's beam theory, and in bending.

use super::BenchmarkResult;
use super::bodies::{BoxBody, box_body, timoshenko_tip_deflection};
use super::cases::{LIVER_UNDAMPED, quasi_static, quasi_static_default_alpha};
use crate::math::Vec3;
use crate::scene::Material;
use crate::solver::SolverConfig;

/// Tip deflection (m) of the B5 cantilever (L = 40 mm, b = 10 mm, E = 5 kPa, ν = 0.45, tip
/// load 0.1 mN), converged in 3D: 27-node hexahedra at 2 to 10 elements across, extrapolated
/// to zero size. From tools/reference/reference.json (`cantilever.tip_m`); a test keeps the
/// two equal.
pub const CANTILEVER_3D_TIP_M: f64 = 5.192_047_753e-4;

/// The same for the slender B5b beam (L = 100 mm); `slender_cantilever.tip_m`.
pub const SLENDER_CANTILEVER_3D_TIP_M: f64 = 7.940_019_778e-3;

/// Static tip deflection of a cantilever (root face clamped, tip load along −z spread over
/// the tip face by point volume) and the Timoshenko value.
pub fn cantilever_deflection(
    length: f64,
    side: f64,
    points_across: usize,
    load_n: f64,
    config: SolverConfig,
) -> (f64, f64, BoxBody) {
    let mut body = cantilever_body(length, side, points_across, load_n, &LIVER_UNDAMPED, config);
    body.solver.solve_static();
    let deflection = tip_deflection(&body);
    let e = LIVER_UNDAMPED.youngs_modulus_pa;
    let expected = timoshenko_tip_deflection(load_n, length, side, e, LIVER_UNDAMPED.poisson_ratio);
    (deflection, expected, body)
}

/// A cantilever with its root face clamped and the tip load applied, at rest.
pub fn cantilever_body(
    length: f64,
    side: f64,
    points_across: usize,
    load_n: f64,
    material: &Material,
    config: SolverConfig,
) -> BoxBody {
    let mut body = box_body(
        Vec3::new(length, side, side),
        points_across,
        material,
        2.0,
        config,
    );
    for i in body.face(0, -1.0) {
        body.solver.fix(i, [true; 3]);
    }
    load_tip(&mut body, load_n);
    body
}

/// Spreads a total load along −z over the tip face, by point volume (= face area weights).
fn load_tip(body: &mut BoxBody, load_n: f64) {
    let tip = body.face(0, 1.0);
    let total: f64 = tip.iter().map(|&i| body.model.points.volume_m3[i]).sum();
    for &i in &tip {
        let share = body.model.points.volume_m3[i] / total;
        body.solver
            .set_external_force(i, Vec3::new(0.0, 0.0, -load_n * share));
    }
}

/// Volume-weighted mean downward displacement of the tip face (m).
pub fn tip_deflection(body: &BoxBody) -> f64 {
    body.face_sag(0, 1.0)
}

/// The tip deflections of the B5 and B5b cantilevers for the `points_across` of the bench,
/// at α = 0 (the pure discretisation) and at the product's default α.
fn both_alphas(length: f64, m: usize) -> (f64, f64, f64) {
    let (d, timoshenko, _) = cantilever_deflection(length, 0.010, m, 1e-4, quasi_static());
    let (d_default, _, _) =
        cantilever_deflection(length, 0.010, m, 1e-4, quasi_static_default_alpha());
    (d, d_default, timoshenko)
}

/// The B5 beam's (points across, tip at α = 0, tip at the default α, Timoshenko's tip) at 7
/// and 9 points across: B5 and B5T read the same four static solves, made once a process.
fn b5_runs() -> &'static [(usize, f64, f64, f64); 2] {
    static RUNS: std::sync::OnceLock<[(usize, f64, f64, f64); 2]> = std::sync::OnceLock::new();
    RUNS.get_or_init(|| {
        [7, 9].map(|m| {
            let (d, d_default, timoshenko) = both_alphas(0.040, m);
            (m, d, d_default, timoshenko)
        })
    })
}

/// B5, cantilever L = 40 mm, b = 10 mm, tip load 0.1 mN: tip deflection within 2 % of the
/// converged 3D reference at 7 and 9 points across, at α = 0 and at the default α alike.
pub fn b5_cantilever() -> BenchmarkResult {
    let mut details = Vec::new();
    let mut error: f64 = 0.0;
    for &(m, d, d_default, _) in b5_runs() {
        let (r, r_default) = (d / CANTILEVER_3D_TIP_M, d_default / CANTILEVER_3D_TIP_M);
        error = error.max((r - 1.0).abs()).max((r_default - 1.0).abs());
        details.push(format!(
            "m = {m}: δ/δ_3D = {r:.4} (α = {}: {r_default:.4})",
            SolverConfig::default().hourglass_alpha,
        ));
    }
    BenchmarkResult::new(
        "B5",
        "cantilever tip deflection vs the converged 3D reference (L/b = 4)",
        error,
        0.02,
        format!(
            "{} (δ_3D = {:.4} mm, tools/reference/fem_reference.py)",
            details.join(", "),
            1e3 * CANTILEVER_3D_TIP_M
        ),
    )
}

/// B5T, the same beam against Timoshenko's beam theory, kept beside B5 (within 5 % at α = 0).
/// Beam theory lets the root's cross-section warp; a clamped face cannot, so the real 3D
/// beam is stiffer than Timoshenko assumes (3.84 % at L/b = 4; the detail prints it).
pub fn b5t_cantilever_timoshenko() -> BenchmarkResult {
    let mut details = Vec::new();
    let mut error: f64 = 0.0;
    let mut timoshenko = 0.0;
    for &(m, d, d_default, t) in b5_runs() {
        timoshenko = t;
        error = error.max((d / t - 1.0).abs());
        details.push(format!(
            "m = {m}: δ/δ_T = {:.4} (α = {}: {:.4})",
            d / t,
            SolverConfig::default().hourglass_alpha,
            d_default / t
        ));
    }
    BenchmarkResult::new(
        "B5T",
        "cantilever tip deflection vs Timoshenko beam theory (L/b = 4)",
        error,
        0.05,
        format!(
            "{} (δ_T = {:.4} mm, {:+.1} % from the 3D reference: a clamped root is stiffer \
             than beam theory assumes)",
            details.join(", "),
            1e3 * timoshenko,
            100.0 * (timoshenko / CANTILEVER_3D_TIP_M - 1.0)
        ),
    )
}

/// B5b, slender cantilever L/b = 10 at 5 points across: within 2 % of the 3D reference (the
/// worse of α = 0 and the default α); Timoshenko's ratio is reported beside it.
pub fn b5b_slender_cantilever() -> BenchmarkResult {
    let (d, d_default, timoshenko) = both_alphas(0.100, 5);
    let (r, r_default) = (
        d / SLENDER_CANTILEVER_3D_TIP_M,
        d_default / SLENDER_CANTILEVER_3D_TIP_M,
    );
    BenchmarkResult::new(
        "B5b",
        "slender cantilever tip deflection vs the 3D reference (L/b = 10)",
        (r - 1.0).abs().max((r_default - 1.0).abs()),
        0.02,
        format!(
            "m = 5: δ = {:.4} mm, δ_3D = {:.4} mm, ratio {r:.4} (α = {}: {r_default:.4}); \
             Timoshenko δ_T = {:.4} mm, δ/δ_T = {:.4}",
            d * 1e3,
            SLENDER_CANTILEVER_3D_TIP_M * 1e3,
            SolverConfig::default().hourglass_alpha,
            timoshenko * 1e3,
            d / timoshenko,
        ),
    )
}

/// First bending frequency of the B5 cantilever (Euler–Bernoulli), Hz.
pub fn euler_bernoulli_frequency(length: f64, side: f64, e: f64, density: f64) -> f64 {
    let inertia = side.powi(4) / 12.0;
    let area = side * side;
    1.8751f64.powi(2) / (2.0 * std::f64::consts::PI * length * length)
        * (e * inertia / (density * area)).sqrt()
}

/// Measured first bending period: release the B5 beam from its static deflection and time
/// the zero crossings of the tip (undamped explicit dynamics). Returns (period s, body).
pub fn bending_period(points_across: usize) -> (f64, BoxBody) {
    let (_, _, mut body) =
        cantilever_deflection(0.040, 0.010, points_across, 1e-4, SolverConfig::default());
    // Release: the static solve left the beam deflected and at rest.
    body.solver.clear_external_forces();
    let dynamic = &mut body;
    let dt = 1e-3;
    let mut crossings: Vec<f64> = Vec::new();
    let mut previous = tip_deflection(dynamic);
    let mut t = 0.0;
    while crossings.len() < 5 && t < 3.0 {
        dynamic.solver.step(dt);
        t += dt;
        let now = tip_deflection(dynamic);
        if previous > 0.0 && now <= 0.0 || previous < 0.0 && now >= 0.0 {
            // Linear interpolation of the crossing time within the tick.
            crossings.push(t - dt * now / (now - previous));
        }
        previous = now;
    }
    let period = if crossings.len() >= 3 {
        // Successive crossings are half a period apart.
        2.0 * (crossings[crossings.len() - 1] - crossings[0]) / (crossings.len() - 1) as f64
    } else {
        f64::NAN
    };
    (period, body)
}

/// B6, first bending frequency of the B5 beam: period within 5 % of Euler–Bernoulli 2.19 Hz.
pub fn b6_bending_frequency() -> BenchmarkResult {
    let (period, body) = bending_period(5);
    let f = euler_bernoulli_frequency(0.04, 0.01, 5000.0, 1060.0);
    let expected = 1.0 / f;
    BenchmarkResult::new(
        "B6",
        "first bending period vs Euler–Bernoulli f₁ = 2.19 Hz",
        (period / expected - 1.0).abs(),
        0.05,
        format!(
            "m = 5, undamped explicit ({} sub-steps per ms): T = {:.4} s vs {:.4} s (f = {:.3} Hz vs {:.3} Hz)",
            body.solver.substeps(),
            period,
            expected,
            1.0 / period,
            f
        ),
    )
}
