//! The analytic benchmarks of physics.md §8 (B1, B2, B3, B5, B5b, B6, B9, B11, B12) pass
//! their bands. The same functions back `scalpel validate`.

use scalpel_sim::validate;

#[test]
fn every_benchmark_passes() {
    let mut failures = Vec::new();
    for b in validate::all() {
        let r = (b.run)();
        println!(
            "{} {:<70} error {:.3e} (band {:.0e}) {}: {}",
            r.name,
            r.title,
            r.error,
            r.tolerance,
            if r.pass { "pass" } else { "FAIL" },
            r.detail
        );
        if !r.pass {
            failures.push(r.name);
        }
    }
    assert!(failures.is_empty(), "failed: {failures:?}");
}
