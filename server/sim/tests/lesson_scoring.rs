//! The lesson scorer runs on a station's simulation thread: it must not allocate after it
//! is made, whatever the trainee does (events, a no-go structure cut, Σ growing), and it
//! must score the scripted trainees as the lesson expects.

// A counting global allocator needs `unsafe impl GlobalAlloc`; this test crate allows it.
#![allow(unsafe_code)]

#[path = "common/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations;
use scalpel_sim::lesson::{LessonEventKind, Plan, Scorer, Trainee, builtin_lesson, trainee_script};
use scalpel_sim::pipeline::{NoClock, SIMULATION_TICK_S, Simulation, start_surface};
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{build_scene, builtin};

#[test]
fn scoring_a_careless_trainee_allocates_nothing() {
    let scene = build_scene(&builtin("liver").unwrap(), None, &mut Silent).unwrap();
    let plan = Plan::new(
        builtin_lesson("liver-straight").unwrap(),
        &scene.model.surface,
        "liver-straight",
    )
    .unwrap();
    let script = trainee_script(&plan, &start_surface(&scene), Trainee::Careless);
    let mut scorer = Scorer::new(plan);
    let mut sim = Simulation::new(&scene);
    sim.prepare(SIMULATION_TICK_S);
    let (mut allocated, mut events, mut cut) = (0, 0, false);
    let mut score_on_the_way = f64::NAN;
    for k in 0..script.tick_count(SIMULATION_TICK_S) {
        sim.handle_tool_pose(Some(script.pose_at(k as f64 * SIMULATION_TICK_S)));
        let report = sim.tick(SIMULATION_TICK_S, &mut NoClock);
        let before = allocations();
        scorer.observe(&sim, &report, SIMULATION_TICK_S);
        while let Some(e) = scorer.poll_event() {
            events += 1;
            cut |= matches!(e.kind, LessonEventKind::NoGoCut(0));
        }
        if k % 100 == 0 {
            score_on_the_way = scorer.metrics().score;
        }
        allocated += allocations() - before;
    }
    assert_eq!(allocated, 0, "the scorer allocated {allocated} times");
    assert!(cut && events >= 3, "{events} events, vessel cut: {cut}");
    assert!(score_on_the_way.is_finite());
    let m = scorer.metrics();
    assert!(
        !m.passed && m.no_go_cuts == 1 && m.max_depth_error_m > 0.005,
        "{m:?}"
    );
}
