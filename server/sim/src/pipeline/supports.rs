//! The scene's supports put on the solver (cutting-physics.md §1), and settling a body
//! under gravity and its surface layer's tension before anything touches it.

use std::borrow::Cow;

use serde::Serialize;

use crate::geometry::TriMesh;
use crate::math::{Aabb, Vec3};
use crate::mls::Prestress;
use crate::model::{CoupledModel, Neighbourhoods, SurfaceEmbedding};
use crate::scene::supports::StartState;
use crate::scene::{BuiltScene, Material, SceneSpec};
use crate::solver::held::{Held, HeldVertex, TrayPlane};
use crate::solver::{Solver, SolverConfig};

/// How many of the body's supports took hold.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct SupportCounts {
    /// Points fixed at their rest places.
    pub fixed_points: usize,
    /// Surface vertices attached by springs.
    pub attached_vertices: usize,
    /// Surface samples that may touch the tray.
    pub tray_samples: usize,
}

/// The scene's solver with its supports: fixed points, attachments, tray (and gravity in
/// its configuration), over `neighbours` with `spare` spare nodes.
pub(super) fn held_solver(
    scene: &BuiltScene,
    neighbours: &Neighbourhoods,
    spare: usize,
) -> (Solver, SupportCounts) {
    let (spec, model) = (&scene.spec, &scene.model);
    let config = SolverConfig {
        gravity: spec.loads.gravity,
        ..SolverConfig::for_scene(&spec.features, &spec.material, &spec.solver)
    };
    let mut solver = if spare > 0 {
        Solver::for_model_with_spare_nodes(model, &spec.material, config, neighbours, spare)
    } else {
        Solver::for_model(model, &spec.material, config)
    };
    let counts = apply_supports(spec, model, &mut solver);
    solver.set_prestress(surface_prestress(&spec.material, model));
    (solver, counts)
}

/// The residual tension the scene's material puts in the model's surface layer (none
/// without `prestrain`).
pub fn surface_prestress(material: &Material, model: &CoupledModel) -> Prestress {
    if material.prestrain == 0.0 {
        return Prestress::default();
    }
    let sigma = Prestress::tension_pa(
        material.youngs_modulus_pa,
        material.poisson_ratio,
        material.prestrain,
    );
    let depth = material.prestrain_depth_m.unwrap_or(model.lattice.spacing);
    Prestress::surface_layer(&model.points.rest, &model.surface, depth, sigma)
}

/// Fixes the points in the scene's fixed regions and hands the attachments and the tray
/// to `solver` (the scene's build checked that each holds something).
fn apply_supports(spec: &SceneSpec, model: &CoupledModel, solver: &mut Solver) -> SupportCounts {
    let supports = &spec.supports;
    let surface = &model.surface;
    let body = Aabb::around(&surface.positions);
    let mut counts = SupportCounts::default();
    for region in &supports.fixed {
        for i in 0..model.points.len() {
            if region.contains(&model.points.rest[i], &body) {
                solver.fix(i, [true; 3]);
                counts.fixed_points += 1;
            }
        }
    }
    // A third of each incident triangle's area per vertex.
    let mut area = vec![0.0; surface.positions.len()];
    for (t, tri) in surface.triangles.iter().enumerate() {
        let third = surface.doubled_area_normal(t).norm() / 6.0;
        for &v in tri {
            area[v as usize] += third;
        }
    }
    let mut spring = vec![0.0; surface.positions.len()];
    for a in &supports.attachments {
        for (v, x) in surface.positions.iter().enumerate() {
            if a.region.contains(x, &body) {
                spring[v] += a.stiffness_pa_per_m * area[v];
                counts.attached_vertices += 1;
            }
        }
    }
    let tray = supports.tray.map(|t| {
        let normal = Vec3::from(t.normal);
        let lowest = surface
            .positions
            .iter()
            .map(|x| normal.dot(x))
            .fold(f64::INFINITY, f64::min);
        let plane = TrayPlane {
            normal,
            offset: t.point.map_or(lowest, |p| normal.dot(&Vec3::from(p))),
            friction: t.friction,
        };
        (plane, t.stiffness_pa_per_m)
    });
    let mut vertices = Vec::new();
    for (v, x) in surface.positions.iter().enumerate() {
        if spring[v] == 0.0 {
            continue;
        }
        let (points, weights) = model.embedding.of(v);
        vertices.push(HeldVertex {
            row: points
                .iter()
                .copied()
                .zip(weights.iter().copied())
                .collect(),
            rest: *x,
            spring_n_per_m: spring[v],
            tray_n_per_m: 0.0,
        });
    }
    if let Some((plane, stiffness)) = tray {
        let samples = tray_samples(model, &plane, stiffness);
        counts.tray_samples = samples.len();
        vertices.extend(samples);
    }
    if !vertices.is_empty() {
        solver.hold(Held::new(
            &vertices,
            &model.points.rest,
            tray.map(|(plane, _)| plane),
        ));
    }
    counts
}

/// How far from the tray its samples are taken, as a fraction of the body's thickness
/// across it.
const REACH: f64 = 0.25;

/// Samples of the surface that may touch the tray: the triangles within [`REACH`] of the
/// body's thickness across the tray of it and not facing away from it, sampled at the
/// lattice spacing, each following the points by its kernel row with the tray's stiffness times
/// its share of the area. The surface's own vertices are up to an edge apart (16 mm on the
/// liver), and the weight of the organ carried by a few of them crushed the points they
/// follow (det F < 0 at E = 2.5 kPa).
fn tray_samples(model: &CoupledModel, plane: &TrayPlane, stiffness: f64) -> Vec<HeldVertex> {
    let surface = &model.surface;
    let heights = surface.positions.iter().map(|x| plane.gap(x));
    let thickness = heights.fold(0.0, f64::max);
    let cell = model.lattice.spacing;
    let mut samples = Vec::new();
    for t in 0..surface.triangles.len() {
        let corners = surface.corners(t);
        let doubled = surface.doubled_area_normal(t);
        let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
        let facing = doubled.normalize().dot(&plane.normal);
        if plane.gap(&centroid) > REACH * thickness || facing > 0.5 {
            continue;
        }
        let longest = (0..3)
            .map(|i| (corners[(i + 1) % 3] - corners[i]).norm())
            .fold(0.0, f64::max);
        let n = (longest / cell).ceil().max(1.0) as usize;
        let area = 0.5 * doubled.norm() / (n * n) as f64;
        // The centroids of the n² triangles of a regular subdivision.
        let mut at = |a: f64, b: f64| {
            let x = corners[0] * (1.0 - a - b) + corners[1] * a + corners[2] * b;
            samples.push(HeldVertex {
                row: SurfaceEmbedding::sample_row(
                    &x,
                    &model.points.rest,
                    &model.grid,
                    &model.kernel,
                ),
                rest: x,
                spring_n_per_m: 0.0,
                tray_n_per_m: stiffness * area,
            });
        };
        let step = 1.0 / n as f64;
        for i in 0..n {
            for j in 0..n - i {
                at((i as f64 + 1.0 / 3.0) * step, (j as f64 + 1.0 / 3.0) * step);
                if i + j + 1 < n {
                    at((i as f64 + 2.0 / 3.0) * step, (j as f64 + 2.0 / 3.0) * step);
                }
            }
        }
    }
    samples
}

pub use crate::scene::supports::SettleReport;

/// A body is at rest when no point moves faster than this (m/s) for [`CALM_TICKS`].
const REST_SPEED: f64 = 1e-4;
const CALM_TICKS: u32 = 100;

/// The report of a settle that moved the body's `n` points from `start` to where `solver`
/// has them: the mean move along `gravity` and the largest, and the tray samples on the
/// tray.
fn moved_by(solver: &Solver, start: &[Vec3], gravity: Vec3) -> SettleReport {
    let p = &solver.positions()[..start.len()];
    let down = gravity.try_normalize(0.0).unwrap_or(Vec3::zeros());
    let n = start.len().max(1) as f64;
    SettleReport {
        sag_mm: 1e3
            * p.iter()
                .zip(start)
                .map(|(x, x0)| (x - x0).dot(&down))
                .sum::<f64>()
            / n,
        max_displacement_mm: 1e3
            * p.iter()
                .zip(start)
                .map(|(x, x0)| (x - x0).norm())
                .fold(0.0, f64::max),
        on_tray: solver.held().map_or(0, |h| h.on_tray(p)),
        settle_s: 0.0,
        residual_n: 0.0,
        settled: false,
        newton_iterations: 0,
    }
}

/// Steps `solver` with every point awake, `dt` at a time, until the body rests or
/// `max_s` has passed.
pub fn settle(solver: &mut Solver, gravity: Vec3, dt: f64, max_s: f64) -> SettleReport {
    let n = solver.material_points();
    let all: Vec<u32> = (0..n as u32).collect();
    solver.set_active(&all);
    let start = solver.positions()[..n].to_vec();
    let mut before = solver.velocities()[..n].to_vec();
    let (mut time, mut calm, mut residual) = (0.0, 0, f64::INFINITY);
    while time < max_s && calm < CALM_TICKS {
        solver.step(dt);
        time += dt;
        let v = &solver.velocities()[..n];
        let fastest = v.iter().map(|v| v.norm()).fold(0.0, f64::max);
        residual = (0..n)
            .map(|i| solver.masses()[i] * (v[i] - before[i]).norm() / dt)
            .fold(0.0, f64::max);
        before.copy_from_slice(v);
        calm = if fastest < REST_SPEED { calm + 1 } else { 0 };
    }
    SettleReport {
        settle_s: time,
        residual_n: residual,
        settled: calm >= CALM_TICKS,
        ..moved_by(solver, &start, gravity)
    }
}

/// Puts `solver`'s body into its static equilibrium under its gravity and supports, every
/// point awake (Newton with CG; the tray without friction, which a body also held by fixed
/// points or attachments does not need to stand still), and where that stalls (a tray's
/// contacts switching on and off) the rest of the way by letting it come to rest from
/// there: the state a scene starts from. `settle_s` is the dynamic finish's, if any.
pub fn settle_start(solver: &mut Solver, gravity: Vec3, dt: f64, max_s: f64) -> SettleReport {
    let n = solver.material_points();
    let all: Vec<u32> = (0..n as u32).collect();
    solver.set_active(&all);
    let start = solver.positions()[..n].to_vec();
    let statics = solver.solve_static();
    let (settle_s, residual_n, settled) = if statics.converged {
        (0.0, statics.residual_n, true)
    } else {
        let finish = settle(solver, gravity, dt, max_s);
        (finish.settle_s, finish.residual_n, finish.settled)
    };
    SettleReport {
        settle_s,
        residual_n,
        settled,
        newton_iterations: statics.newton_iterations,
        ..moved_by(solver, &start, gravity)
    }
}

/// Where the scene's body starts under gravity and its residual tension (`None` with
/// neither): settled the first time it is asked for and kept with the built scene, on a
/// solver of its own so that every simulation of the scene starts from the same state.
pub fn start_state(scene: &BuiltScene) -> Option<&StartState> {
    let gravity = scene.spec.loads.gravity;
    if gravity == Vec3::zeros() && scene.spec.material.prestrain == 0.0 {
        return None;
    }
    Some(scene.start.get_or_init(|| {
        let model = &scene.model;
        let (mut s, _) = held_solver(scene, &model.neighbours, 0);
        let report = settle_start(
            &mut s,
            gravity,
            super::SIMULATION_TICK_S,
            super::SETTLE_MAX_S,
        );
        let n = model.points.len();
        let surface = (0..model.surface.positions.len())
            .map(|v| {
                model.embedding.vertex_position(
                    v,
                    &model.surface.positions[v],
                    s.rest(),
                    s.positions(),
                    |k| s.deformation_gradient(k),
                )
            })
            .collect();
        StartState {
            positions: s.positions()[..n].to_vec(),
            surface,
            report,
        }
    }))
}

/// The surface a scene starts from: the built surface, or, under gravity, where it rests
/// on its supports (what a scripted stroke is placed on).
pub fn start_surface(scene: &BuiltScene) -> Cow<'_, TriMesh> {
    match start_state(scene) {
        None => Cow::Borrowed(&scene.model.surface),
        Some(start) => {
            let mut surface = scene.model.surface.clone();
            surface.positions.clone_from(&start.surface);
            Cow::Owned(surface)
        }
    }
}
