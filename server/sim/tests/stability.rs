//! The stiff and extreme cases of physics.md §9: each is stable (the StVK compression is
//! the negative control), and nothing non-finite ever leaves the solver.

use scalpel_sim::validate::stability_cases;

#[test]
fn stability_matrix() {
    let mut failures = Vec::new();
    for case in stability_cases() {
        let r = (case.run)();
        println!(
            "{:<45} stable {:<5} energy ratio {:>8.4} min det F {:>7.4} rollbacks {:>3} nan {}: {}",
            r.name, r.stable, r.max_energy_ratio, r.min_det_f, r.rollbacks, r.nan, r.detail
        );
        if r.nan || (case.expect_stable && !r.stable) {
            failures.push(r.name);
        }
    }
    assert!(failures.is_empty(), "unstable: {failures:?}");
}
