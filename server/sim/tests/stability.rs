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
/// thirtieth of a spacing below it: cond(A) in the hundreds, under the rank test's 10⁴) makes that fit's points many times
/// stiffer than the body; on the old code the step shrank with them (over a session on the
/// shoulder, 6 → 448 sub-steps per tick). Now those points get mass instead: the tick's
/// sub-steps stay within √2 of the uncut body's, and the fit's points are the ones that
/// got it.
#[test]
fn a_fit_left_degenerate_by_a_cut_adds_mass_not_sub_steps() {
    use scalpel_sim::math::Vec3;
    use scalpel_sim::model::{Kernel, Neighbourhoods, RestGrid};
    use scalpel_sim::solver::{Solver, SolverConfig};
    let s = 0.003;
    let n = 7;
    let mut rest = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                rest.push(Vec3::new(i as f64, j as f64, k as f64) * s);
            }
        }
    }
    let id = |i: usize, j: usize, k: usize| (i * n + j) * n + k;
    let centre = id(3, 3, 3);
    // The centre a thirtieth of a spacing above its layer: whole, its fit does not mind.
    rest[centre].z += s / 30.0;
    let h = 2.0 * s;
    let grid = RestGrid::build(&rest, h);
    let mut neighbours = Neighbourhoods::build(&rest, &grid, h, 8);
    let volume = vec![s * s * s; rest.len()];
    let mass: Vec<f64> = volume.iter().map(|v| v * 1060.0).collect();
    let mut solver = Solver::new(
        &rest,
        &volume,
        &mass,
        &neighbours,
        Kernel { support_m: h },
        s,
        None,
        5e3,
        0.45,
        SolverConfig::default(),
    );
    let uncut = solver.step(1e-3).substeps;
    // Cut down to its four neighbours in its layer, all just below it.
    let keep: Vec<u32> = [id(4, 3, 3), id(2, 3, 3), id(3, 4, 3), id(3, 2, 3)]
        .map(|i| i as u32)
        .to_vec();
    let mut changed = vec![centre as u32];
    for j in neighbours.of(centre).to_vec() {
        if !keep.contains(&j) {
            neighbours.remove(centre, j);
            neighbours.remove(j as usize, centre as u32);
            changed.push(j);
        }
    }
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
