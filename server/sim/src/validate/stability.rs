//! The stiff and extreme cases of physics.md §9, shared by the tests and
//! `scalpel bench stability`. Each case runs a small body through the solver and reports
//! whether it stayed stable, how far its energy rose above what was put in, the smallest
//! det F, the guard's rollbacks, and whether anything non-finite appeared.

use serde::Serialize;

use super::bodies::{BoxBody, box_body};
use super::cases::cut_plane;

use crate::math::Vec3;
use crate::mls::{ElasticModel, PointRank};
use crate::scene::Material;
use crate::solver::{SolverConfig, SolverEvent, SolverMode};

/// The outcome of one stability case.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StabilityResult {
    /// Case name.
    pub name: &'static str,
    /// No divergence, no NaN, energy bounded by what was put in (and the case's own check).
    pub stable: bool,
    /// Largest (kinetic + elastic energy) / (initial energy + work put in).
    pub max_energy_ratio: f64,
    /// Smallest det F seen.
    pub min_det_f: f64,
    /// Guard rollbacks.
    pub rollbacks: u32,
    /// A non-finite position appeared (never expected).
    pub nan: bool,
    /// The case's own figures.
    pub detail: String,
}

/// Total energy may exceed what was put in by this factor before a run counts as unstable.
/// Symplectic Euler's measured energy (kinetic after the update, elastic before it)
/// oscillates by O(ω dt) in the fastest modes, up to ~25 % for a perturbation of a tiny
/// lattice; a real blow-up grows exponentially. The guard uses the same factor.
const ENERGY_BOUND: f64 = 1.5;

/// What a run of ticks observed.
struct Observed {
    max_energy_ratio: f64,
    min_det_f: f64,
    rollbacks: u32,
    first_detection: Option<u32>,
    diverged: bool,
    nan: bool,
    /// Solver iterations over the run (CG or local/global; 0 for explicit).
    iterations: u64,
}

impl Observed {
    fn bounded(&self, limit: f64) -> bool {
        !self.diverged && !self.nan && self.max_energy_ratio <= limit
    }
}

/// Runs `ticks` ticks of `dt`, calling `drive` before each, and watches energy and events.
fn run(
    body: &mut BoxBody,
    ticks: usize,
    dt: f64,
    mut drive: impl FnMut(&mut BoxBody, usize),
) -> Observed {
    let (_, stats) = body.solver.elastic_forces();
    let initial = stats.energy() + body.solver.kinetic_energy();
    let mut obs = Observed {
        max_energy_ratio: 0.0,
        min_det_f: stats.min_det_f,
        rollbacks: 0,
        first_detection: None,
        diverged: false,
        nan: false,
        iterations: 0,
    };
    let mut work = 0.0;
    for t in 0..ticks {
        drive(body, t);
        let r = body.solver.step(dt);
        while let Some(e) = body.solver.poll_event() {
            match e {
                SolverEvent::Rollback {
                    detected_at_substep,
                    ..
                } => {
                    obs.rollbacks += 1;
                    obs.first_detection.get_or_insert(detected_at_substep);
                }
                SolverEvent::Diverged { .. } => obs.diverged = true,
                _ => {}
            }
        }
        work += r.work_j;
        obs.iterations += u64::from(r.iterations);
        let energy = r.kinetic_energy + r.elastic_energy;
        obs.max_energy_ratio = obs
            .max_energy_ratio
            .max(energy / (initial + work).max(1e-15));
        if r.min_det_f.is_finite() {
            obs.min_det_f = obs.min_det_f.min(r.min_det_f);
        }
        obs.nan |= !body
            .solver
            .positions()
            .iter()
            .all(|p| p.iter().all(|x| x.is_finite()));
    }
    obs
}

fn result(name: &'static str, obs: &Observed, stable: bool, detail: String) -> StabilityResult {
    StabilityResult {
        name,
        stable,
        max_energy_ratio: obs.max_energy_ratio,
        min_det_f: obs.min_det_f,
        rollbacks: obs.rollbacks,
        nan: obs.nan,
        detail,
    }
}

/// A cube of `n`³ points at spacing `s` (m).
fn cube(n: usize, s: f64, material: &Material, config: SolverConfig) -> BoxBody {
    box_body(Vec3::repeat(s * (n - 1) as f64), n, material, 2.0, config)
}

/// Adds a deterministic random displacement of `amplitude` lattice spacings to every point.
fn perturb(body: &mut BoxBody, amplitude: f64) {
    let s = body.model.lattice.spacing;
    let mut seed = 99u64;
    let mut rnd = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    };
    let p: Vec<Vec3> = body
        .model
        .points
        .rest
        .iter()
        .map(|x| x + Vec3::new(rnd(), rnd(), rnd()) * (amplitude * s))
        .collect();
    body.solver.set_positions(&p);
}

fn material(e: f64, nu: f64, damping: f64) -> Material {
    Material {
        youngs_modulus_pa: e,
        poisson_ratio: nu,
        density_kg_m3: 1060.0,
        damping_per_s: damping,
        ..Material::LIVER
    }
}

fn mode(mode: SolverMode) -> SolverConfig {
    SolverConfig {
        mode,
        ..SolverConfig::default()
    }
}

/// Ticks of 1 ms a stiff case runs.
const STIFF_TICKS: usize = 100;

/// A stiff or near-incompressible block, 2 % random perturbation, 100 ticks of 1 ms.
fn stiff_case(name: &'static str, e: f64, nu: f64, solver: SolverMode) -> StabilityResult {
    let mut body = cube(8, 0.003, &material(e, nu, 10.0), mode(solver));
    perturb(&mut body, 0.02);
    let dt_crit = body.solver.dt_crit();
    let obs = run(&mut body, STIFF_TICKS, 1e-3, |_, _| {});
    let substeps = body.solver.substeps();
    let detail = match solver {
        SolverMode::Explicit => format!(
            "8³ points, s = 3 mm: dt_crit = {:.1} µs, {substeps} sub-steps per 1 ms tick",
            dt_crit * 1e6
        ),
        SolverMode::Implicit => format!(
            "8³ points, s = 3 mm, 1 ms ticks, {:.1} CG iterations per tick (explicit would need dt_crit = {:.1} µs)",
            obs.iterations as f64 / STIFF_TICKS as f64,
            dt_crit * 1e6
        ),
        _ => format!(
            "8³ points, s = 3 mm, 1 ms ticks, {} local/global iterations (explicit would need dt_crit = {:.1} µs)",
            body.solver.config().projective_iterations,
            dt_crit * 1e6
        ),
    };
    result(name, &obs, obs.bounded(ENERGY_BOUND), detail)
}

/// E = 1 MPa with explicit sub-stepping.
pub fn stiff_explicit() -> StabilityResult {
    stiff_case("E = 1 MPa, explicit", 1e6, 0.45, SolverMode::Explicit)
}

/// E = 1 MPa in the stiff (projective) mode at 1 ms.
pub fn stiff_projective() -> StabilityResult {
    stiff_case(
        "E = 1 MPa, projective, 1 ms",
        1e6,
        0.45,
        SolverMode::Projective,
    )
}

/// E = 1 MPa, implicit (its default preconditioner) at 1 ms.
pub fn stiff_implicit() -> StabilityResult {
    stiff_case("E = 1 MPa, implicit, 1 ms", 1e6, 0.45, SolverMode::Implicit)
}

/// E = 1 MPa and ν = 0.499 together, implicit at 1 ms.
pub fn stiff_incompressible_implicit() -> StabilityResult {
    stiff_case(
        "E = 1 MPa, ν = 0.499, implicit, 1 ms",
        1e6,
        0.499,
        SolverMode::Implicit,
    )
}

/// ν = 0.49, explicit.
pub fn nu_049_explicit() -> StabilityResult {
    stiff_case("ν = 0.49, explicit", 5e3, 0.49, SolverMode::Explicit)
}

/// ν = 0.499, explicit.
pub fn nu_0499_explicit() -> StabilityResult {
    stiff_case("ν = 0.499, explicit", 5e3, 0.499, SolverMode::Explicit)
}

/// E = 1 MPa and ν = 0.499 together, projective at 1 ms.
pub fn stiff_incompressible_projective() -> StabilityResult {
    stiff_case(
        "E = 1 MPa, ν = 0.499, projective, 1 ms",
        1e6,
        0.499,
        SolverMode::Projective,
    )
}

/// An explicit step ten times dt_crit: the guard must detect the blow-up within the first
/// sub-steps, roll back and halve the step until it is stable.
pub fn huge_time_step() -> StabilityResult {
    let mat = material(5e3, 0.45, 10.0);
    let dt_crit = cube(8, 0.003, &mat, SolverConfig::default())
        .solver
        .dt_crit();
    let config = SolverConfig {
        dt_override_s: Some(10.0 * dt_crit),
        ..SolverConfig::default()
    };
    let mut body = cube(8, 0.003, &mat, config);
    perturb(&mut body, 0.02);
    let tick = 10.0 * dt_crit;
    let obs = run(&mut body, 30, tick, |_, _| {});
    let substeps = body.solver.substeps();
    let detected = obs.first_detection.map_or(u32::MAX, |s| s + 1);
    let stable = obs.bounded(ENERGY_BOUND) && obs.rollbacks > 0 && detected < 10;
    result(
        "dt = 10 dt_crit, explicit",
        &obs,
        stable,
        format!(
            "ticks of 10 dt_crit = {:.2} ms: blow-up detected in sub-step {detected}, {} rollbacks, now {substeps} sub-steps per tick ({:.2} dt_crit each)",
            tick * 1e3,
            obs.rollbacks,
            10.0 / substeps as f64
        ),
    )
}

/// A body rotated by 180° stays at rest: no spurious stress.
pub fn rotated_180() -> StabilityResult {
    let mut body = cube(
        6,
        0.003,
        &material(5e3, 0.45, 10.0),
        SolverConfig::default(),
    );
    let r = nalgebra::Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(Vec3::new(1.0, 1.0, 0.0)),
        std::f64::consts::PI,
    );
    let p: Vec<Vec3> = body.model.points.rest.iter().map(|x| r * x).collect();
    body.solver.set_positions(&p);
    let (f, stats) = body.solver.elastic_forces();
    let force = f.iter().map(|x| x.norm()).fold(0.0, f64::max);
    let energy = stats.energy();
    let obs = run(&mut body, 50, 1e-3, |_, _| {});
    let moved = body
        .solver
        .positions()
        .iter()
        .zip(&p)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let s = body.model.lattice.spacing;
    let stable = !obs.diverged && !obs.nan && moved < 1e-9 * s;
    result(
        "rotation by 180°",
        &obs,
        stable,
        format!(
            "elastic energy {energy:.1e} J, max force {force:.1e} N, max drift after 50 ticks {:.1e} spacings",
            moved / s
        ),
    )
}

/// A free body spinning at 10 rad/s, undamped: energy stays put (only the physical
/// centrifugal stretch exchanges kinetic and elastic energy).
pub fn spinning() -> StabilityResult {
    let config = SolverConfig {
        damping_per_s: 0.0,
        ..SolverConfig::default()
    };
    let mut body = cube(6, 0.003, &material(5e3, 0.45, 0.0), config);
    let omega = Vec3::new(0.0, 0.0, 10.0);
    let v: Vec<Vec3> = body
        .model
        .points
        .rest
        .iter()
        .map(|x| omega.cross(x))
        .collect();
    body.solver.set_velocities(&v);
    let obs = run(&mut body, 630, 1e-3, |_, _| {});
    result(
        "spin at 10 rad/s, undamped",
        &obs,
        obs.bounded(1.05),
        format!(
            "one full turn (630 ticks); max elastic/kinetic exchange within {:.2} %",
            100.0 * (obs.max_energy_ratio - 1.0)
        ),
    )
}

/// Squash a cube to 30 % of its height between plates, hold, release. Corotated recovers
/// with det F > 0; StVK is the negative control of physics.md §9.
fn compression(
    name: &'static str,
    model: ElasticModel,
    clamp_inversion: bool,
    stiffening: f64,
) -> StabilityResult {
    let config = SolverConfig {
        model,
        clamp_inversion,
        stiffening,
        ..SolverConfig::default()
    };
    let mut body = cube(7, 0.003, &material(5e3, 0.45, 20.0), config);
    let bottom = body.face(2, -1.0);
    let top = body.face(2, 1.0);
    for &i in &bottom {
        body.solver.fix(i, [false, false, true]);
    }
    // Stop the bottom from sliding away as a whole.
    let centre = bottom
        .iter()
        .copied()
        .min_by(|&a, &b| {
            body.model.points.rest[a]
                .norm()
                .total_cmp(&body.model.points.rest[b].norm())
        })
        .expect("bottom face");
    body.solver.fix(centre, [true; 3]);
    for &i in &top {
        body.solver.fix(i, [false, false, true]);
    }
    let height = body.size.z;
    let z_top = 0.5 * height;
    let press = 300;
    let hold = 100;
    let release = 500;
    let mut min_det_squeezed = f64::INFINITY;
    let obs = run(&mut body, press + hold + release, 1e-3, |b, t| {
        if t < press {
            let z = z_top - 0.7 * height * (t + 1) as f64 / press as f64;
            for &i in &top {
                let mut target = b.solver.positions()[i];
                target.z = z;
                b.solver.set_target(i, target);
            }
        } else if t == press + hold {
            let (_, stats) = b.solver.elastic_forces();
            min_det_squeezed = stats.min_det_f;
            for &i in &top {
                b.solver.fix(i, [false; 3]);
            }
        }
    });
    let (_, stats) = body.solver.elastic_forces();
    let rest_height = body.size.z;
    let p = body.solver.positions();
    let final_height =
        top.iter().map(|&i| p[i].z).sum::<f64>() / top.len() as f64 + 0.5 * rest_height;
    let recovered = final_height / rest_height;
    let stable = !obs.diverged && !obs.nan && stats.min_det_f > 0.0 && recovered > 0.9;
    result(
        name,
        &obs,
        stable,
        format!(
            "7³ cube squashed to 30 % over 0.3 s, held, released: min det F {min_det_squeezed:.3} while squeezed, {:.3} after release; height recovered to {:.1} %",
            stats.min_det_f,
            100.0 * recovered
        ),
    )
}

/// Compression to 30 %, corotated.
pub fn compression_corotated() -> StabilityResult {
    compression(
        "compression to 30 %, corotated",
        ElasticModel::Corotated,
        true,
        0.0,
    )
}

/// Compression to 30 %, StVK with the guard's clamp fallback.
pub fn compression_stvk() -> StabilityResult {
    compression(
        "compression to 30 %, StVK + clamp fallback",
        ElasticModel::StVK,
        true,
        0.0,
    )
}

/// Compression to 30 %, StVK strain-stiffened (β = 10: the distortional tangent up to e² × 5
/// = 37 times the small-strain one), explicit: the sub-steps follow the stiffening.
pub fn compression_stiffened() -> StabilityResult {
    compression(
        "compression to 30 %, StVK stiffened (β = 10)",
        ElasticModel::StVK,
        true,
        10.0,
    )
}

/// Compression to 30 %, plain StVK without the fallback: the negative control of
/// physics.md §9 (StVK softens past 42 % compression and inverts).
pub fn compression_stvk_plain() -> StabilityResult {
    compression(
        "compression to 30 %, plain StVK (negative control)",
        ElasticModel::StVK,
        false,
        0.0,
    )
}

/// Tiny lattices: every point full rank, rigid motion exact, dynamics stable.
fn tiny(name: &'static str, n: usize) -> StabilityResult {
    let mut body = cube(
        n,
        0.003,
        &material(5e3, 0.45, 10.0),
        SolverConfig::default(),
    );
    let full = (0..body.model.points.len())
        .filter(|&i| matches!(body.solver.operator().point(i).rank, PointRank::Full))
        .count();
    let r = nalgebra::Rotation3::from_euler_angles(0.5, -1.2, 2.0);
    let p: Vec<Vec3> = body
        .model
        .points
        .rest
        .iter()
        .map(|x| r * x + Vec3::new(0.01, 0.0, 0.0))
        .collect();
    body.solver.set_positions(&p);
    let (f, _) = body.solver.elastic_forces();
    let rigid_force = f.iter().map(|x| x.norm()).fold(0.0, f64::max);
    perturb(&mut body, 0.05);
    let obs = run(&mut body, 200, 1e-3, |_, _| {});
    let all = body.model.points.len();
    let scale = 5e3 * 0.003 * 0.003;
    let stable = obs.bounded(ENERGY_BOUND) && full == all && rigid_force < 1e-9 * scale;
    result(
        name,
        &obs,
        stable,
        format!(
            "{full} of {all} points full rank; rigid motion force {:.1e} E s²",
            rigid_force / scale
        ),
    )
}

/// A 2×2×2 lattice.
pub fn lattice_2() -> StabilityResult {
    tiny("2×2×2 lattice", 2)
}

/// A 3×3×3 lattice.
pub fn lattice_3() -> StabilityResult {
    tiny("3×3×3 lattice", 3)
}

/// Cuts isolate a corner point: it becomes an orphan; no force spike, no NaN.
pub fn isolated_point() -> StabilityResult {
    let mut body = cube(
        5,
        0.003,
        &material(5e3, 0.45, 10.0),
        SolverConfig::default(),
    );
    let rest = body.model.points.rest.clone();
    let corner = (0..rest.len())
        .min_by(|&a, &b| {
            (rest[a].x + rest[a].y + rest[a].z).total_cmp(&(rest[b].x + rest[b].y + rest[b].z))
        })
        .expect("points");
    // Cut every pair that touches the corner point, on both sides.
    let mut neighbours = body.model.neighbours.clone();
    let mut changed: Vec<u32> = neighbours.of(corner).to_vec();
    for &j in &changed {
        neighbours.remove(corner, j);
        neighbours.remove(j as usize, corner as u32);
    }
    changed.push(corner as u32);
    body.solver.topology_changed(&changed, &neighbours);
    let orphan = matches!(body.solver.operator().point(corner).rank, PointRank::Orphan);
    perturb(&mut body, 0.05);
    let mut corner_force: f64 = 0.0;
    let obs = run(&mut body, 200, 1e-3, |b, _| {
        let (f, _) = b.solver.elastic_forces();
        corner_force = corner_force.max(f[corner].norm());
    });
    let stable = obs.bounded(ENERGY_BOUND) && orphan && corner_force == 0.0;
    result(
        "isolated point",
        &obs,
        stable,
        format!("corner point orphaned: {orphan}; largest force on it {corner_force:.1e} N"),
    )
}

/// A one-layer sliver cut off a face behaves as a membrane: no explosion.
pub fn sliver() -> StabilityResult {
    let mut body = cube(
        6,
        0.003,
        &material(5e3, 0.45, 10.0),
        SolverConfig::default(),
    );
    let rest = body.model.points.rest.clone();
    let s = body.model.lattice.spacing;
    let mut neighbours = body.model.neighbours.clone();
    let changed = cut_plane(&mut neighbours, &rest, 2, 0.5 * body.size.z - 0.5 * s);
    body.solver.topology_changed(&changed, &neighbours);
    let planar = (0..rest.len())
        .filter(|&i| {
            matches!(
                body.solver.operator().point(i).rank,
                PointRank::Planar { .. }
            )
        })
        .count();
    perturb(&mut body, 0.05);
    let obs = run(&mut body, 300, 1e-3, |_, _| {});
    result(
        "one-layer sliver",
        &obs,
        obs.bounded(ENERGY_BOUND) && planar > 0,
        format!("{planar} rank-2 points completed with the current normal"),
    )
}

/// Amplitude of the 2s-wavelength (checkerboard) pattern in the displacement.
fn checkerboard(body: &BoxBody) -> f64 {
    let rest = &body.model.points.rest;
    let p = body.solver.positions();
    let mut sum = Vec3::zeros();
    for (i, c) in body.model.points.lattice_coords.iter().enumerate() {
        let sign = if (c[0] + c[1] + c[2]) % 2 == 0 {
            1.0
        } else {
            -1.0
        };
        sum += (p[i] - rest[i]) * sign;
    }
    sum.norm() / rest.len() as f64
}

/// A point load on one node of a 12³ block, no damping: the checkerboard pattern, amplitude
/// early and late in the run, with hourglass α. Returns (early, late, observed).
fn point_load_run(alpha: f64) -> (f64, f64, Observed) {
    let config = SolverConfig {
        damping_per_s: 0.0,
        hourglass_alpha: alpha,
        ..SolverConfig::default()
    };
    let mut body = cube(12, 0.002, &material(5e3, 0.45, 0.0), config);
    let bottom = body.face(2, -1.0);
    for &i in &bottom {
        body.solver.fix(i, [true; 3]);
    }
    let top = body.face(2, 1.0);
    let rest = body.model.points.rest.clone();
    let node = *top
        .iter()
        .min_by(|&&a, &&b| {
            (rest[a].x.abs() + rest[a].y.abs()).total_cmp(&(rest[b].x.abs() + rest[b].y.abs()))
        })
        .expect("top face");
    body.solver
        .set_external_force(node, Vec3::new(0.0, 0.0, -2e-4));
    let ticks = 600;
    let mut early: f64 = 0.0;
    let mut late: f64 = 0.0;
    let obs = run(&mut body, ticks, 1e-3, |b, t| {
        let c = checkerboard(b);
        if t < ticks / 3 {
            early = early.max(c);
        } else if t >= 2 * ticks / 3 {
            late = late.max(c);
        }
    });
    (early, late, obs)
}

/// Point load without damping, α = 0.1: no checkerboard growth (α = 0 shown for contrast).
pub fn point_load_undamped() -> StabilityResult {
    let (early, late, obs) = point_load_run(0.1);
    let (early0, late0, _) = point_load_run(0.0);
    let stable = obs.bounded(1.2) && late <= 2.0 * early;
    result(
        "point load, no damping, α = 0.1",
        &obs,
        stable,
        format!(
            "12³ block, 0.2 mN on one node, 0.6 s: checkerboard amplitude {:.2e} → {:.2e} m (α = 0: {:.2e} → {:.2e} m)",
            early, late, early0, late0
        ),
    )
}

/// A stability case that can be run by name.
pub struct StabilityCase {
    /// Case name.
    pub name: &'static str,
    /// Whether the case is expected to be stable (false for negative controls).
    pub expect_stable: bool,
    /// Runs it.
    pub run: fn() -> StabilityResult,
}

/// Every case of physics.md §9, in order.
pub fn stability_cases() -> Vec<StabilityCase> {
    let case = |name, expect_stable, run| StabilityCase {
        name,
        expect_stable,
        run,
    };
    vec![
        case(
            "stiff_explicit",
            true,
            stiff_explicit as fn() -> StabilityResult,
        ),
        case("stiff_projective", true, stiff_projective),
        case("nu_0.49_explicit", true, nu_049_explicit),
        case("nu_0.499_explicit", true, nu_0499_explicit),
        case(
            "stiff_incompressible_projective",
            true,
            stiff_incompressible_projective,
        ),
        case("stiff_implicit", true, stiff_implicit),
        case(
            "stiff_incompressible_implicit",
            true,
            stiff_incompressible_implicit,
        ),
        case("huge_time_step", true, huge_time_step),
        case("rotation_180", true, rotated_180),
        case("spin", true, spinning),
        case("compression_corotated", true, compression_corotated),
        case("compression_stvk", true, compression_stvk),
        case("compression_stiffened", true, compression_stiffened),
        case("compression_stvk_plain", false, compression_stvk_plain),
        case("lattice_2", true, lattice_2),
        case("lattice_3", true, lattice_3),
        case("isolated_point", true, isolated_point),
        case("sliver", true, sliver),
        case("point_load_undamped", true, point_load_undamped),
    ]
}
