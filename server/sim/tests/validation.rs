//! The analytic benchmarks of physics.md §8 (B1, B2, B3, B5, B5T, B5b, B6, B9, B11, B12) and
//! cutting-physics.md §1 and §4 (B13, B14, B15) pass their bands. The same functions back
//! `scalpel validate`.

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use scalpel_sim::validate;

#[test]
fn every_benchmark_passes() {
    // Two at a time (the machine's two cores; none is timed), reported in order.
    let benchmarks = validate::all();
    let next = AtomicUsize::new(0);
    let results = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| {
                loop {
                    let k = next.fetch_add(1, Ordering::Relaxed);
                    let Some(b) = benchmarks.get(k) else { break };
                    let r = (b.run)();
                    results.lock().unwrap().push((k, r));
                }
            });
        }
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by_key(|(k, _)| *k);
    let mut failures = Vec::new();
    for (_, r) in results {
        println!(
            "{} {:<70} error {:.3e} (band {:.2e}) {}: {}",
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

/// The 3D references compiled into the benchmarks are the ones the reference script stored
/// (tools/reference/reference.json, from tools/reference/fem_reference.py).
#[test]
fn compiled_references_match_the_stored_result() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tools/reference/reference.json"
    );
    let text = std::fs::read_to_string(path).expect("the stored reference is in the repository");
    let stored: serde_json::Value = serde_json::from_str(&text).expect("it is JSON");
    for (case, compiled) in [
        ("cantilever", validate::CANTILEVER_3D_TIP_M),
        ("slender_cantilever", validate::SLENDER_CANTILEVER_3D_TIP_M),
    ] {
        let tip = stored[case]["tip_m"].as_f64().expect("an extrapolated tip");
        assert!(
            (compiled / tip - 1.0).abs() < 1e-6,
            "{case}: compiled {compiled:e} m, stored {tip:e} m: copy the stored value"
        );
        // Beam theory is softer than the clamped 3D beam, more so for the short one.
        let timoshenko = stored[case]["timoshenko_over_reference"].as_f64().unwrap();
        assert!(
            timoshenko > 1.0 && timoshenko < 1.05,
            "{case}: {timoshenko}"
        );
    }
    let punch = stored["punch"]["stiffness_n_per_mm"]
        .as_f64()
        .expect("an extrapolated stiffness");
    let compiled = validate::PUNCH_BLOCK_3D_N_PER_MM;
    assert!(
        (compiled / punch - 1.0).abs() < 1e-6,
        "punch: compiled {compiled} N/mm, stored {punch} N/mm: copy the stored value"
    );
}

/// physics.md §9, "Müller-literal check": MuellerCompat with E/4 gives the same motion as
/// StVK with E (the literal form has four times the stiffness).
#[test]
fn mueller_compat_with_a_quarter_of_e_matches_stvk() {
    use scalpel_sim::math::Vec3;
    use scalpel_sim::mls::ElasticModel;
    use scalpel_sim::scene::Material;
    use scalpel_sim::solver::SolverConfig;
    use scalpel_sim::validate::box_body;
    let run = |model: ElasticModel, e: f64| {
        let material = Material {
            youngs_modulus_pa: e,
            ..Material::LIVER
        };
        let config = SolverConfig {
            model,
            ..SolverConfig::default()
        };
        let mut body = box_body(Vec3::new(0.02, 0.01, 0.01), 5, &material, 2.0, config);
        let p: Vec<Vec3> = body
            .model
            .points
            .rest
            .iter()
            .enumerate()
            .map(|(i, x)| x + Vec3::new((i as f64).sin(), 0.5, (i as f64).cos()) * 1e-4)
            .collect();
        body.solver.set_positions(&p);
        for _ in 0..50 {
            body.solver.step(1e-3);
        }
        (body.solver.positions().to_vec(), body.solver.substeps())
    };
    let (stvk, n1) = run(ElasticModel::StVK, 8000.0);
    let (mueller, n2) = run(ElasticModel::MuellerCompat, 2000.0);
    assert_eq!(n1, n2, "same dt_crit, same sub-steps");
    let scale = 1e-4;
    for (a, b) in stvk.iter().zip(&mueller) {
        assert!((a - b).norm() < 1e-9 * scale, "{a} vs {b}");
    }
}

#[test]
fn scene_features_select_the_solver() {
    use scalpel_sim::scene::{Features, Integrator, Material, SolverSpec};
    use scalpel_sim::solver::{SolverConfig, SolverMode};
    let stiff = Features {
        stiff_mode: true,
        volume_term: true,
        ..Features::default()
    };
    let default = SolverSpec::default();
    let c = SolverConfig::for_scene(&stiff, &Material::LIVER, &default);
    assert_eq!(c.mode, SolverMode::Projective);
    assert!(c.volume_k_pa > 0.0);
    let plain = SolverConfig::for_scene(&Features::default(), &Material::LIVER, &default);
    assert_eq!(plain.mode, SolverMode::Explicit);
    assert_eq!(plain.volume_k_pa, 0.0);
    assert_eq!(plain.mass_scaling_budget, 0.01);
    let unscaled = SolverSpec {
        mass_scaling_budget: 0.0,
        ..default
    };
    let c = SolverConfig::for_scene(&Features::default(), &Material::LIVER, &unscaled);
    assert_eq!(c.mass_scaling_budget, 0.0);
    let implicit = SolverSpec {
        integrator: Integrator::Implicit,
        ..default
    };
    let c = SolverConfig::for_scene(&Features::default(), &Material::LIVER, &implicit);
    assert_eq!(c.mode, SolverMode::Implicit);
}

/// The implicit mode comes to the same rest as the explicit one (the cantilever's tip under
/// its load, 5 across), in one CG-solved step a tick whose iterations stay few, and on a
/// stiff beam (E = 1 MPa) it takes one step where the explicit mode takes dozens.
#[test]
fn the_implicit_mode_settles_where_the_explicit_mode_does() {
    use scalpel_sim::scene::Material;
    use scalpel_sim::solver::{ImplicitPreconditioner, SolverConfig, SolverMode};
    use scalpel_sim::validate::{cantilever_body, tip_deflection};
    for (e, damping) in [(5e3, 28.0), (1e6, 400.0)] {
        let material = Material {
            youngs_modulus_pa: e,
            damping_per_s: damping,
            ..Material::LIVER
        };
        let load = 1e-4 * e / 5e3;
        let settle = |mode, preconditioner| {
            let config = SolverConfig {
                mode,
                implicit_preconditioner: preconditioner,
                ..SolverConfig::default()
            };
            let mut body = cantilever_body(0.040, 0.010, 5, load, &material, config);
            let mut iterations = 0;
            for _ in 0..800 {
                let r = body.solver.step(1e-3);
                assert!(!r.diverged && r.rollbacks == 0);
                iterations += r.iterations;
            }
            (tip_deflection(&body), iterations, body.solver.substeps())
        };
        let (explicit, _, substeps) = settle(SolverMode::Explicit, ImplicitPreconditioner::Jacobi);
        for preconditioner in [
            ImplicitPreconditioner::Jacobi,
            ImplicitPreconditioner::Factored,
            ImplicitPreconditioner::TwoLevel,
        ] {
            let (implicit, iterations, one) = settle(SolverMode::Implicit, preconditioner);
            assert_eq!(one, 1);
            assert!(
                (implicit / explicit - 1.0).abs() < 2e-3,
                "E = {e}, {preconditioner:?}: tip {implicit} against {explicit}"
            );
            assert!(
                iterations > 0 && iterations < 40 * 800,
                "E = {e}, {preconditioner:?}: {iterations} CG iterations in 800 ticks"
            );
        }
        if e > 1e5 {
            assert!(
                substeps >= 30,
                "the stiff beam's explicit sub-steps: {substeps}"
            );
        }
    }
}

/// B15 on finer lattices (5 minutes, so not in CI; the decisions log quotes it): the
/// slit's opening past the finite strip's converges as the spacing shrinks against the slit,
/// and so does its shape. `cargo test --release -p scalpel-sim --test validation
/// griffith_refined -- --ignored --nocapture`.
#[test]
#[ignore]
fn griffith_refined() {
    let strip = validate::finite_width_opening_factor(0.25);
    let mut last = (f64::INFINITY, f64::INFINITY);
    for n in [6.5, 9.5, 12.5] {
        let r = validate::slit_in_stretched_plate(n, true);
        let excess = r.centre_ratio() / strip - 1.0;
        println!(
            "a = {n} spacings: centre ratio {:.4} ({:+.2} % past the strip), shape RMS {:.4}, converged {}",
            r.centre_ratio(),
            100.0 * excess,
            r.shape_rms(),
            r.converged
        );
        assert!(r.converged);
        assert!(excess > 0.0 && excess < last.0, "{excess} after {}", last.0);
        assert!(r.shape_rms() < last.1);
        last = (excess, r.shape_rms());
    }
}
