//! `scalpel probe`: a flat cylindrical punch pressed quasi-statically into the supported
//! body (cutting-physics.md §2, §6). Material samples of the surface under the punch's
//! face follow the points through the surface's own map (first-order rows); the face pushes
//! them out with stiff one-sided penalties (`solver::contact`); each depth is a static
//! solve; the force is what the tissue puts back on the punch.

use serde::Serialize;

use crate::geometry::TriMesh;
use crate::geometry::predicates::{closest_point_on_triangle, line_triangle};
use crate::math::Vec3;
use crate::model::{CoupledModel, SurfaceEmbedding};
use crate::scene::BuiltScene;
use crate::solver::Solver;
use crate::solver::contact::{Tool, ToolContact, ToolShape};
use crate::solver::embedded::EmbeddedRows;

/// The penalty per area, as a multiple of E / spacing: a patch of the face is this many
/// times stiffer than the tissue under it, so the penalty gives a few % of the press
/// before the augmented-Lagrangian rounds take that out (`max_penetration_mm` reports
/// what is left).
const PENALTY_PER_E_OVER_SPACING: f64 = 100.0;

/// The penalty's give left after the augmented-Lagrangian rounds, as a fraction of the
/// depth, and the most rounds a depth gets.
const GIVE: f64 = 1e-2;
const GIVE_ROUNDS: usize = 8;

/// What to press, where and how far.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeSpec {
    /// A point near the surface to press at (m); `None` for the top of the body above the
    /// middle of its bounding box.
    pub at: Option<Vec3>,
    /// Direction to press (unit, into the body); `None` for along the surface's mean
    /// inward normal under the face.
    pub axis: Option<Vec3>,
    /// Punch radius (m).
    pub radius_m: f64,
    /// Press a blade of this shape, edge first, instead of the punch.
    pub blade: Option<ToolShape>,
    /// Final depth past the surface (m).
    pub depth_m: f64,
    /// Static solves on the way down (the last two give the tangent stiffness; with one,
    /// it is the secant).
    pub steps: u32,
}

impl Default for ProbeSpec {
    fn default() -> Self {
        Self {
            at: None,
            axis: None,
            radius_m: 0.005,
            blade: None,
            depth_m: 0.003,
            steps: 6,
        }
    }
}

/// Force at one depth on the way down.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ProbePoint {
    /// Depth past the surface (mm).
    pub depth_mm: f64,
    /// The tissue's push back along the press (N).
    pub force_n: f64,
}

/// What a probe measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ProbeReport {
    /// Where the face's centre met the surface (mm).
    pub at_mm: [f64; 3],
    /// Unit direction of the press (into the body).
    pub axis: [f64; 3],
    /// Punch radius (mm; none for a blade).
    pub radius_mm: Option<f64>,
    /// Final depth (mm).
    pub depth_mm: f64,
    /// The tissue's push back along the press at the final depth (N).
    pub force_n: f64,
    /// The whole force on the punch (N): sideways parts where the surface is sloped.
    pub force_vector_n: [f64; 3],
    /// Tangent stiffness at the final depth, from the last step (N/mm).
    pub stiffness_n_per_mm: f64,
    /// Force over depth (N/mm).
    pub secant_n_per_mm: f64,
    /// A rigid flat punch on an elastic half-space, 2aE/(1 − ν²) (N/mm; none for a blade).
    pub analytic_n_per_mm: Option<f64>,
    /// The tool pressed (sizes in m).
    pub tool: ToolShape,
    /// Samples touching the face at the final depth, and in all.
    pub contact_points: usize,
    /// Surface samples under the face.
    pub samples: usize,
    /// The deepest a sample is inside the face (mm): the penalty's give.
    pub max_penetration_mm: f64,
    /// 1 − the smallest det F of any point at the final depth.
    pub max_det_f_loss: f64,
    /// Force on the way down.
    pub curve: Vec<ProbePoint>,
    /// Every step's static solve converged.
    pub converged: bool,
    /// Newton iterations over all steps.
    pub newton_iterations: u32,
    /// Conjugate-gradient iterations over all steps.
    pub cg_iterations: u32,
    /// The last solve's residual force (N).
    pub residual_n: f64,
}

/// Why a probe could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProbeError {
    /// The press line misses the body.
    #[error("the press at {0:?} mm misses the body: give --at a point on or near its surface")]
    MissesBody([f64; 3]),
    /// Nothing of the surface is under the tool.
    #[error("no surface under the tool there")]
    NothingUnder,
    /// A non-positive or non-finite size.
    #[error("{0} must be positive and finite, got {1}")]
    BadSize(&'static str, f64),
}

/// Presses a punch into `scene`'s body on its supports, from where it rests under its
/// gravity.
pub fn probe(scene: &BuiltScene, spec: &ProbeSpec) -> Result<ProbeReport, ProbeError> {
    let model = &scene.model;
    let (mut solver, _) = super::supports::held_solver(scene, &model.neighbours, 0);
    if let Some(start) = super::supports::start_state(scene) {
        solver.set_positions(&start.positions);
    }
    let surface = super::supports::start_surface(scene);
    let material = &scene.spec.material;
    let modulus = material.youngs_modulus_pa;
    let plane_modulus = modulus / (1.0 - material.poisson_ratio.powi(2));
    press(model, &surface, &mut solver, spec, plane_modulus, 1.0)
}

/// Presses a punch into `model`'s body, whose surface stands at `surface` with the points
/// where `solver` has them; the half-space reference uses `plane_modulus` = E/(1 − ν²).
/// `share` is the fraction of the punch the body is (¼ for a quarter model under symmetry):
/// forces are divided by it.
pub fn press(
    model: &CoupledModel,
    surface: &TriMesh,
    solver: &mut Solver,
    spec: &ProbeSpec,
    plane_modulus: f64,
    share: f64,
) -> Result<ProbeReport, ProbeError> {
    for (what, x) in [("radius", spec.radius_m), ("depth", spec.depth_m)] {
        if !(x.is_finite() && x > 0.0) {
            return Err(ProbeError::BadSize(what, x));
        }
    }
    let (centre, axis) = aim(surface, spec)?;
    let punch = match spec.blade {
        None => Tool::flat_punch(centre, axis, spec.radius_m),
        Some(shape) => {
            // The edge along the scene's x, as the default strokes run (y if pressing
            // along x).
            let x = if axis.x.abs() < 0.9 {
                Vec3::x()
            } else {
                Vec3::y()
            };
            Tool {
                along: (x - axis * axis.dot(&x)).normalize(),
                shape,
                ..Tool::flat_punch(centre, axis, spec.radius_m)
            }
        }
    };
    let spacing = model.lattice.spacing;
    let mut contact = face_samples(model, surface, solver, &punch, plane_modulus, spacing);
    contact.touch_down(solver.positions());
    let centre = contact.tool().centre;
    if contact.is_empty() {
        return Err(ProbeError::NothingUnder);
    }
    let samples = contact.len();
    solver.press(Some(contact));
    let steps = spec.steps.max(1);
    let mut curve = Vec::with_capacity(steps as usize + 1);
    let (mut converged, mut newton, mut cg, mut residual) = (true, 0, 0, 0.0);
    curve.push(ProbePoint {
        depth_mm: 0.0,
        force_n: 0.0,
    });
    let mut force = Vec3::zeros();
    for step in 1..=steps {
        let depth = spec.depth_m * f64::from(step) / f64::from(steps);
        solver.contact_mut().expect("pressed").set_depth(depth);
        // Static solves until the penalty's give is under GIVE of the depth (Uzawa).
        for round in 0..GIVE_ROUNDS {
            let report = solver.solve_static();
            converged &= report.converged;
            newton += report.newton_iterations;
            cg += report.cg_iterations;
            residual = report.residual_n;
            let contact = solver.contact().expect("pressed");
            if contact.max_penetration(solver.positions()) <= GIVE * depth
                || round + 1 == GIVE_ROUNDS
            {
                break;
            }
            solver.absorb_contact_give();
        }
        force = solver
            .contact()
            .expect("pressed")
            .on_tool(solver.positions())
            / share;
        curve.push(ProbePoint {
            depth_mm: depth * 1e3,
            force_n: -force.dot(&axis),
        });
    }
    let contact = solver.contact().expect("pressed");
    let p = solver.positions();
    let [.., before, last] = curve[..] else {
        unreachable!("the unloaded start and at least one step")
    };
    let min_det_f = (0..solver.material_points())
        .map(|k| solver.deformation_gradient(k).determinant())
        .fold(f64::INFINITY, f64::min);
    let report = ProbeReport {
        at_mm: (centre * 1e3).into(),
        axis: axis.into(),
        radius_mm: spec.blade.is_none().then_some(spec.radius_m * 1e3),
        depth_mm: spec.depth_m * 1e3,
        force_n: last.force_n,
        force_vector_n: force.into(),
        stiffness_n_per_mm: (last.force_n - before.force_n) / (last.depth_mm - before.depth_mm),
        secant_n_per_mm: last.force_n / last.depth_mm,
        analytic_n_per_mm: spec
            .blade
            .is_none()
            .then_some(2.0 * spec.radius_m * plane_modulus * 1e-3),
        tool: contact.tool().shape,
        contact_points: contact.touching(p),
        samples,
        max_penetration_mm: contact.max_penetration(p) * 1e3,
        max_det_f_loss: 1.0 - min_det_f,
        curve,
        converged,
        newton_iterations: newton,
        cg_iterations: cg,
        residual_n: residual,
    };
    solver.press(None);
    Ok(report)
}

/// Where the face's centre meets the surface and the direction to press: into the body
/// along the surface's mean normal under the face.
fn aim(surface: &TriMesh, spec: &ProbeSpec) -> Result<(Vec3, Vec3), ProbeError> {
    let bbox = surface.bbox();
    let (lo, hi) = (Vec3::from(bbox.min), Vec3::from(bbox.max));
    let reach = (hi - lo).norm();
    // The point the face's centre meets, and the triangle it is on.
    let (centre, on) = match spec.at {
        Some(at) => (0..surface.triangles.len())
            .map(|t| (closest_point_on_triangle(&at, &surface.corners(t)), t))
            .min_by(|a, b| {
                (a.0 - at)
                    .norm_squared()
                    .total_cmp(&(b.0 - at).norm_squared())
            })
            .filter(|(x, _)| (x - at).norm() <= reach)
            .ok_or(ProbeError::MissesBody((at * 1e3).into()))?,
        None => {
            let mid = (lo + hi) * 0.5;
            let top = Vec3::new(mid.x, mid.y, hi.z + reach);
            let (x, t, _) = first_hit(surface, &top, &-Vec3::z())
                .ok_or(ProbeError::MissesBody((mid * 1e3).into()))?;
            (x, t)
        }
    };
    if let Some(axis) = spec.axis {
        return Ok((centre, axis.normalize()));
    }
    let mut normal = Vec3::zeros();
    for t in 0..surface.triangles.len() {
        let c = surface.corners(t);
        if ((c[0] + c[1] + c[2]) / 3.0 - centre).norm() <= spec.radius_m {
            normal += surface.doubled_area_normal(t);
        }
    }
    if normal == Vec3::zeros() {
        // A face smaller than the triangles: the normal of the one it meets.
        normal = surface.doubled_area_normal(on);
    }
    Ok((centre, -normal.normalize()))
}

/// The first place the ray from `origin` along `dir` enters the surface: the point, its
/// triangle and barycentrics.
fn first_hit(surface: &TriMesh, origin: &Vec3, dir: &Vec3) -> Option<(Vec3, usize, [f64; 3])> {
    (0..surface.triangles.len())
        .filter_map(|t| {
            line_triangle(origin, dir, &surface.corners(t))
                .filter(|(s, _)| *s >= 0.0)
                .map(|(s, b)| (s, t, b))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(s, t, b)| (origin + dir * s, t, b))
}

/// The surface under the tool, each sample following the points by the surface's
/// first-order map at its rest place, with a penalty of [`PENALTY_PER_E_OVER_SPACING`] ×
/// E/h times its area. Under a punch: the centres of a square grid's cells over the disc
/// (so a quarter model gets exactly a quarter of them). Under a blade: rows along the
/// edge, one under it and more beside it out to 3 mm, for the flats.
fn face_samples(
    model: &CoupledModel,
    surface: &TriMesh,
    solver: &Solver,
    punch: &Tool,
    plane_modulus: f64,
    spacing: f64,
) -> ToolContact {
    let (u, w) = (punch.along, punch.axis.cross(&punch.along));
    // (offset along u, offset along w, area) of each sample's column.
    let mut grid: Vec<(f64, f64, f64)> = Vec::new();
    match punch.shape {
        ToolShape::Punch { radius } => {
            let cell = (radius / 6.0).min(0.5 * spacing);
            let across = (radius / cell).ceil() as i64;
            for i in -across..across {
                for j in -across..across {
                    let (a, b) = ((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell);
                    if a * a + b * b <= radius * radius {
                        grid.push((a, b, cell * cell));
                    }
                }
            }
        }
        ToolShape::Blade { length, .. } => {
            let along = (length / 12.0).min(0.5 * spacing);
            let beside = (0.25 * spacing).min(1e-3);
            let rows = (3e-3 / beside).ceil() as i64;
            let n = (length / along).round() as i64;
            for i in 0..n {
                for j in -rows..=rows {
                    let a = (i as f64 + 0.5) * along - 0.5 * length;
                    grid.push((a, j as f64 * beside, along * beside));
                }
            }
        }
    }
    let reach = (Vec3::from(surface.bbox().max) - Vec3::from(surface.bbox().min)).norm();
    let mut row = Vec::new();
    let mut rows: Vec<(Vec<(u32, f64)>, Vec3)> = Vec::new();
    let mut stiffness = Vec::new();
    let per_area = PENALTY_PER_E_OVER_SPACING * plane_modulus / spacing;
    for (a, b, area) in grid {
        let from = punch.centre + u * a + w * b - punch.axis * reach;
        let Some((_, tri, bary)) = first_hit(surface, &from, &punch.axis) else {
            continue;
        };
        let [p, q, r] = model.surface.triangles[tri];
        let rest = &model.surface.positions;
        let x =
            rest[p as usize] * bary[0] + rest[q as usize] * bary[1] + rest[r as usize] * bary[2];
        let zero = SurfaceEmbedding::sample_row(&x, &model.points.rest, &model.grid, &model.kernel);
        solver
            .operator()
            .linear_row(&zero, &x, solver.rest(), &mut row);
        rows.push((row.clone(), x));
        stiffness.push(per_area * area);
    }
    let samples = EmbeddedRows::new(rows.iter().map(|(r, x)| (&r[..], *x)), solver.rest());
    ToolContact::new(samples, stiffness, *punch)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Mat3;
    use crate::scene::Material;
    use crate::solver::SolverConfig;
    use crate::validate::box_body;

    /// A sample follows a linear field exactly: the first-order rows reproduce it.
    #[test]
    fn samples_follow_a_linear_field() {
        let size = Vec3::new(0.02, 0.02, 0.02);
        let body = box_body(size, 5, &Material::LIVER, 2.0, SolverConfig::default());
        let punch = Tool::flat_punch(Vec3::new(0.0, 0.0, 0.01), -Vec3::z(), 0.004);
        let contact = face_samples(
            &body.model,
            &body.model.surface,
            &body.solver,
            &punch,
            5e3,
            body.model.lattice.spacing,
        );
        assert!(contact.len() > 10);
        let g = Mat3::new(0.01, 0.02, -0.03, 0.0, 0.015, 0.01, 0.02, -0.01, -0.02);
        let p: Vec<Vec3> = body.solver.rest().iter().map(|x| x + g * x).collect();
        for s in 0..contact.len() {
            let x0 = contact.sample_position(s, body.solver.rest());
            let x = contact.sample_position(s, &p);
            assert!(
                (x - (x0 + g * x0)).norm() < 1e-9,
                "{s}: {x} vs {}",
                x0 + g * x0
            );
        }
    }

    /// Pressed into a block on a fixed base, the tool gets exactly what the tissue gets,
    /// reversed: the reaction on the punch plus the forces on the points sum to zero.
    #[test]
    fn the_tool_gets_what_the_tissue_gets_reversed() {
        let size = Vec3::new(0.03, 0.03, 0.02);
        let mut body = box_body(size, 7, &Material::LIVER, 2.0, SolverConfig::default());
        for i in body.face(2, -1.0) {
            body.solver.fix(i, [true; 3]);
        }
        let punch = Tool::flat_punch(
            Vec3::new(0.002, -0.001, 0.01),
            Vec3::new(0.3, 0.0, -1.0).normalize(),
            0.006,
        );
        let spacing = body.model.lattice.spacing;
        let mut contact = face_samples(
            &body.model,
            &body.model.surface,
            &body.solver,
            &punch,
            5e3,
            spacing,
        );
        contact.touch_down(body.solver.positions());
        contact.set_depth(0.002);
        body.solver.press(Some(contact));
        assert!(body.solver.solve_static().converged);
        let contact = body.solver.contact().unwrap();
        let p = body.solver.positions();
        let mut on_points = vec![Vec3::zeros(); p.len()];
        contact.forces(p, &mut on_points);
        let tissue: Vec3 = on_points.iter().sum();
        let tool = contact.on_tool(p);
        assert!(tool.norm() > 0.01 && tool.x.abs() > 1e-4, "{tool}");
        assert!(
            (tissue + tool).norm() <= 1e-9 * tool.norm(),
            "tissue {tissue}, tool {tool}"
        );
    }
}
