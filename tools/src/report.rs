//! Scene reports, as text for people and as JSON for scripts.

use std::collections::BTreeMap;

use scalpel_sim::mls::Prestress;
use scalpel_sim::model::ModelSummary;
use scalpel_sim::pipeline::Simulation;
use scalpel_sim::pipeline::surface_prestress;
use scalpel_sim::scene::{self, BuiltinMesh, MeshSource, SamplingPlan};
use scalpel_sim::solver::{SubstepKeepingMass, WholeStepMass};
use serde::Serialize;

use crate::cutrun;
use crate::load::TimedScene;

/// The JSON report of `scalpel scene inspect --json` (and `demo --json`).
#[derive(Serialize)]
pub struct SceneReport {
    /// Scene name.
    pub name: String,
    /// Scene description.
    pub description: String,
    /// `builtin:<shape>` or the mesh file.
    pub source: String,
    /// Surface triangles.
    pub triangles: usize,
    /// Surface vertices.
    pub vertices: usize,
    /// Interior points.
    pub points: usize,
    /// Lattice spacing (mm).
    pub spacing_mm: f64,
    /// Support radius h (mm).
    pub support_mm: f64,
    /// Bounding box size (mm).
    pub bbox_mm: [f64; 3],
    /// Enclosed volume of the surface (ml).
    pub volume_ml: f64,
    /// Total mass of the points (g).
    pub mass_g: f64,
    /// Smallest triangle angle (degrees).
    pub min_angle_deg: f64,
    /// Mean edge length (mm).
    pub mean_edge_mm: f64,
    /// Interior model figures.
    pub model: ModelSummary,
    /// Enabled features.
    pub features: Vec<&'static str>,
    /// Material: E (kPa), ν, ρ (kg/m³), damping (1/s).
    pub material: MaterialReport,
    /// The explicit time step the scene's solver plans for the station's 1 ms ticks;
    /// `None` in the stiff mode or for a body over [`PLANNED_POINTS_MAX`] points.
    pub time_step: Option<TimeStepReport>,
    /// How a mesh's default sampling was chosen for a real-time tick.
    pub sampling_plan: Option<SamplingPlan>,
    /// Repairs made to the surface, as sentences.
    pub warnings: Vec<String>,
    /// Whole build (ms).
    pub build_ms: f64,
    /// Build time per stage (ms).
    pub stages_ms: BTreeMap<&'static str, f64>,
}

/// Bodies up to this many points get their time step planned in the report (a power
/// iteration per try: 45 ms on the cerebroma's 7086 points, seconds at a million).
pub const PLANNED_POINTS_MAX: usize = 200_000;

/// The time step a scene's explicit solver plans: what the sampling costs per tick.
#[derive(Serialize)]
pub struct TimeStepReport {
    /// Critical explicit step (ms), after any mass floor.
    pub dt_crit_ms: f64,
    /// Explicit sub-steps per 1 ms tick.
    pub substeps_per_tick: u32,
    /// The mass floor that saved a sub-step, if any.
    pub mass_floor: Option<WholeStepMass>,
}

impl TimeStepReport {
    /// Builds the scene's simulation and plans 1 ms ticks (`Simulation::prepare`), unless
    /// the build's real-time sampling rule already planned the model kept.
    fn plan(timed: &TimedScene) -> Option<Self> {
        let s = &timed.scene;
        if let Some(kept) = s.sampling_plan.as_ref().map(|p| p.kept) {
            return Some(Self {
                dt_crit_ms: kept.dt_crit_s * 1e3,
                substeps_per_tick: kept.substeps,
                mass_floor: kept.mass_floor,
            });
        }
        if !s.spec.is_explicit() || s.model.points.len() > PLANNED_POINTS_MAX {
            return None;
        }
        let mut sim = Simulation::new(s);
        sim.prepare(cutrun::TICK_S);
        let solver = sim.solver();
        Some(Self {
            dt_crit_ms: solver.known_dt_crit()? * 1e3,
            substeps_per_tick: solver.substeps(),
            mass_floor: solver.whole_step_mass(),
        })
    }
}

/// Material figures in user units.
#[derive(Serialize)]
pub struct MaterialReport {
    youngs_modulus_kpa: f64,
    poisson_ratio: f64,
    density_kg_m3: f64,
    damping_per_s: f64,
    /// Strain-stiffening β (0: none).
    stiffening: f64,
    /// Residual tension ε of the surface layer (0: none).
    prestrain: f64,
    /// The layer's tension σ = E ε/(1 − ν) (Pa).
    prestrain_tension_pa: f64,
    /// Points in the tensioned layer.
    prestrain_layer_points: usize,
}

impl SceneReport {
    /// Gathers the report of a built scene.
    pub fn of(timed: &TimedScene) -> Self {
        let s = &timed.scene;
        let stats = &s.mesh_stats;
        let model = s.model.summary();
        let m = &s.spec.material;
        Self {
            name: s.spec.name.clone(),
            description: s.spec.description.clone(),
            source: match &s.spec.mesh.source {
                MeshSource::Builtin(b) => format!("builtin:{}", b.name()),
                MeshSource::File(p) => p.display().to_string(),
            },
            triangles: stats.triangles,
            vertices: stats.vertices,
            points: model.points,
            spacing_mm: model.spacing_mm,
            support_mm: model.support_mm,
            bbox_mm: (stats.bbox.size() * 1e3).into(),
            volume_ml: stats.volume_m3 * 1e6,
            mass_g: model.mass_g,
            min_angle_deg: stats.min_angle_deg,
            mean_edge_mm: stats.mean_edge_m * 1e3,
            features: s.spec.features.enabled(),
            material: MaterialReport {
                youngs_modulus_kpa: m.youngs_modulus_pa * 1e-3,
                poisson_ratio: m.poisson_ratio,
                density_kg_m3: m.density_kg_m3,
                damping_per_s: m.damping_per_s,
                stiffening: m.stiffening,
                prestrain: m.prestrain,
                prestrain_tension_pa: Prestress::tension_pa(
                    m.youngs_modulus_pa,
                    m.poisson_ratio,
                    m.prestrain,
                ),
                prestrain_layer_points: surface_prestress(m, &s.model).points().len(),
            },
            time_step: TimeStepReport::plan(timed),
            sampling_plan: s.sampling_plan.clone(),
            warnings: s.mesh_warnings.iter().map(ToString::to_string).collect(),
            build_ms: timed.build_ms,
            stages_ms: timed.stages_ms.clone(),
            model,
        }
    }
}

/// Prints the report of a built scene.
pub fn print_scene(timed: &TimedScene, json: bool) -> anyhow::Result<()> {
    let r = SceneReport::of(timed);
    if json {
        println!("{}", serde_json::to_string_pretty(&r)?);
        return Ok(());
    }
    let m = &r.model;
    println!("scene {} — {}", r.name, r.description);
    println!(
        "  surface    {} triangles, {} vertices, min angle {:.1}°, mean edge {:.2} mm ({})",
        r.triangles, r.vertices, r.min_angle_deg, r.mean_edge_mm, r.source
    );
    println!(
        "  size       {:.1} × {:.1} × {:.1} mm, volume {:.2} ml, mass {:.1} g",
        r.bbox_mm[0], r.bbox_mm[1], r.bbox_mm[2], r.volume_ml, r.mass_g
    );
    println!(
        "  interior   {} points, spacing {:.3} mm, support h = {:.3} mm, lattice {} × {} × {}",
        r.points,
        r.spacing_mm,
        r.support_mm,
        m.lattice_dims[0],
        m.lattice_dims[1],
        m.lattice_dims[2]
    );
    println!(
        "             Σ V = {:.3} ml (error {:.1e} of the surface volume), {} slivers merged",
        m.points_volume_ml, m.volume_error, m.merged_slivers
    );
    println!(
        "             neighbours {} / {:.1} / {} (min / mean / max), {} points with fewer than 4",
        m.min_neighbours, m.mean_neighbours, m.max_neighbours, m.weak_points
    );
    println!(
        "  embedding  {:.1} points per surface vertex (min {}), {} vertices needed a wider support",
        m.embedding.mean_points, m.embedding.min_points, m.embedding.widened
    );
    let mat = &r.material;
    println!(
        "  material   E = {:.1} kPa, ν = {}, ρ = {} kg/m³, damping {} /s, stiffening β = {}",
        mat.youngs_modulus_kpa,
        mat.poisson_ratio,
        mat.density_kg_m3,
        mat.damping_per_s,
        mat.stiffening
    );
    if mat.prestrain > 0.0 {
        println!(
            "             residual tension ε = {} (σ = {:.0} Pa) on {} surface-layer points",
            mat.prestrain, mat.prestrain_tension_pa, mat.prestrain_layer_points
        );
    }
    match &r.time_step {
        Some(t) => println!(
            "  time step  dt_crit {:.3} ms: {}",
            t.dt_crit_ms,
            cutrun::describe_substeps(
                t.substeps_per_tick,
                t.mass_floor.as_ref(),
                &SubstepKeepingMass::default()
            )
        ),
        None if timed.scene.spec.features.stiff_mode => {
            println!("  time step  stiff mode: one projective step per tick")
        }
        None if !timed.scene.spec.is_explicit() => {
            println!("  time step  implicit: one preconditioned CG solve per tick")
        }
        None => println!("  time step  not planned here (over {PLANNED_POINTS_MAX} points)"),
    }
    if let Some(plan) = &r.sampling_plan {
        println!("  sampling   {plan}");
    }
    let features = if r.features.is_empty() {
        "none (deformation only)".to_string()
    } else {
        r.features.join(", ")
    };
    println!("  features   {features}");
    if r.warnings.is_empty() {
        println!("  repairs    none");
    } else {
        for w in &r.warnings {
            println!("  repair     {w}");
        }
    }
    let stages: Vec<String> = r
        .stages_ms
        .iter()
        .map(|(k, v)| format!("{k} {v:.1}"))
        .collect();
    println!("  built in   {:.1} ms ({})", r.build_ms, stages.join(", "));
    Ok(())
}

#[derive(Serialize)]
struct ListedScene {
    name: &'static str,
    description: String,
    features: Vec<&'static str>,
}

/// Prints the built-in scenes.
pub fn print_scene_list(json: bool) -> anyhow::Result<()> {
    let scenes: Vec<ListedScene> = BuiltinMesh::ALL
        .iter()
        .filter_map(|b| {
            let spec = scene::builtin(b.name())?;
            Some(ListedScene {
                name: b.name(),
                description: spec.description,
                features: spec.features.enabled(),
            })
        })
        .collect();
    if json {
        println!("{}", serde_json::to_string_pretty(&scenes)?);
    } else {
        for s in &scenes {
            println!("{:<10} {}", s.name, s.description);
        }
    }
    Ok(())
}
