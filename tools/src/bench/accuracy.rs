//! `scalpel bench accuracy`: error against run time (physics.md §8, "Error vs run time").
//!
//! For the cantilever (B5 geometry, tip load) and the uniaxial block (B3), at 3 to 9 points
//! across and in both dynamic solver modes, the body is simulated with damping until it
//! settles; the error is measured at the end against the converged 3D reference (the
//! cantilever: tools/reference/fem_reference.py; Timoshenko's figure is kept beside it) or
//! the exact answer (the uniaxial block's homogeneous stretch), and the cost is the wall
//! time per simulated second. The slope of log error against log cost is fitted per series
//! (physics.md expects about −1/4 for explicit dynamics). The cut's series (`accuracy_cut`)
//! measures the liver stroke's force curve against a fine run's. Peers' points
//! (tools/bench/peers) join the plot from their JSON.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use scalpel_sim::math::Vec3;
use scalpel_sim::scene::Material;
use scalpel_sim::solver::{ImplicitPreconditioner, SolverConfig, SolverMode};
use scalpel_sim::validate::{
    BoxBody, CANTILEVER_3D_TIP_M, box_body, cantilever_body, timoshenko_tip_deflection,
    tip_deflection, uniaxial_measure, uniaxial_setup,
};
use serde::{Deserialize, Serialize};

use super::accuracy_cut;
pub use super::accuracy_cut::{CUT_POINTS, CUT_REFERENCE_POINTS};
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
    /// Mean solver iterations per tick: the implicit mode's conjugate gradients, the
    /// projective mode's local/global rounds, 0 for explicit.
    iterations_per_tick: f64,
    /// Relative error against the converged 3D reference (the cantilever) or the exact
    /// answer (the uniaxial block).
    error: f64,
    /// The cantilever's relative error against Timoshenko's beam theory.
    #[serde(skip_serializing_if = "Option::is_none")]
    error_timoshenko: Option<f64>,
    /// The cantilever's tip deflection (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    tip_m: Option<f64>,
    /// What `wall_s` measures: "wall" (one thread: the bodies) or "process CPU" (the cut,
    /// whose re-cut worker runs beside the simulation thread).
    cost_clock: &'static str,
}

/// A peer simulator's run of the cantilever, as tools/bench/peers writes it.
#[derive(Deserialize, Serialize, Clone)]
struct PeerRow {
    peer: String,
    across: usize,
    nodes: usize,
    wall_s_per_simulated_s: f64,
    tip_m: f64,
    /// Relative error against the 3D reference, computed here.
    #[serde(default)]
    error: f64,
}

#[derive(Deserialize)]
struct PeerFile {
    rows: Vec<PeerRow>,
}

/// Which bodies and modes to run.
pub struct Selection {
    /// Points across the beam, fewest and most.
    pub across: (usize, usize),
    /// "cantilever", "cantilever-stiff", "uniaxial", "cut" or "all".
    pub case: String,
    /// "explicit", "projective", "implicit", "implicit-factored", "implicit-two-level" or
    /// "all".
    pub mode: String,
    /// The implicit modes' CG tolerance.
    pub implicit_tolerance: f64,
    /// A peers JSON (tools/bench/peers) whose cantilever points join the plot.
    pub peers: Option<std::path::PathBuf>,
    /// The cut's resolutions (target points) and its reference run's.
    pub cut_points: Vec<usize>,
    /// The reference run's target points.
    pub cut_reference: usize,
}

#[derive(Serialize)]
struct Fit {
    case: &'static str,
    /// A solver mode, or a peer's name.
    mode: String,
    slope: f64,
    samples: usize,
}

#[derive(Serialize)]
struct Report {
    reference_tip_m: f64,
    rows: Vec<Row>,
    fits: Vec<Fit>,
    peers: Vec<PeerRow>,
    csv: String,
    plot: String,
}

/// An integrator as the bench names it: a solver mode and, for the implicit mode, its
/// preconditioner.
#[derive(Clone, Copy)]
struct Method {
    name: &'static str,
    mode: SolverMode,
    preconditioner: Option<ImplicitPreconditioner>,
}

/// The bodies, as `--case` names them.
const CASES: [&str; 4] = ["cantilever", "cantilever-stiff", "uniaxial", "cut"];

/// The dynamic integrators compared, in the order they run.
const METHODS: [Method; 5] = [
    Method {
        name: "explicit",
        mode: SolverMode::Explicit,
        preconditioner: None,
    },
    Method {
        name: "projective",
        mode: SolverMode::Projective,
        preconditioner: None,
    },
    Method {
        name: "implicit",
        mode: SolverMode::Implicit,
        preconditioner: Some(ImplicitPreconditioner::Jacobi),
    },
    Method {
        name: "implicit-factored",
        mode: SolverMode::Implicit,
        preconditioner: Some(ImplicitPreconditioner::Factored),
    },
    Method {
        name: "implicit-two-level",
        mode: SolverMode::Implicit,
        preconditioner: Some(ImplicitPreconditioner::TwoLevel),
    },
];

impl Method {
    fn config(self, tolerance: f64) -> SolverConfig {
        let default = SolverConfig::default();
        SolverConfig {
            mode: self.mode,
            implicit_preconditioner: self
                .preconditioner
                .unwrap_or(default.implicit_preconditioner),
            implicit_tolerance: tolerance,
            ..default
        }
    }
}

fn mode_name(mode: SolverMode) -> &'static str {
    match mode {
        SolverMode::Explicit => "explicit",
        SolverMode::Projective => "projective",
        SolverMode::QuasiStatic => "quasi-static",
        SolverMode::Implicit => "implicit",
    }
}

/// Simulates `ticks` ticks of 1 ms and times them; the mean iterations per tick (the
/// implicit mode's CG, the projective mode's local/global rounds; 0 for explicit).
fn simulate(body: &mut BoxBody, ticks: usize) -> (f64, f64) {
    let start = Instant::now();
    let mut iterations = 0u64;
    for _ in 0..ticks {
        iterations += u64::from(body.solver.step(1e-3).iterations);
    }
    (
        start.elapsed().as_secs_f64(),
        iterations as f64 / ticks as f64,
    )
}

fn settling_material(damping_per_s: f64) -> Material {
    Material {
        damping_per_s,
        ..Material::LIVER
    }
}

/// The stiff cantilever's Young's modulus: the top of the range tissue reaches (a
/// stiffened capsule, cartilage), 200 times the liver's. Its load is 200 times too, so the
/// deflection, and the 3D reference, are the soft beam's; its damping is √200 times, for
/// its slowest mode is that much faster.
const STIFF_E_PA: f64 = 1e6;

fn cantilever(m: usize, method: Method, stiff: bool, tolerance: f64) -> Row {
    let config = method.config(tolerance);
    let ratio = if stiff {
        STIFF_E_PA / Material::LIVER.youngs_modulus_pa
    } else {
        1.0
    };
    let load = 1e-4 * ratio;
    let material = Material {
        youngs_modulus_pa: Material::LIVER.youngs_modulus_pa * ratio,
        ..settling_material(CANTILEVER_DAMPING * ratio.sqrt())
    };
    let mut body = cantilever_body(0.040, 0.010, m, load, &material, config);
    let ticks = CANTILEVER_TICKS;
    let (wall, iterations) = simulate(&mut body, ticks);
    let timoshenko = timoshenko_tip_deflection(
        load,
        0.040,
        0.010,
        material.youngs_modulus_pa,
        material.poisson_ratio,
    );
    let tip = tip_deflection(&body);
    Row {
        error_timoshenko: Some((tip / timoshenko - 1.0).abs()),
        tip_m: Some(tip),
        ..row(
            if stiff {
                "cantilever-stiff"
            } else {
                "cantilever"
            },
            method,
            m,
            &body,
            (ticks, wall, iterations),
            (tip / CANTILEVER_3D_TIP_M - 1.0).abs(),
        )
    }
}

fn uniaxial(m: usize, method: Method, tolerance: f64) -> Row {
    let config = method.config(tolerance);
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
    let (wall, iterations) = simulate(&mut body, ticks);
    let r = uniaxial_measure(&mut body, strain);
    row(
        "uniaxial",
        method,
        m,
        &body,
        (ticks, wall, iterations),
        r.reaction_error.abs().max(r.nu_error.abs()),
    )
}

/// `run` is (ticks, wall seconds, mean iterations per tick).
fn row(
    case: &'static str,
    method: Method,
    m: usize,
    body: &BoxBody,
    (ticks, wall, iterations): (usize, f64, f64),
    error: f64,
) -> Row {
    let simulated = ticks as f64 * 1e-3;
    Row {
        case,
        mode: method.name,
        points_across: m,
        points: body.model.points.len(),
        spacing_mm: body.model.lattice.spacing * 1e3,
        simulated_s: simulated,
        wall_s: wall,
        wall_s_per_simulated_s: wall / simulated,
        substeps_per_tick: body.solver.substeps(),
        iterations_per_tick: iterations,
        error,
        error_timoshenko: None,
        tip_m: None,
        cost_clock: "wall",
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

fn wanted(choice: &str, name: &str) -> bool {
    choice == "all" || choice == name
}

/// The cut's rows: each resolution's force curve against the reference run's, in the liver
/// scene's own solver mode (explicit).
fn cut_rows(selection: &Selection, json: bool) -> anyhow::Result<Vec<Row>> {
    let mut script = None;
    let reference = accuracy_cut::run_at(selection.cut_reference, &mut script)?;
    let mut rows = Vec::new();
    for &target in &selection.cut_points {
        let s = accuracy_cut::run_at(target, &mut script)?;
        anyhow::ensure!(
            s.force_n.len() == reference.force_n.len(),
            "the cut at {} points ran {} ticks, its reference {}: the same script must give \
             the same ticks",
            s.points,
            s.force_n.len(),
            reference.force_n.len()
        );
        let error = accuracy_cut::curve_error(&s.force_n, &reference.force_n);
        if !json {
            eprintln!(
                "cut {} points: error {error:.3e} against {} points, {:.3} CPU s per simulated s",
                s.points,
                reference.points,
                s.cpu_s / s.simulated_s
            );
        }
        rows.push(Row {
            case: "cut",
            mode: mode_name(s.mode),
            points_across: 0,
            points: s.points,
            spacing_mm: s.spacing_mm,
            simulated_s: s.simulated_s,
            wall_s: s.cpu_s,
            wall_s_per_simulated_s: s.cpu_s / s.simulated_s,
            substeps_per_tick: s.substeps_max,
            iterations_per_tick: 0.0,
            error,
            error_timoshenko: None,
            tip_m: None,
            cost_clock: "process CPU",
        });
    }
    Ok(rows)
}

/// Simulates every selected case, mode and resolution.
fn sweep(selection: &Selection, json: bool) -> anyhow::Result<Vec<Row>> {
    let mut rows = Vec::new();
    for method in METHODS {
        if !wanted(&selection.mode, method.name) {
            continue;
        }
        for m in selection.across.0..=selection.across.1 {
            let before = rows.len();
            if wanted(&selection.case, "cantilever") {
                rows.push(cantilever(m, method, false, selection.implicit_tolerance));
            }
            if wanted(&selection.case, "cantilever-stiff") {
                rows.push(cantilever(m, method, true, selection.implicit_tolerance));
            }
            if wanted(&selection.case, "uniaxial") {
                rows.push(uniaxial(m, method, selection.implicit_tolerance));
            }
            if !json {
                for r in &rows[before..] {
                    eprintln!(
                        "{} {} m = {m}: error {:.3e}, {:.3} s per simulated s, {} sub-steps, \
                         {:.1} iterations per tick",
                        r.case,
                        r.mode,
                        r.error,
                        r.wall_s_per_simulated_s,
                        r.substeps_per_tick,
                        r.iterations_per_tick
                    );
                }
            }
        }
    }
    // The liver scene's own mode is explicit (`run` refuses the cut with another).
    if wanted(&selection.case, "cut") && wanted(&selection.mode, "explicit") {
        rows.extend(cut_rows(selection, json)?);
    }
    Ok(rows)
}

/// Reads a peers file and measures each row's error against the 3D reference.
fn read_peers(path: &Path) -> anyhow::Result<Vec<PeerRow>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let file: PeerFile = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a peers file (tools/bench/peers)", path.display()))?;
    let mut rows = file.rows;
    for r in &mut rows {
        anyhow::ensure!(
            r.tip_m.is_finite() && r.wall_s_per_simulated_s > 0.0,
            "{}: peer {} at {} across has tip {} m and cost {} s per simulated s",
            path.display(),
            r.peer,
            r.across,
            r.tip_m,
            r.wall_s_per_simulated_s
        );
        r.error = (r.tip_m / CANTILEVER_3D_TIP_M - 1.0).abs();
    }
    Ok(rows)
}

/// The fitted slope and plot series of each (case, mode) and each peer.
fn series_of(rows: &[Row], peers: &[PeerRow]) -> (Vec<Fit>, Vec<Series>) {
    let mut fits = Vec::new();
    let mut series = Vec::new();
    let mut add = |case: &'static str, mode: &str, label: &str, points: Vec<(f64, f64)>| {
        if points.is_empty() {
            return;
        }
        let slope = log_slope(&points);
        fits.push(Fit {
            case,
            mode: mode.to_string(),
            slope,
            samples: points.len(),
        });
        series.push(Series {
            label: format!("{label} (slope {slope:.2})"),
            points: points
                .into_iter()
                .filter(|(x, y)| *x > 0.0 && *y > 0.0)
                .collect(),
        });
    };
    for case in CASES {
        for mode in METHODS.map(|m| m.name) {
            let points: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.case == case && r.mode == mode)
                .map(|r| (r.wall_s_per_simulated_s, r.error))
                .collect();
            let label = if case == "cut" {
                format!("scalpel cut (liver stroke, process CPU), {mode}")
            } else {
                format!("scalpel {case}, {mode}")
            };
            add(case, mode, &label, points);
        }
    }
    let mut names: Vec<&str> = peers.iter().map(|p| p.peer.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    for name in names {
        let points = peers
            .iter()
            .filter(|p| p.peer == name)
            .map(|p| (p.wall_s_per_simulated_s, p.error))
            .collect();
        add("cantilever", name, &format!("{name} cantilever"), points);
    }
    (fits, series)
}

fn csv_of(rows: &[Row]) -> String {
    let mut csv = String::from(
        "case,mode,points_across,points,spacing_mm,simulated_s,wall_s,wall_s_per_simulated_s,cost_clock,substeps_per_tick,iterations_per_tick,error,error_timoshenko\n",
    );
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{},{},{:.4},{},{:.6},{:.6},{},{},{:.2},{:.6e},{}",
            r.case,
            r.mode,
            r.points_across,
            r.points,
            r.spacing_mm,
            r.simulated_s,
            r.wall_s,
            r.wall_s_per_simulated_s,
            r.cost_clock,
            r.substeps_per_tick,
            r.iterations_per_tick,
            r.error,
            r.error_timoshenko
                .map(|e| format!("{e:.6e}"))
                .unwrap_or_default()
        );
    }
    csv
}

fn print_table(rows: &[Row], fits: &[Fit], peers: &[PeerRow]) {
    println!(
        "{:<11} {:<15} {:>6} {:>7} {:>8} {:>10} {:>12} {:>12} {:>5} {:>6}",
        "case",
        "mode",
        "across",
        "points",
        "s (mm)",
        "error",
        "vs Timosh.",
        "s per sim s",
        "subst",
        "iter"
    );
    for r in rows {
        println!(
            "{:<11} {:<15} {:>6} {:>7} {:>8.3} {:>10.3e} {:>12} {:>12.4} {:>5} {:>6.1}",
            r.case,
            r.mode,
            r.points_across,
            r.points,
            r.spacing_mm,
            r.error,
            r.error_timoshenko
                .map(|e| format!("{e:.3e}"))
                .unwrap_or_else(|| "-".into()),
            r.wall_s_per_simulated_s,
            r.substeps_per_tick,
            r.iterations_per_tick
        );
    }
    for p in peers {
        println!(
            "{:<11} {:<15} {:>6} {:>7} {:>8} {:>10.3e} {:>12} {:>12.4}",
            "cantilever", p.peer, p.across, p.nodes, "-", p.error, "-", p.wall_s_per_simulated_s
        );
    }
    for f in fits {
        println!(
            "slope of log error vs log cost, {} {}: {:.3}",
            f.case, f.mode, f.slope
        );
    }
}

/// Runs the sweep and writes `accuracy.csv` and `accuracy.png` into `out`.
pub fn run(out: &Path, selection: &Selection, json: bool) -> anyhow::Result<()> {
    let (min_across, max_across) = selection.across;
    anyhow::ensure!(
        min_across >= 3 && max_across >= min_across,
        "points across must be 3 or more, min ≤ max"
    );
    for (what, choice, names) in [
        ("case", &selection.case, &CASES[..]),
        ("mode", &selection.mode, &METHODS.map(|m| m.name)[..]),
    ] {
        anyhow::ensure!(
            choice == "all" || names.contains(&choice.as_str()),
            "--{what} {choice}: expected one of {} or all",
            names.join(", ")
        );
    }
    anyhow::ensure!(
        selection.case != "cut" || matches!(selection.mode.as_str(), "explicit" | "all"),
        "--case cut --mode {}: the cut runs in the liver scene's own mode, explicit (a scene \
         file with `[solver] integrator = \"implicit\"` cuts with `scalpel cut`)",
        selection.mode
    );
    anyhow::ensure!(
        selection
            .cut_points
            .iter()
            .all(|&p| p < selection.cut_reference),
        "--cut-points must all be fewer than --cut-reference ({})",
        selection.cut_reference
    );
    let peers = match &selection.peers {
        Some(path) => read_peers(path)?,
        None => Vec::new(),
    };
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let rows = sweep(selection, json)?;
    let (fits, series) = series_of(&rows, &peers);
    let csv_path = out.join("accuracy.csv");
    std::fs::write(&csv_path, csv_of(&rows))
        .with_context(|| format!("cannot write {}", csv_path.display()))?;
    let plot_path = out.join("accuracy.png");
    log_log(
        &plot_path,
        "Error against run time (beams: 3D reference; block: exact; cut: finest run)",
        "cost per simulated second (s): wall time; the cut's, process CPU time",
        "relative error",
        &series,
    )?;
    if json {
        let report = Report {
            reference_tip_m: CANTILEVER_3D_TIP_M,
            rows,
            fits,
            peers,
            csv: csv_path.display().to_string(),
            plot: plot_path.display().to_string(),
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_table(&rows, &fits, &peers);
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
