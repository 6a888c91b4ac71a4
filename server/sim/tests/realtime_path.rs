//! The simulation step is on the real-time path: after warm-up it must not allocate, and
//! it must be deterministic (two runs bitwise equal). (A cutting tick's allocations are
//! counted with the station's re-cut worker: server/tests/cutting_realtime.rs.)

// A counting global allocator needs `unsafe impl GlobalAlloc`; this test crate allows it.
#![allow(unsafe_code)]

#[path = "common/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations;
use scalpel_sim::math::Vec3;
use scalpel_sim::model::CoupledModel;
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{Material, build_scene, builtin};
use scalpel_sim::solver::{Solver, SolverConfig, SolverMode};

fn model(name: &str) -> CoupledModel {
    build_scene(&builtin(name).unwrap(), None, &mut Silent)
        .unwrap()
        .model
}

/// A solver on `model` with a deterministic perturbation, a clamped face and a load, so
/// every part of the step (forces, constraints, loads) is exercised.
fn prepared(model: &CoupledModel, mode: SolverMode) -> Solver {
    prepared_with(model, mode, &Material::LIVER)
}

/// [`prepared`] with another material.
fn prepared_with(model: &CoupledModel, mode: SolverMode, material: &Material) -> Solver {
    let config = SolverConfig {
        mode,
        ..SolverConfig::default()
    };
    prepared_from(model, material, config)
}

/// [`prepared`] with any configuration.
fn prepared_from(model: &CoupledModel, material: &Material, config: SolverConfig) -> Solver {
    let mut solver = Solver::for_model(model, material, config);
    let p: Vec<Vec3> = model
        .points
        .rest
        .iter()
        .enumerate()
        .map(|(i, x)| {
            x + Vec3::new(
                (i as f64).sin(),
                (1.3 * i as f64).cos(),
                (0.7 * i as f64).sin(),
            ) * 1e-4
        })
        .collect();
    solver.set_positions(&p);
    let lowest = model
        .points
        .rest
        .iter()
        .map(|x| x.z)
        .fold(f64::INFINITY, f64::min);
    for (i, x) in model.points.rest.iter().enumerate() {
        if x.z < lowest + 1e-9 {
            solver.fix(i, [true; 3]);
        }
    }
    solver.set_external_force(0, Vec3::new(0.0, 0.0, -1e-3));
    solver
}

#[test]
fn step_does_not_allocate_after_warm_up() {
    let model = model("liver");
    for mode in [
        SolverMode::Explicit,
        SolverMode::Projective,
        SolverMode::Implicit,
        SolverMode::QuasiStatic,
    ] {
        let mut solver = prepared(&model, mode);
        // Warm-up: the first ticks compute dt_crit or factor the projective matrix.
        for _ in 0..3 {
            solver.step(1e-3);
            while solver.poll_event().is_some() {}
        }
        let ticks = if mode == SolverMode::QuasiStatic {
            5
        } else {
            50
        };
        let before = allocations();
        for t in 0..ticks {
            // A moving constraint target, as a tool would set each tick.
            solver.set_target(
                0,
                model.points.rest[0] + Vec3::new(0.0, 0.0, -1e-5 * t as f64),
            );
            solver.step(1e-3);
            while solver.poll_event().is_some() {}
        }
        let during = allocations() - before;
        assert_eq!(
            during, 0,
            "{mode:?}: {during} allocations in {ticks} ticks after warm-up"
        );
    }
}

#[test]
fn rollbacks_do_not_allocate_either() {
    // A step far above dt_crit makes the guard roll back and retry inside the tick.
    let model = model("block");
    let dt_crit = Solver::for_model(&model, &Material::LIVER, SolverConfig::default()).dt_crit();
    let config = SolverConfig {
        dt_override_s: Some(10.0 * dt_crit),
        ..SolverConfig::default()
    };
    let mut solver = Solver::for_model(&model, &Material::LIVER, config);
    let p: Vec<Vec3> = model
        .points
        .rest
        .iter()
        .enumerate()
        .map(|(i, x)| x + Vec3::new((i as f64).sin(), 0.0, 0.0) * 5e-5)
        .collect();
    solver.set_positions(&p);
    solver.dt_crit();
    let before = allocations();
    let mut rollbacks = 0;
    for _ in 0..5 {
        rollbacks += solver.step(10.0 * dt_crit).rollbacks;
        while solver.poll_event().is_some() {}
    }
    assert!(rollbacks > 0, "the guard should have rolled back");
    assert_eq!(allocations() - before, 0);
}

/// A blow-up that no sub-step can cure (a load that is not finite) is given up after the
/// guard's five doublings, not chased to 65 536 sub-steps: a tick of the simulation thread
/// stays bounded (the lagged virtual-point loop once made ticks of 3.8 s that way), and the
/// state that leaves is the tick's start, finite and at rest.
#[test]
fn a_blow_up_more_sub_steps_cannot_cure_is_given_up_within_bounds() {
    let model = model("block");
    let mut solver = Solver::for_model(&model, &Material::LIVER, SolverConfig::default());
    solver.step(1e-3);
    let planned = solver.substeps();
    let start: Vec<Vec3> = solver.positions().to_vec();
    solver.set_external_force(0, Vec3::new(f64::NAN, 0.0, 0.0));
    let report = solver.step(1e-3);
    assert!(report.diverged, "{report:?}");
    assert_eq!(report.rollbacks, SolverConfig::default().max_rollbacks);
    assert!(report.substeps <= 32 * planned, "{report:?}");
    assert_eq!(solver.positions(), &start[..]);
    assert!(solver.velocities().iter().all(|v| *v == Vec3::zeros()));
}

/// Every coordinate's bits, for bitwise comparisons.
fn position_bits(solver: &Solver) -> Vec<u64> {
    solver
        .positions()
        .iter()
        .flat_map(|p| p.iter().map(|x| x.to_bits()))
        .collect()
}

#[test]
fn runs_are_bitwise_deterministic() {
    let model = model("liver");
    for mode in [SolverMode::Explicit, SolverMode::Projective] {
        let run = || {
            let mut solver = prepared(&model, mode);
            for _ in 0..40 {
                solver.step(1e-3);
            }
            position_bits(&solver)
        };
        assert_eq!(run(), run(), "{mode:?}");
    }
}

#[test]
fn an_explicit_active_set_of_everything_changes_nothing() {
    let model = model("liver");
    let run = |restrict: bool| {
        let mut solver = prepared(&model, SolverMode::Explicit);
        if restrict {
            let all: Vec<u32> = (0..model.points.len() as u32).collect();
            solver.set_active(&all);
        }
        for _ in 0..20 {
            solver.step(1e-3);
        }
        position_bits(&solver)
    };
    assert_eq!(run(false), run(true));
}

#[test]
fn frozen_points_stay_put_and_the_active_region_moves() {
    let model = model("liver");
    let mut solver = prepared(&model, SolverMode::Explicit);
    // Activate the points within 2 cm of the first point.
    let centre = model.points.rest[model.points.len() / 2];
    let active: Vec<u32> = (0..model.points.len() as u32)
        .filter(|&i| (model.points.rest[i as usize] - centre).norm() < 0.02)
        .collect();
    assert!(active.len() > 10 && active.len() < model.points.len() / 2);
    solver.set_active(&active);
    let before = solver.positions().to_vec();
    for _ in 0..20 {
        solver.step(1e-3);
    }
    let after = solver.positions();
    let mut moved_active = 0;
    for i in 0..before.len() {
        if active.binary_search(&(i as u32)).is_ok() {
            moved_active += usize::from(after[i] != before[i]);
        } else {
            assert_eq!(after[i], before[i], "frozen point {i} moved");
        }
    }
    assert!(moved_active > 0);
    // Restricting also must not allocate per tick.
    let before = allocations();
    for _ in 0..10 {
        solver.step(1e-3);
        solver.set_active(&active);
    }
    assert_eq!(allocations() - before, 0);
}

/// An instructor's tissue-stiffness fault changes E on a running solver: it must then step
/// like a solver built with that E (constants, preconditioner and time step re-derived),
/// and the change itself must not allocate.
#[test]
fn changing_youngs_modulus_matches_a_solver_built_with_it_and_does_not_allocate() {
    let m = model("liver");
    let stiffer = Material {
        youngs_modulus_pa: Material::LIVER.youngs_modulus_pa * 2.5,
        ..Material::LIVER
    };
    for mode in [SolverMode::Explicit, SolverMode::QuasiStatic] {
        let mut changed = prepared_with(&m, mode, &Material::LIVER);
        // Known before the change: it is scaled, not searched for again.
        let soft_dt = changed.dt_crit();
        let before = allocations();
        changed.set_youngs_modulus(stiffer.youngs_modulus_pa);
        assert_eq!(allocations() - before, 0, "{mode:?}");
        let mut built = prepared_with(&m, mode, &stiffer);
        let rest = prepared_with(&m, mode, &Material::LIVER);
        let (scaled, searched) = (changed.dt_crit(), built.dt_crit());
        assert!((scaled * 2.5f64.sqrt() - soft_dt).abs() < 1e-12 * soft_dt);
        assert!(
            (scaled / searched - 1.0).abs() < 0.02,
            "{mode:?}: dt_crit scaled {scaled}, searched {searched}"
        );
        for _ in 0..5 {
            changed.step(1e-3);
            built.step(1e-3);
        }
        let gap = |a: &Solver, b: &Solver| {
            a.positions()
                .iter()
                .zip(b.positions())
                .map(|(x, y)| (x - y).norm())
                .fold(0.0, f64::max)
        };
        let moved = gap(&built, &rest);
        let error = gap(&changed, &built);
        assert!(moved > 1e-7, "{mode:?}: the solver should move ({moved})");
        assert!(error <= 1e-9 * moved, "{mode:?}: {error} against {moved}");
    }
}

/// The optional two-thread force evaluation (a caller's rayon pool, `Solver::use_pool`) gives
/// the serial run's bits, on the whole body and on an active region.
#[test]
fn two_threads_give_the_serial_bits() {
    let model = model("liver");
    let pooled = |solver: &mut Solver, threads: usize| {
        if threads > 1 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a pool");
            solver.use_pool(std::sync::Arc::new(pool));
        }
    };
    let run = |threads: usize, region: bool| {
        let mut solver = prepared_from(&model, &Material::LIVER, SolverConfig::default());
        pooled(&mut solver, threads);
        if region {
            let some: Vec<u32> = (0..model.points.len() as u32).step_by(3).collect();
            solver.set_active(&some);
        }
        for _ in 0..30 {
            solver.step(1e-3);
        }
        position_bits(&solver)
    };
    for region in [false, true] {
        let serial = run(1, region);
        assert_eq!(serial, run(2, region), "region {region}");
        assert_eq!(serial, run(3, region), "region {region}");
    }
    // Outside a tick (here `elastic_forces`) the evaluation goes into the solver's pool too,
    // with the same bits.
    let forces = |threads: usize| {
        let mut solver = prepared_from(&model, &Material::LIVER, SolverConfig::default());
        pooled(&mut solver, threads);
        let (f, _) = solver.elastic_forces();
        f.iter()
            .flat_map(|g| g.iter().map(|x| x.to_bits()))
            .collect::<Vec<u64>>()
    };
    assert_eq!(forces(1), forces(2));
}
