//! Speed of the elastic force evaluation and of one 1 ms tick (with its sub-steps) at the
//! point counts of the paper's Table 1 (liver 1526, shoulder 4812, cerebroma 7086), all with
//! the liver material (E = 5 kPa, ν = 0.45), explicit mode; plus a projective (stiff mode)
//! tick. Run: `cargo bench -p scalpel-sim --bench solver`.

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use scalpel_sim::math::Vec3;
use scalpel_sim::mls::add_elastic_forces;
use scalpel_sim::mls::forces::{ForceScratch, Threads};
use scalpel_sim::model::CoupledModel;
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{Material, build_scene, builtin};
use scalpel_sim::solver::{Solver, SolverConfig, SolverMode};

fn model(name: &str) -> CoupledModel {
    build_scene(&builtin(name).expect("built-in"), None, &mut Silent)
        .expect("builds")
        .model
}

/// A solver on the scene with every point slightly displaced, so forces are non-trivial.
fn solver(model: &CoupledModel, mode: SolverMode, threads: usize) -> Solver {
    let config = SolverConfig {
        mode,
        ..SolverConfig::default()
    };
    let mut solver = Solver::for_model(model, &Material::LIVER, config);
    if threads > 1 {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a pool");
        solver.use_pool(std::sync::Arc::new(pool));
    }
    let s = model.lattice.spacing;
    let p: Vec<Vec3> = model
        .points
        .rest
        .iter()
        .enumerate()
        .map(|(i, x)| {
            x + Vec3::new(
                (i as f64).sin(),
                (1.7 * i as f64).cos(),
                (0.3 * i as f64).sin(),
            ) * (0.01 * s)
        })
        .collect();
    solver.set_positions(&p);
    solver
}

fn force_evaluation(c: &mut Criterion) {
    force_evaluation_with(
        c,
        "force_evaluation",
        &["liver", "shoulder", "cerebroma"],
        Threads::One,
    );
}

/// The same without the lattice stencil: every point through the pair kernels (the
/// stencil runs and the single-point kernel), as a cut region is evaluated.
fn force_evaluation_pair_kernels(c: &mut Criterion) {
    force_evaluation_with(
        c,
        "force_evaluation_pair_kernels",
        &["liver", "shoulder", "cerebroma"],
        Threads::One,
    );
}

/// The force evaluation split over two threads (rayon), measured from inside a pool of two
/// as the solver runs it (`Solver::use_pool` with a pool of two). Meaningful on a machine with two
/// free cores.
fn force_evaluation_two_threads(c: &mut Criterion) {
    force_evaluation_with(
        c,
        "force_evaluation_2_threads",
        &["cerebroma"],
        Threads::Rayon,
    );
}

fn force_evaluation_with(c: &mut Criterion, group_name: &str, scenes: &[&str], threads: Threads) {
    let mut group = c.benchmark_group(group_name);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .expect("a pool of two threads");
    for name in scenes {
        let model = model(name);
        let solver = solver(&model, SolverMode::Explicit, 1);
        let p = solver.positions().to_vec();
        let mut f = vec![Vec3::zeros(); p.len()];
        let mut scratch = ForceScratch::new(p.len()).with_threads(threads);
        if group_name.ends_with("pair_kernels") {
            scratch = scratch.without_stencil();
        }
        let mut evaluate = || {
            f.iter_mut().for_each(|x| *x = Vec3::zeros());
            black_box(add_elastic_forces(
                solver.operator(),
                solver.params(),
                solver.volumes(),
                None,
                &p,
                None,
                &mut f,
                &mut scratch,
            ))
        };
        group.bench_function(format!("{name}_{}_points", p.len()), |b| match threads {
            Threads::One => b.iter(&mut evaluate),
            Threads::Rayon => pool.install(|| b.iter(&mut evaluate)),
        });
    }
    group.finish();
}

fn tick(c: &mut Criterion, group_name: &str, mode: SolverMode, scenes: &[&str]) {
    tick_with(c, group_name, mode, scenes, 1);
}

fn tick_with(
    c: &mut Criterion,
    group_name: &str,
    mode: SolverMode,
    scenes: &[&str],
    threads: usize,
) {
    let mut group = c.benchmark_group(group_name);
    for name in scenes {
        let model = model(name);
        let mut warm = solver(&model, mode, threads);
        warm.step(1e-3);
        let substeps = warm.substeps();
        group.bench_function(
            format!("{name}_{}_points_{substeps}_substeps", model.points.len()),
            |b| {
                // Each sample advances a fresh copy of the warmed-up state, so every tick does the
                // same work (no settling toward rest across samples).
                b.iter_batched_ref(
                    || {
                        let mut s = solver(&model, mode, threads);
                        s.step(1e-3);
                        s
                    },
                    |s| black_box(s.step(1e-3)),
                    BatchSize::LargeInput,
                )
            },
        );
    }
    group.finish();
}

fn explicit_tick(c: &mut Criterion) {
    tick(
        c,
        "tick_1ms_explicit",
        SolverMode::Explicit,
        &["liver", "shoulder", "cerebroma"],
    );
}

fn explicit_tick_two_threads(c: &mut Criterion) {
    tick_with(
        c,
        "tick_1ms_explicit_2_threads",
        SolverMode::Explicit,
        &["cerebroma"],
        2,
    );
}

/// Ticks one after another on one solver, as the simulation thread runs them (warm
/// caches). An explicit tick's work does not depend on the state (the same evaluations and
/// sub-steps whatever the positions), so the body ringing down from its displaced start
/// changes nothing but the values; `tick_1ms_explicit` measures each tick from a freshly
/// built copy instead (the figures of earlier sessions).
fn explicit_ticks_back_to_back(c: &mut Criterion) {
    let mut group = c.benchmark_group("tick_1ms_explicit_back_to_back");
    for name in ["liver", "shoulder", "cerebroma"] {
        let model = model(name);
        let mut s = solver(&model, SolverMode::Explicit, 1);
        s.step(1e-3);
        let substeps = s.substeps();
        group.bench_function(
            format!("{name}_{}_points_{substeps}_substeps", model.points.len()),
            |b| b.iter(|| black_box(s.step(1e-3))),
        );
        assert_eq!(
            s.substeps(),
            substeps,
            "{name}: the sub-steps stayed as planned"
        );
    }
    group.finish();
}

fn projective_tick(c: &mut Criterion) {
    tick(c, "tick_1ms_projective", SolverMode::Projective, &["liver"]);
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30).measurement_time(std::time::Duration::from_secs(4));
    targets = force_evaluation, force_evaluation_pair_kernels, force_evaluation_two_threads, explicit_tick, explicit_ticks_back_to_back, explicit_tick_two_threads, projective_tick
}
criterion_main!(benches);
