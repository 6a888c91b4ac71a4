//! B14, a flat punch on a block (cutting-physics.md §6): the rigid tool of `scalpel probe`
//! pressed into a block on a fixed base, against the block's converged 3D stiffness (the
//! project's own, tools/reference/fem_reference.py) and the half-space's 2aE/(1 − ν²).

use super::BenchmarkResult;
use super::bodies::box_body;
use crate::math::Vec3;
use crate::pipeline::probe::{ProbeReport, ProbeSpec, press};
use crate::scene::Material;
use crate::solver::{SolverConfig, SolverMode};

/// Block half-width and depth in punch radii: the block is 8 radii wide and deep.
const HALF_WIDTH_RADII: f64 = 4.0;
const DEPTH_RADII: f64 = 8.0;
/// Indentation as a fraction of the radius (linear elasticity's regime).
const INDENTATION: f64 = 0.02;
/// The punch radius (m).
pub const PUNCH_RADIUS_M: f64 = 0.006;
/// The block's stiffness under the whole punch (N/mm), converged in 3D: 27-node hexahedra
/// at 1 to 4 elements per radius, extrapolated. From tools/reference/reference.json
/// (`punch.stiffness_n_per_mm`); a test keeps the two equal.
pub const PUNCH_BLOCK_3D_N_PER_MM: f64 = 7.499_737_204e-2;

/// A quarter of the block under symmetry (rollers on the two cut planes, the base fixed),
/// `spacings` lattice spacings to the punch radius, pressed `INDENTATION` of the radius.
pub fn punch_on_block(spacings: usize) -> ProbeReport {
    let a = PUNCH_RADIUS_M;
    let material = Material {
        damping_per_s: 0.0,
        ..Material::LIVER
    };
    let config = SolverConfig {
        mode: SolverMode::QuasiStatic,
        ..SolverConfig::default()
    };
    let size = Vec3::new(HALF_WIDTH_RADII * a, HALF_WIDTH_RADII * a, DEPTH_RADII * a);
    let across = (HALF_WIDTH_RADII as usize) * spacings + 1;
    let mut body = box_body(size, across, &material, 2.0, config);
    for i in body.face(2, -1.0) {
        body.solver.fix(i, [true; 3]);
    }
    for i in body.face(0, -1.0) {
        body.solver.fix(i, [true, false, false]);
    }
    for i in body.face(1, -1.0) {
        body.solver.fix(i, [false, true, false]);
    }
    let corner = Vec3::new(-0.5 * size.x, -0.5 * size.y, 0.5 * size.z);
    let spec = ProbeSpec {
        at: Some(corner),
        axis: Some(-Vec3::z()),
        radius_m: a,
        blade: None,
        depth_m: INDENTATION * a,
        // Linear at 2 % of the radius: one solve, the secant is the stiffness.
        steps: 1,
    };
    let plane = material.youngs_modulus_pa / (1.0 - material.poisson_ratio.powi(2));
    press(
        &body.model,
        &body.model.surface,
        &mut body.solver,
        &spec,
        plane,
        0.25,
    )
    .expect("the punch is over the block")
}

/// B14: the block's stiffness within 5 % of the block's 3D reference at 3 spacings to the
/// radius, and within 5 % of the same run at half the spacing; the half-space is reported.
pub fn b14_flat_punch() -> BenchmarkResult {
    let coarse = punch_on_block(3);
    let fine = punch_on_block(6);
    let half_space = coarse.analytic_n_per_mm.expect("a punch");
    let against_reference = coarse.secant_n_per_mm / PUNCH_BLOCK_3D_N_PER_MM - 1.0;
    let convergence = coarse.secant_n_per_mm / fine.secant_n_per_mm - 1.0;
    let error = (against_reference.abs() / 0.05).max(convergence.abs() / 0.05);
    BenchmarkResult::new(
        "B14",
        "flat punch on a block: stiffness against the block's 3D reference, and at half the spacing",
        error,
        1.0,
        format!(
            "a = {:.0} mm, indentation {:.2} %: 3 spacings {:.4} N/mm, 6 spacings {:.4} N/mm, \
             3D reference {:.4} N/mm, half-space {:.4} N/mm; {:+.1} % (6 spacings {:+.1} %) \
             against the reference (band 5 %), {:+.1} % against the finer run (band 5 %), \
             {:+.1} % against the half-space; penalty give {:.2} % of the press; error is the \
             larger share of its band",
            PUNCH_RADIUS_M * 1e3,
            INDENTATION * 100.0,
            coarse.secant_n_per_mm,
            fine.secant_n_per_mm,
            PUNCH_BLOCK_3D_N_PER_MM,
            half_space,
            100.0 * against_reference,
            100.0 * (fine.secant_n_per_mm / PUNCH_BLOCK_3D_N_PER_MM - 1.0),
            100.0 * convergence,
            100.0 * (coarse.secant_n_per_mm / half_space - 1.0),
            100.0 * coarse.max_penetration_mm / coarse.depth_mm,
        ),
    )
}
