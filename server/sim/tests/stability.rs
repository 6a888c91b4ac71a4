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

/// A cut that leaves a point's fit nearly degenerate (here its four neighbours in a plane a
/// thirtieth of a spacing below it: cond(A) in the hundreds, under the rank test's 10⁴)
/// makes that fit's points many times stiffer than the body; on the old code the step
/// shrank with them (over a session on the shoulder, 6 → 448 sub-steps per tick). Now those
/// points get mass instead: the tick's sub-steps stay within √2 of the uncut body's, and
/// the fit's points are the ones that got it.
#[test]
fn a_fit_left_degenerate_by_a_cut_adds_mass_not_sub_steps() {
    use scalpel_sim::validate::{LatticeCube, cut_down_to};
    let s = 0.003;
    let cube = LatticeCube::new(7, s);
    let mut rest = cube.rest.clone();
    let centre = cube.centre();
    // The centre a thirtieth of a spacing above its layer: whole, its fit does not mind.
    rest[centre].z += s / 30.0;
    let mut neighbours = cube.neighbours(&rest, 8);
    let volume = vec![s * s * s; rest.len()];
    let mass: Vec<f64> = volume.iter().map(|v| v * 1060.0).collect();
    let mut solver = cube.soft_solver(&rest, &volume, &mass, &neighbours);
    let uncut = solver.step(1e-3).substeps;
    // Cut down to its four neighbours in its layer, all just below it.
    let keep = cube.layer_around_centre();
    let changed = cut_down_to(&mut neighbours, centre, &keep);
    solver.topology_changed(&changed, &neighbours);
    let condition = solver.operator().point(centre).condition;
    let cut = solver.step(1e-3).substeps;
    let (points, kg) = solver.added_mass();
    println!(
        "cond {condition:.0}, sub-steps {uncut} → {cut}, mass added to {points} points: {kg:.2e} kg"
    );
    assert!(
        condition > 100.0,
        "the fit should be nearly degenerate: {condition}"
    );
    assert!(
        f64::from(cut) <= (f64::from(uncut) * 2f64.sqrt()).ceil(),
        "{uncut} → {cut} sub-steps"
    );
    assert!(
        points > 0 && points <= keep.len() + 1,
        "{points} points given mass"
    );
}
