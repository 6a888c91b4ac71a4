//! The benchmarks of a supported body under load (cutting-physics.md §1): B13, a column
//! under its own weight.

use super::BenchmarkResult;
use super::bodies::{BoxBody, box_body, static_config};
use crate::math::Vec3;
use crate::scene::Material;
use crate::solver::SolverConfig;

/// Standard gravity (m/s²).
pub const STANDARD_GRAVITY: f64 = 9.81;

/// B13's column: L = 20 mm tall, 10 × 10 mm across, E = 50 kPa (strain under 1 %: the
/// answer is linear elasticity's).
pub const COLUMN_HEIGHT_M: f64 = 0.020;
const COLUMN_SIDE_M: f64 = 0.010;
const COLUMN_MATERIAL: Material = Material {
    youngs_modulus_pa: 50_000.0,
    damping_per_s: 0.0,
    ..Material::LIVER
};

/// A column standing on rollers under gravity, solved statically: the base holds z only,
/// one base point x and y and another y (the rigid motions), the sides are free.
pub fn standing_column(points_across: usize, alpha_default: bool) -> BoxBody {
    let config = SolverConfig {
        gravity: Vec3::new(0.0, 0.0, -STANDARD_GRAVITY),
        ..static_config(alpha_default)
    };
    let size = Vec3::new(COLUMN_SIDE_M, COLUMN_SIDE_M, COLUMN_HEIGHT_M);
    let mut body = box_body(size, points_across, &COLUMN_MATERIAL, 2.0, config);
    body.on_rollers(2);
    body.solver.solve_static();
    body
}

/// Volume-weighted mean downward displacement of the column's top face (m).
pub fn top_sag(body: &BoxBody) -> f64 {
    body.face_sag(2, 1.0)
}

/// The top of a column in uniaxial stress σ_zz = ρ g (L − z): ρ g L² / (2E) (m).
pub fn column_sag_analytic() -> f64 {
    let m = COLUMN_MATERIAL;
    m.density_kg_m3 * STANDARD_GRAVITY * COLUMN_HEIGHT_M.powi(2) / (2.0 * m.youngs_modulus_pa)
}

/// B13, a column under its own weight: the top's mean sag within 2 % of ρ g L²/(2E) at 9
/// points across (7 reported beside it).
pub fn b13_column_under_gravity() -> BenchmarkResult {
    let expected = column_sag_analytic();
    let mut details = Vec::new();
    let mut error = 0.0;
    for m in [7, 9] {
        let sag = top_sag(&standing_column(m, false));
        let sag_default = top_sag(&standing_column(m, true));
        if m == 9 {
            error = (sag / expected - 1.0).abs();
        }
        details.push(format!(
            "m = {m}: {:.5} mm, ratio {:.4} (α = {}: {:.4})",
            sag * 1e3,
            sag / expected,
            SolverConfig::default().hourglass_alpha,
            sag_default / expected
        ));
    }
    BenchmarkResult::new(
        "B13",
        "column under its own weight: top sag = ρgL²/(2E)",
        error,
        0.02,
        format!(
            "{} (ρgL²/(2E) = {:.5} mm, strain at the base {:.2} %)",
            details.join(", "),
            expected * 1e3,
            100.0 * 2.0 * expected / COLUMN_HEIGHT_M
        ),
    )
}
