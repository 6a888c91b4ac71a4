//! `scalpel bench stability`: the stiff and extreme cases of physics.md §9.

use std::time::Instant;

use scalpel_sim::validate::{StabilityResult, stability_cases};
use serde::Serialize;

#[derive(Serialize)]
struct Row {
    #[serde(flatten)]
    result: StabilityResult,
    /// False for the negative control.
    expected_stable: bool,
    wall_ms: f64,
}

/// Runs every case; fails if a case is not as expected or anything went non-finite.
pub fn run(json: bool) -> anyhow::Result<()> {
    let mut rows = Vec::new();
    for case in stability_cases() {
        let start = Instant::now();
        let result = (case.run)();
        rows.push(Row {
            result,
            expected_stable: case.expect_stable,
            wall_ms: start.elapsed().as_secs_f64() * 1e3,
        });
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!(
            "{:<52} {:>6} {:>9} {:>9} {:>9} {:>4} {:>8}",
            "case", "stable", "E ratio", "min detF", "rollbacks", "nan", "ms"
        );
        for r in &rows {
            let x = &r.result;
            let mark = if x.stable == r.expected_stable {
                ""
            } else {
                "  <-- unexpected"
            };
            println!(
                "{:<52} {:>6} {:>9.4} {:>9.4} {:>9} {:>4} {:>8.1}{mark}",
                x.name, x.stable, x.max_energy_ratio, x.min_det_f, x.rollbacks, x.nan, r.wall_ms
            );
            println!("    {}", x.detail);
        }
    }
    let bad: Vec<&str> = rows
        .iter()
        .filter(|r| r.result.nan || r.result.stable != r.expected_stable)
        .map(|r| r.result.name)
        .collect();
    anyhow::ensure!(
        bad.is_empty(),
        "unexpected stability results: {}",
        bad.join(", ")
    );
    Ok(())
}
