//! The cut's series of `scalpel bench accuracy` (issue 46): the default liver stroke at
//! several resolutions, each run's force curve against a fine run's.
//!
//! The error is the relative RMS difference of the force magnitude on the blade, tick by
//! tick (the same script at 1 kHz, so the ticks align), over the whole stroke. The cost is
//! the process's CPU time per simulated second: it counts the re-cut worker's time too (a
//! worker's time belongs to the step it serves), not only the simulation thread's.

use scalpel_sim::model::SpacingRule;
use scalpel_sim::pipeline::CutScript;
use scalpel_sim::scene::{self, BuiltScene};
use scalpel_sim::solver::SolverMode;

use crate::cutrun::{self, TICK_S};
use crate::load;
use crate::progress::StageProgress;

/// The resolutions of the series (target points) and of the reference run.
pub const CUT_POINTS: [usize; 3] = [1_500, 3_000, 6_000];
pub const CUT_REFERENCE_POINTS: usize = 15_000;

/// One resolution's run.
pub struct CutSample {
    /// Points sampled.
    pub points: usize,
    /// Lattice spacing (mm).
    pub spacing_mm: f64,
    /// Simulated time (s).
    pub simulated_s: f64,
    /// Process CPU time over the run (s), every thread's.
    pub cpu_s: f64,
    /// The most sub-steps a tick took.
    pub substeps_max: u32,
    /// The scene's solver mode.
    pub mode: SolverMode,
    /// |force on the blade| per tick (N).
    pub force_n: Vec<f64>,
}

/// CPU time of the whole process (s): the simulation thread and the re-cut worker.
fn process_cpu_s() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

fn liver_at(points: usize) -> anyhow::Result<BuiltScene> {
    let mut spec = scene::builtin("liver").expect("built-in scene");
    spec.sampling.spacing = SpacingRule::TargetPoints(points);
    spec.name = format!("liver@{points}");
    let mut display = StageProgress::new(&spec.name);
    let timed = load::build_timed(&spec, &mut display)?;
    display.finish();
    Ok(timed.scene)
}

/// Runs the default liver stroke (the same at every resolution: the surface is the same)
/// with the organ sampled at about `points` points.
pub fn run_at(points: usize, script: &mut Option<CutScript>) -> anyhow::Result<CutSample> {
    let scene = liver_at(points)?;
    let script = match script {
        Some(s) => s,
        None => script.insert(CutScript::default_for(
            &scalpel_sim::pipeline::start_surface(&scene),
        )?),
    };
    let start = process_cpu_s();
    let run = cutrun::run_cut(&scene, script, 1, 0, |_, _| {})?;
    let cpu_s = process_cpu_s() - start;
    Ok(CutSample {
        points: scene.model.points.len(),
        spacing_mm: scene.model.lattice.spacing * 1e3,
        simulated_s: run.rows.len() as f64 * TICK_S,
        cpu_s,
        substeps_max: run.rows.iter().map(|r| r.substeps).max().unwrap_or(0),
        mode: run.sim.solver().config().mode,
        force_n: run.rows.iter().map(|r| r.force_mag_n).collect(),
    })
}

/// ‖f − f_ref‖₂ / ‖f_ref‖₂ over the ticks both runs have.
pub fn curve_error(force: &[f64], reference: &[f64]) -> f64 {
    let (diff, norm) = force
        .iter()
        .zip(reference)
        .fold((0.0, 0.0), |(d, n), (f, r)| {
            (d + (f - r).powi(2), n + r * r)
        });
    if norm > 0.0 {
        (diff / norm).sqrt()
    } else {
        f64::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curve_error_is_relative_rms() {
        assert_eq!(curve_error(&[1.0, 2.0], &[1.0, 2.0]), 0.0);
        let e = curve_error(&[1.1, 2.2], &[1.0, 2.0]);
        assert!((e - 0.1).abs() < 1e-12, "{e}");
        assert!(curve_error(&[1.0], &[0.0]).is_nan());
    }
}
