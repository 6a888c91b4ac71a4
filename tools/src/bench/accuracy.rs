//! `scalpel bench accuracy`: error against run time (physics.md §8, "Error vs run time").
//!
//! For the cantilever (B5 geometry, tip load) and the uniaxial block (B3), at 3 to 9 points
//! across and in both dynamic solver modes, the body is simulated with damping until it
//! settles; the error is measured against the analytic answer at the end, and the cost is
//! the wall time per simulated second. The slope of log error against log cost is fitted
//! per series (physics.md expects about −1/4 for explicit dynamics).

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use scalpel_sim::math::Vec3;
use scalpel_sim::scene::Material;
use scalpel_sim::solver::{SolverConfig, SolverMode};
use scalpel_sim::validate::{
    BoxBody, box_body, cantilever_body, timoshenko_tip_deflection, tip_deflection,
    uniaxial_measure, uniaxial_setup,
};
use serde::Serialize;

use crate::plot::{Series, log_log};

/// Mass-proportional damping that settles each case within its run: about twice the
/// lowest mode's angular frequency (cantilever 2.2 Hz ≈ 14 rad/s; the uniaxial block's axial
/// mode ≈ 340 rad/s), so the slowest mode decays in a few tenths of a second.
const CANTILEVER_DAMPING: f64 = 28.0;
const UNIAXIAL_DAMPING: f64 = 400.0;
/// Simulated time per run (ticks of 1 ms).
const CANTILEVER_TICKS: usize = 1000;
const UNIAXIAL_TICKS: usize = 300;

#[derive(Serialize, Clone)]
struct Row {
    case: &'static str,
    mode: &'static str,
    points_across: usize,
    points: usize,
    spacing_mm: f64,
    simulated_s: f64,
    wall_s: f64,
    wall_s_per_simulated_s: f64,
    substeps_per_tick: u32,
    error: f64,
}

#[derive(Serialize)]
struct Fit {
    case: &'static str,
    mode: &'static str,
    slope: f64,
    samples: usize,
}

#[derive(Serialize)]
struct Report {
    rows: Vec<Row>,
    fits: Vec<Fit>,
    csv: String,
    plot: String,
}

fn mode_name(mode: SolverMode) -> &'static str {
    match mode {
        SolverMode::Explicit => "explicit",
        SolverMode::Projective => "projective",
        SolverMode::QuasiStatic => "quasi-static",
    }
}

/// Simulates `ticks` ticks of 1 ms and times them.
fn simulate(body: &mut BoxBody, ticks: usize) -> f64 {
    let start = Instant::now();
    for _ in 0..ticks {
        body.solver.step(1e-3);
    }
    start.elapsed().as_secs_f64()
}

fn settling_material(damping_per_s: f64) -> Material {
    Material {
        damping_per_s,
        ..Material::LIVER
    }
}

fn cantilever(m: usize, mode: SolverMode) -> Row {
    let config = SolverConfig {
        mode,
        ..SolverConfig::default()
    };
    let load = 1e-4;
    let mut body = cantilever_body(
        0.040,
        0.010,
        m,
        load,
        &settling_material(CANTILEVER_DAMPING),
        config,
    );
    let ticks = CANTILEVER_TICKS;
    let wall = simulate(&mut body, ticks);
    let expected = timoshenko_tip_deflection(load, 0.040, 0.010, 5000.0, 0.45);
    row(
        "cantilever",
        mode,
        m,
        &body,
        ticks,
        wall,
        (tip_deflection(&body) / expected - 1.0).abs(),
    )
}

fn uniaxial(m: usize, mode: SolverMode) -> Row {
    let config = SolverConfig {
        mode,
        ..SolverConfig::default()
    };
    let side = 0.010;
    let mut body = box_body(
        Vec3::new(2.0 * side, side, side),
        m,
        &settling_material(UNIAXIAL_DAMPING),
        2.0,
        config,
    );
    let strain = 1e-3;
    uniaxial_setup(&mut body, strain);
    let ticks = UNIAXIAL_TICKS;
    let wall = simulate(&mut body, ticks);
    let r = uniaxial_measure(&mut body, strain);
    row(
        "uniaxial",
        mode,
        m,
        &body,
        ticks,
        wall,
        r.reaction_error.abs().max(r.nu_error.abs()),
    )
}

fn row(
    case: &'static str,
    mode: SolverMode,
    m: usize,
    body: &BoxBody,
    ticks: usize,
    wall: f64,
    error: f64,
) -> Row {
    let simulated = ticks as f64 * 1e-3;
    Row {
        case,
        mode: mode_name(mode),
        points_across: m,
        points: body.model.points.len(),
        spacing_mm: body.model.lattice.spacing * 1e3,
        simulated_s: simulated,
        wall_s: wall,
        wall_s_per_simulated_s: wall / simulated,
        substeps_per_tick: body.solver.substeps(),
        error,
    }
}

/// Least-squares slope of ln y against ln x.
fn log_slope(points: &[(f64, f64)]) -> f64 {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0)
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    let n = logs.len() as f64;
    if logs.len() < 2 {
        return f64::NAN;
    }
    let mx = logs.iter().map(|p| p.0).sum::<f64>() / n;
    let my = logs.iter().map(|p| p.1).sum::<f64>() / n;
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

/// Runs the sweep and writes `accuracy.csv` and `accuracy.png` into `out`.
pub fn run(out: &Path, min_across: usize, max_across: usize, json: bool) -> anyhow::Result<()> {
    anyhow::ensure!(
        min_across >= 3 && max_across >= min_across,
        "points across must be 3 or more, min ≤ max"
    );
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut rows = Vec::new();
    for mode in [SolverMode::Explicit, SolverMode::Projective] {
        for m in min_across..=max_across {
            rows.push(cantilever(m, mode));
            rows.push(uniaxial(m, mode));
            if !json {
                let r = &rows[rows.len() - 2];
                eprintln!(
                    "{} {} m = {m}: error {:.3e}, {:.3} s per simulated s",
                    r.case, r.mode, r.error, r.wall_s_per_simulated_s
                );
            }
        }
    }
    let mut fits = Vec::new();
    let mut series = Vec::new();
    for case in ["cantilever", "uniaxial"] {
        for mode in ["explicit", "projective"] {
            let points: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.case == case && r.mode == mode)
                .map(|r| (r.wall_s_per_simulated_s, r.error))
                .collect();
            let slope = log_slope(&points);
            fits.push(Fit {
                case,
                mode,
                slope,
                samples: points.len(),
            });
            series.push(Series {
                label: format!("{case}, {mode} (slope {slope:.2})"),
                points: points
                    .into_iter()
                    .filter(|(x, y)| *x > 0.0 && *y > 0.0)
                    .collect(),
            });
        }
    }
    let csv_path = out.join("accuracy.csv");
    let mut csv = String::from(
        "case,mode,points_across,points,spacing_mm,simulated_s,wall_s,wall_s_per_simulated_s,substeps_per_tick,error\n",
    );
    for r in &rows {
        let _ = writeln!(
            csv,
            "{},{},{},{},{:.4},{},{:.6},{:.6},{},{:.6e}",
            r.case,
            r.mode,
            r.points_across,
            r.points,
            r.spacing_mm,
            r.simulated_s,
            r.wall_s,
            r.wall_s_per_simulated_s,
            r.substeps_per_tick,
            r.error
        );
    }
    std::fs::write(&csv_path, csv)
        .with_context(|| format!("cannot write {}", csv_path.display()))?;
    let plot_path = out.join("accuracy.png");
    log_log(
        &plot_path,
        "Error against run time (liver, E = 5 kPa, ν = 0.45)",
        "wall time per simulated second (s)",
        "relative error",
        &series,
    )?;
    if json {
        let report = Report {
            rows,
            fits,
            csv: csv_path.display().to_string(),
            plot: plot_path.display().to_string(),
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{:<11} {:<11} {:>6} {:>7} {:>8} {:>10} {:>12}",
            "case", "mode", "across", "points", "s (mm)", "error", "s per sim s"
        );
        for r in &rows {
            println!(
                "{:<11} {:<11} {:>6} {:>7} {:>8.3} {:>10.3e} {:>12.4}",
                r.case,
                r.mode,
                r.points_across,
                r.points,
                r.spacing_mm,
                r.error,
                r.wall_s_per_simulated_s
            );
        }
        for f in &fits {
            println!(
                "slope of log error vs log cost, {} {}: {:.3}",
                f.case, f.mode, f.slope
            );
        }
        println!("wrote {} and {}", csv_path.display(), plot_path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slope_of_a_power_law() {
        let pts: Vec<(f64, f64)> = (1..6).map(|k| (k as f64, (k as f64).powf(-0.25))).collect();
        assert!((log_slope(&pts) + 0.25).abs() < 1e-12);
    }
}
