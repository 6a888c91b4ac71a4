//! Cutting benchmarks: the paper's Table 1 on the three organs, scaling with resolution,
//! and what a scene without cutting pays for it.

use std::time::Instant;

use scalpel_sim::model::SpacingRule;
use scalpel_sim::pipeline::{CutScript, NoClock, Simulation};
use scalpel_sim::scene::{self, BuiltScene, SceneSpec};
use scalpel_sim::solver::{SubstepKeepingMass, WholeStepMass};
use serde::Serialize;

use crate::cutrun::{self, Quantiles, TICK_S};
use crate::load;
use crate::progress::StageProgress;
use crate::{TargetArgs, cut_cmd};

/// The paper's Table 1: (scene, triangles, points, surface ms, internal ms).
const PAPER_TABLE1: [(&str, usize, usize, f64, f64); 3] = [
    ("liver", 508, 1526, 0.125, 2.21),
    ("shoulder", 1842, 4812, 1.03, 9.08),
    ("cerebroma", 2601, 7086, 6.86, 20.67),
];

/// One row of Table 1.
#[derive(Debug, Serialize)]
struct Table1Row {
    scene: String,
    triangles: usize,
    points: usize,
    paper_triangles: usize,
    paper_points: usize,
    script: String,
    cut_steps: usize,
    surface_ms: Quantiles,
    internal_ms: Quantiles,
    /// All of a cut step's work: both stages and the re-cut worker's time for the re-cuts
    /// that landed in it (like for like with the paper's single thread).
    total_ms: Quantiles,
    /// The re-cut worker's time over the run (ms).
    recut_worker_ms: f64,
    /// All the work per cut step on average (ms).
    work_per_cut_step_ms: f64,
    paper_surface_ms: f64,
    paper_internal_ms: f64,
    paper_total_ms: f64,
    /// Paper total over our median total.
    speedup: f64,
    max_active_points: usize,
    steady_force_n: f64,
    min_angle_deg: Option<f64>,
    closed: bool,
    manifold: bool,
    substeps_max: u32,
    /// The mass floor that saved a sub-step per tick, if any.
    whole_step_mass: Option<WholeStepMass>,
    /// Mass given to cut points to keep the planned sub-steps through the cuts.
    substep_keeping_mass: SubstepKeepingMass,
}

fn build(spec: &SceneSpec) -> anyhow::Result<BuiltScene> {
    let mut display = StageProgress::new(&spec.name);
    let timed = load::build_timed(spec, &mut display)?;
    display.finish();
    Ok(timed.scene)
}

/// The built-in organ `name`; with `fracture`, with the physical cut (fracture by energy) on
/// its own stiffening or on β when given — said as a scene file would say it, so that β is
/// checked as the file's is. (TOML spells NaN in lower case.)
pub fn organ_spec(name: &str, fracture: Option<Option<f64>>) -> anyhow::Result<SceneSpec> {
    let Some(beta) = fracture else {
        return scene::builtin(name).ok_or_else(|| anyhow::anyhow!("no built-in scene {name}"));
    };
    Ok(SceneSpec::from_toml(
        &format!(
            "extends = \"{name}\"\nname = \"{name}\"\n[force]\nfracture_by_energy = true\n{}",
            match beta {
                None => String::new(),
                Some(b) if b.is_nan() => "[material]\nstiffening = nan\n".to_string(),
                Some(b) => format!("[material]\nstiffening = {b:?}\n"),
            }
        ),
        std::path::Path::new("--fracture"),
    )?)
}

/// `scalpel bench table1`; with `fracture`, the physical cut (fracture by energy), on the
/// organ's own stiffening or on β when given.
pub fn table1(threads: usize, fracture: Option<Option<f64>>, json: bool) -> anyhow::Result<()> {
    let mut rows = Vec::new();
    for (name, paper_tris, paper_points, paper_surface, paper_internal) in PAPER_TABLE1 {
        let spec = organ_spec(name, fracture)?;
        let scene = build(&spec)?;
        let script = CutScript::default_for(&scalpel_sim::pipeline::start_surface(&scene))?;
        let run = cut_cmd::run_with_progress(&scene, &script, threads, 0)?;
        let m = cutrun::metrics(&scene, &run, spec.force.ripple_wavelength_m);
        let paper_total = paper_surface + paper_internal;
        rows.push(Table1Row {
            scene: name.to_string(),
            triangles: scene.model.surface.triangles.len(),
            points: scene.model.points.len(),
            paper_triangles: paper_tris,
            paper_points,
            script: script.description.clone(),
            cut_steps: m.cut_steps,
            surface_ms: m.surface_ms,
            internal_ms: m.internal_ms,
            total_ms: m.total_ms,
            recut_worker_ms: m.recut_worker_ms,
            work_per_cut_step_ms: m.work_per_cut_step_ms,
            paper_surface_ms: paper_surface,
            paper_internal_ms: paper_internal,
            paper_total_ms: paper_total,
            speedup: paper_total / m.total_ms.p50.max(1e-9),
            max_active_points: m.max_active_points,
            steady_force_n: m.steady_force_n,
            min_angle_deg: m.min_angle_deg,
            closed: m.closed,
            manifold: m.manifold,
            substeps_max: m.substeps_max,
            whole_step_mass: m.whole_step_mass,
            substep_keeping_mass: m.substep_keeping_mass,
        });
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "Table 1 (per cut step, this machine; all of a step's work, the re-cut worker's time added to the step it landed in; paper figures for comparison){}",
        match fracture {
            None => String::new(),
            Some(None) => "; fracture by energy, each organ's stiffening".to_string(),
            Some(Some(b)) => format!("; fracture by energy, stiffening β = {b}"),
        }
    );
    println!(
        "{:<10} {:>6} {:>6} | {:>8} {:>8} | {:>8} {:>8} | {:>8} {:>8} | {:>7} {:>8} {:>7} | {:>7}",
        "scene",
        "tris",
        "points",
        "surf p50",
        "surf p99",
        "int p50",
        "int p99",
        "tot p50",
        "tot p99",
        "paper s",
        "paper i",
        "paper",
        "speedup"
    );
    for r in &rows {
        println!(
            "{:<10} {:>6} {:>6} | {:>8.3} {:>8.3} | {:>8.3} {:>8.3} | {:>8.3} {:>8.3} | {:>7.3} {:>8.2} {:>7.2} | {:>6.0}×",
            r.scene,
            r.triangles,
            r.points,
            r.surface_ms.p50,
            r.surface_ms.p99,
            r.internal_ms.p50,
            r.internal_ms.p99,
            r.total_ms.p50,
            r.total_ms.p99,
            r.paper_surface_ms,
            r.paper_internal_ms,
            r.paper_total_ms,
            r.speedup
        );
    }
    for r in &rows {
        println!(
            "  {}: {}; {} cut steps, ≤ {} points integrated, steady force {:.2} N, min angle {}, closed {}, manifold {}",
            r.scene,
            r.script,
            r.cut_steps,
            r.max_active_points,
            r.steady_force_n,
            r.min_angle_deg
                .map_or("-".to_string(), |a| format!("{a:.1}°")),
            r.closed,
            r.manifold
        );
        println!(
            "    all the work per cut step {:.3} ms on average, of which the re-cut worker's {:.1} ms over the run",
            r.work_per_cut_step_ms, r.recut_worker_ms
        );
        println!(
            "    {}",
            cutrun::describe_substeps(
                r.substeps_max,
                r.whole_step_mass.as_ref(),
                &r.substep_keeping_mass
            )
        );
    }
    Ok(())
}

/// One resolution of the scaling run.
#[derive(Debug, Serialize)]
struct ScalingRow {
    target_points: usize,
    points: usize,
    spacing_mm: f64,
    cut_steps: usize,
    surface_ms: Quantiles,
    internal_ms: Quantiles,
    total_ms: Quantiles,
    max_active_points: usize,
    substeps_max: u32,
    /// Median total over the coarsest's median total.
    growth: f64,
}

/// `scalpel bench scaling`.
pub fn scaling(targets: &[usize], threads: usize, json: bool) -> anyhow::Result<()> {
    anyhow::ensure!(!targets.is_empty(), "no resolutions given");
    let mut rows: Vec<ScalingRow> = Vec::new();
    let mut script: Option<CutScript> = None;
    for &target in targets {
        let mut spec = scene::builtin("liver").expect("built-in scene");
        spec.sampling.spacing = SpacingRule::TargetPoints(target);
        spec.name = format!("liver@{target}");
        let scene = build(&spec)?;
        // The same stroke at every resolution (the surface is the same).
        let script = script.get_or_insert(CutScript::default_for(
            &scalpel_sim::pipeline::start_surface(&scene),
        )?);
        let run = cut_cmd::run_with_progress(&scene, script, threads, 0)?;
        let m = cutrun::metrics(&scene, &run, spec.force.ripple_wavelength_m);
        let base = rows.first().map_or(m.total_ms.p50, |r| r.total_ms.p50);
        rows.push(ScalingRow {
            target_points: target,
            points: scene.model.points.len(),
            spacing_mm: scene.model.lattice.spacing * 1e3,
            cut_steps: m.cut_steps,
            surface_ms: m.surface_ms,
            internal_ms: m.internal_ms,
            total_ms: m.total_ms,
            max_active_points: m.max_active_points,
            substeps_max: run.sim.solver().substeps(),
            growth: m.total_ms.p50 / base.max(1e-12),
        });
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!("Scaling: the default liver stroke at several resolutions (per cut step)");
    println!(
        "{:>7} {:>8} | {:>8} {:>8} | {:>8} {:>8} | {:>8} {:>8} | {:>7} {:>4} | {:>6}",
        "points",
        "spacing",
        "surf p50",
        "surf p99",
        "int p50",
        "int p99",
        "tot p50",
        "tot p99",
        "active",
        "sub",
        "growth"
    );
    for r in &rows {
        println!(
            "{:>7} {:>6.2}mm | {:>8.3} {:>8.3} | {:>8.3} {:>8.3} | {:>8.3} {:>8.3} | {:>7} {:>4} | {:>5.2}×",
            r.points,
            r.spacing_mm,
            r.surface_ms.p50,
            r.surface_ms.p99,
            r.internal_ms.p50,
            r.internal_ms.p99,
            r.total_ms.p50,
            r.total_ms.p99,
            r.max_active_points,
            r.substeps_max,
            r.growth
        );
    }
    Ok(())
}

/// What one idle tick costs with and without the cutting stages.
#[derive(Debug, Serialize)]
struct IdleRow {
    scene: String,
    cutting_stages_built: bool,
    points_integrated: usize,
    substeps: u32,
    tick_ms: Quantiles,
}

/// `scalpel bench idle`: a scene that does not cut builds no cutting stage (no contact
/// queries, no cut surface, no force model) and pays nothing for it; a cutting scene with
/// the tool away integrates no point at all.
pub fn idle(target: &TargetArgs, ticks: usize, json: bool) -> anyhow::Result<()> {
    let base = load::resolve(target)?;
    let mut rows = Vec::new();
    for cutting in [true, false] {
        let mut spec = base.clone();
        spec.features.cutting = cutting;
        let state = if cutting { "on" } else { "off" };
        spec.name = format!("{}, cutting {state}", base.name);
        let scene = build(&spec)?;
        let mut sim = Simulation::new(&scene);
        scalpel_server::recut_worker::attach(&mut sim);
        sim.prepare(TICK_S);
        let mut times = Vec::with_capacity(ticks);
        let (mut integrated, mut substeps) = (0, 0);
        for _ in 0..ticks {
            let t0 = Instant::now();
            let r = sim.tick(TICK_S, &mut NoClock);
            times.push(t0.elapsed().as_secs_f64() * 1e3);
            integrated = r.active_points;
            substeps = r.solver.substeps;
        }
        rows.push(IdleRow {
            scene: spec.name.clone(),
            cutting_stages_built: sim.cutting().is_some(),
            points_integrated: integrated,
            substeps,
            tick_ms: Quantiles::or_zero(&times),
        });
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!("Idle ticks (no tool), {ticks} each");
    for r in &rows {
        println!(
            "{:<22} cutting stages {:<5} points integrated {:>5} × {} sub-step(s)  tick {:.4} ms median, {:.4} ms p99",
            r.scene,
            r.cutting_stages_built,
            r.points_integrated,
            r.substeps,
            r.tick_ms.p50,
            r.tick_ms.p99
        );
    }
    Ok(())
}
