//! `scalpel validate`: the analytic benchmarks of physics.md §8.

use std::time::Instant;

use scalpel_sim::validate::{BenchmarkResult, all};
use serde::Serialize;

#[derive(Serialize)]
struct Row {
    #[serde(flatten)]
    result: BenchmarkResult,
    wall_ms: f64,
}

/// Runs every benchmark (or those named in `only`); fails (exit status 1) if any is
/// outside its band.
pub fn run(json: bool, only: &[String]) -> anyhow::Result<()> {
    let benchmarks = all();
    for name in only {
        anyhow::ensure!(
            benchmarks.iter().any(|b| b.name.eq_ignore_ascii_case(name)),
            "unknown benchmark '{name}'; choose from {}",
            benchmarks
                .iter()
                .map(|b| b.name)
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let mut rows = Vec::new();
    for b in benchmarks {
        if !only.is_empty() && !only.iter().any(|n| b.name.eq_ignore_ascii_case(n)) {
            continue;
        }
        let start = Instant::now();
        let result = (b.run)();
        rows.push(Row {
            result,
            wall_ms: start.elapsed().as_secs_f64() * 1e3,
        });
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        for r in &rows {
            let x = &r.result;
            println!(
                "{:<4} {:<4} error {:>9.2e} (band {:.2e}) {:>8.1} ms  {}",
                x.name,
                if x.pass { "pass" } else { "FAIL" },
                x.error,
                x.tolerance,
                r.wall_ms,
                x.title
            );
            println!("          {}", x.detail);
        }
        let passed = rows.iter().filter(|r| r.result.pass).count();
        println!("{passed} of {} benchmarks within their bands", rows.len());
    }
    let failed: Vec<&str> = rows
        .iter()
        .filter(|r| !r.result.pass)
        .map(|r| r.result.name)
        .collect();
    anyhow::ensure!(
        failed.is_empty(),
        "benchmarks outside their bands: {}",
        failed.join(", ")
    );
    Ok(())
}
