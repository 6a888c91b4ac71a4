//! `scalpel bench session`: a lab session of many strokes on one organ, measured stroke by
//! stroke — what a trainee's half hour does to the cost of a cut step, to the solver and to
//! the surface (a run of several wounds once made the solver diverge, docs/CUTTING.md).

use scalpel_sim::solver::{SubstepKeepingMass, WholeStepMass};
use serde::Serialize;

use crate::TargetArgs;
use crate::cut_cmd::{self, ScriptChoice};
use crate::cutrun::{self, Quantiles, TickRow};
use crate::{bench, load};

/// Ticks out of the tissue that end a stroke (a blade that drops out for a few ticks in
/// the middle of a stroke is still in it).
const GAP_TICKS: usize = 200;

/// One stroke of the session: the ticks from the blade's entry to its exit.
#[derive(Debug, Serialize)]
struct StrokeRow {
    stroke: usize,
    cut_steps: usize,
    total_ms: Quantiles,
    max_active_points: usize,
    max_substeps: u32,
    /// The sub-steps the explicit mode planned at the stroke's end (what it relaxes back
    /// to once a rollback or the stiffening's rise has passed).
    planned_substeps: u32,
    rollback_ticks: usize,
    diverged_ticks: usize,
    peak_force_n: f64,
}

/// The whole session.
#[derive(Debug, Serialize)]
struct SessionReport {
    scene: String,
    script: String,
    strokes: Vec<StrokeRow>,
    total_ms: Quantiles,
    /// Median cost per cut step of the last third of the strokes over the first third's.
    late_over_early: f64,
    rollback_ticks: usize,
    diverged_ticks: usize,
    /// Points the solver gave mass after cuts, and how much, as a share of the body's:
    /// where cuts left fits degenerate (selective mass scaling: `Solver::topology_changed`)
    /// and to keep the planned sub-steps (`substep_keeping_mass`).
    mass_added_points: usize,
    mass_added_g: f64,
    mass_added_share: f64,
    /// Most sub-steps in one tick.
    substeps_max: u32,
    /// The mass floor the uncut body was given for whole sub-steps, if any.
    whole_step_mass: Option<WholeStepMass>,
    /// Mass given to cut points to keep the planned sub-steps through the cuts.
    substep_keeping_mass: SubstepKeepingMass,
    incisions: usize,
    incisions_refused: usize,
    min_angle_deg: Option<f64>,
    triangles_before: usize,
    triangles_after: usize,
    sigma_triangles: usize,
    closed: bool,
    manifold: bool,
    oriented: bool,
}

/// `scalpel bench session`.
pub fn run(target: &TargetArgs, strokes: usize, seed: u64, json: bool) -> anyhow::Result<()> {
    let spec = cut_cmd::cutting_spec(target)?;
    let timed = load::build_with_progress(&spec)?;
    let scene = &timed.scene;
    let script = cut_cmd::script_for(scene, &ScriptChoice::Session { strokes, seed })?;
    let run = cut_cmd::run_with_progress(scene, &script, 1, 0)?;
    let m = cutrun::metrics(scene, &run, spec.force.ripple_wavelength_m);
    let rows: Vec<StrokeRow> = split_strokes(&run.rows)
        .iter()
        .enumerate()
        .map(|(k, ticks)| stroke_row(k + 1, ticks))
        .collect();
    let third = (rows.len() / 3).max(1);
    let median_of = |rs: &[StrokeRow]| {
        let mut v: Vec<f64> = rs.iter().map(|r| r.total_ms.p50).collect();
        if v.is_empty() {
            0.0
        } else {
            bench::median(&mut v)
        }
    };
    let early = median_of(&rows[..third.min(rows.len())]);
    let late = median_of(&rows[rows.len().saturating_sub(third)..]);
    let (mass_added_points, added_kg) = run.sim.solver().added_mass();
    let body_kg: f64 = scene.model.points.mass_kg.iter().sum();
    let report = SessionReport {
        scene: spec.name.clone(),
        script: script.description.clone(),
        total_ms: m.total_ms,
        late_over_early: late / early.max(1e-12),
        rollback_ticks: m.rollback_ticks,
        diverged_ticks: m.diverged_ticks,
        mass_added_points,
        mass_added_g: added_kg * 1e3,
        mass_added_share: added_kg / body_kg.max(1e-300),
        substeps_max: m.substeps_max,
        whole_step_mass: m.whole_step_mass,
        substep_keeping_mass: m.substep_keeping_mass,
        incisions: m.incisions,
        incisions_refused: m.incisions_refused,
        min_angle_deg: m.min_angle_deg,
        triangles_before: m.triangles_before,
        triangles_after: m.triangles_after,
        sigma_triangles: m.sigma_triangles,
        closed: m.closed,
        manifold: m.manifold,
        oriented: m.oriented,
        strokes: rows,
    };
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report);
    }
    Ok(())
}

/// The in-tissue runs of a session, runs closer than [`GAP_TICKS`] joined.
fn split_strokes(rows: &[TickRow]) -> Vec<Vec<&TickRow>> {
    let mut strokes: Vec<Vec<&TickRow>> = Vec::new();
    let mut out_for = usize::MAX;
    for r in rows {
        if r.in_tissue {
            // (`out_for` starts past the gap: the first tick in opens the first stroke.)
            if out_for >= GAP_TICKS {
                strokes.push(Vec::new());
            }
            strokes.last_mut().expect("opened above").push(r);
            out_for = 0;
        } else {
            out_for = out_for.saturating_add(1);
        }
    }
    strokes
}

fn stroke_row(stroke: usize, ticks: &[&TickRow]) -> StrokeRow {
    let total: Vec<f64> = ticks.iter().map(|r| r.surface_ms + r.internal_ms).collect();
    StrokeRow {
        stroke,
        cut_steps: ticks.len(),
        total_ms: Quantiles::or_zero(&total),
        max_active_points: ticks.iter().map(|r| r.active_points).max().unwrap_or(0),
        max_substeps: ticks.iter().map(|r| r.substeps).max().unwrap_or(0),
        planned_substeps: ticks.last().map_or(0, |r| r.planned_substeps),
        rollback_ticks: ticks.iter().filter(|r| r.rollbacks > 0).count(),
        diverged_ticks: ticks.iter().filter(|r| r.diverged).count(),
        peak_force_n: ticks.iter().map(|r| r.force_mag_n).fold(0.0, f64::max),
    }
}

fn print_report(r: &SessionReport) {
    println!("Session on {}: {}", r.scene, r.script);
    println!(
        "{:>6} {:>6} | {:>8} {:>8} {:>8} | {:>6} {:>4} | {:>8} {:>8} | {:>6}",
        "stroke",
        "steps",
        "tot p50",
        "tot p99",
        "tot max",
        "active",
        "sub",
        "rolled",
        "diverged",
        "peak"
    );
    for s in &r.strokes {
        println!(
            "{:>6} {:>6} | {:>8.3} {:>8.3} {:>8.2} | {:>6} {:>4} | {:>8} {:>8} | {:>5.2}N",
            s.stroke,
            s.cut_steps,
            s.total_ms.p50,
            s.total_ms.p99,
            s.total_ms.max,
            s.max_active_points,
            s.max_substeps,
            s.rollback_ticks,
            s.diverged_ticks,
            s.peak_force_n
        );
    }
    println!(
        "all cut steps: {:.3} ms median, {:.3} ms p99, {:.2} ms max; last third / first third of the strokes (medians): {:.2}×",
        r.total_ms.p50, r.total_ms.p99, r.total_ms.max, r.late_over_early
    );
    println!(
        "time step: {}",
        cutrun::describe_substeps(
            r.substeps_max,
            r.whole_step_mass.as_ref(),
            &r.substep_keeping_mass
        )
    );
    println!(
        "mass added to {} point(s) after cuts (fits left degenerate, sub-steps kept): {:.2} g, {:.2} % of the body",
        r.mass_added_points,
        r.mass_added_g,
        100.0 * r.mass_added_share
    );
    println!(
        "solver: {} tick(s) rolled back, {} diverged; surface: {} incision(s) ({} refused), {} → {} triangles, Σ {} triangles, min angle {}, closed {}, manifold {}, oriented {}",
        r.rollback_ticks,
        r.diverged_ticks,
        r.incisions,
        r.incisions_refused,
        r.triangles_before,
        r.triangles_after,
        r.sigma_triangles,
        r.min_angle_deg
            .map_or("—".to_string(), |a| format!("{a:.1}°")),
        r.closed,
        r.manifold,
        r.oriented
    );
}
