//! `scalpel bench ...`: whole-system figures, reported as medians and tails.

pub mod accuracy;
mod accuracy_cut;
pub mod admission;
pub mod cut_figures;
pub mod cutting;
pub mod loop_bench;
pub mod net;
pub mod session;
pub mod stability;
pub mod stations;

use scalpel_sim::scene::{self, BUILTIN_SCENES};
use serde::Serialize;

use crate::load;
use crate::progress::StageProgress;

/// Build-time figures of one scene.
#[derive(Serialize)]
struct SceneBuildBench {
    name: &'static str,
    triangles: usize,
    points: usize,
    runs: usize,
    build_ms_median: f64,
    build_ms_min: f64,
    build_ms_max: f64,
    /// Median of each stage (ms).
    stages_ms_median: std::collections::BTreeMap<&'static str, f64>,
}

/// Median of a non-empty sample.
pub fn median(values: &mut [f64]) -> f64 {
    crate::stats::median(values)
}

/// Builds every built-in scene `runs` times and reports the build times.
pub fn scenes(runs: usize, json: bool) -> anyhow::Result<()> {
    anyhow::ensure!(runs >= 1, "--runs must be at least 1");
    let mut rows = Vec::new();
    for name in BUILTIN_SCENES {
        let spec = scene::builtin(name).expect("built-in scene");
        let mut totals = Vec::with_capacity(runs);
        let mut stages: std::collections::BTreeMap<&'static str, Vec<f64>> = Default::default();
        let mut counts = (0, 0);
        for _ in 0..runs {
            let mut display = StageProgress::new(name);
            let timed = load::build_timed(&spec, &mut display)?;
            display.finish();
            totals.push(timed.build_ms);
            for (k, v) in &timed.stages_ms {
                stages.entry(k).or_default().push(*v);
            }
            counts = (
                timed.scene.mesh_stats.triangles,
                timed.scene.model.points.len(),
            );
        }
        let min = totals.iter().copied().fold(f64::INFINITY, f64::min);
        let max = totals.iter().copied().fold(0.0, f64::max);
        rows.push(SceneBuildBench {
            name,
            triangles: counts.0,
            points: counts.1,
            runs,
            build_ms_median: median(&mut totals),
            build_ms_min: min,
            build_ms_max: max,
            stages_ms_median: stages
                .into_iter()
                .map(|(k, mut v)| (k, median(&mut v)))
                .collect(),
        });
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!(
            "{:<10} {:>9} {:>7} {:>6} {:>10} {:>8} {:>8}",
            "scene", "triangles", "points", "runs", "median ms", "min ms", "max ms"
        );
        for r in &rows {
            println!(
                "{:<10} {:>9} {:>7} {:>6} {:>10.1} {:>8.1} {:>8.1}",
                r.name,
                r.triangles,
                r.points,
                r.runs,
                r.build_ms_median,
                r.build_ms_min,
                r.build_ms_max
            );
        }
    }
    Ok(())
}

/// Prints `report` as pretty JSON, or for people with `text`.
pub fn emit<T: Serialize>(json: bool, report: &T, text: impl FnOnce(&T)) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(report)?);
    } else {
        text(report);
    }
    Ok(())
}
