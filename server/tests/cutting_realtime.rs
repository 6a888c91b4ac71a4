//! A cutting tick is on the real-time path: after warm-up it must not allocate (contact,
//! force, affected region, step, surface following), including the ticks that grow the cut
//! surface, refit the rows it cuts, hand a re-cut to the station's re-cut worker
//! (`scalpel_server::recut_worker`), place virtual points, land a re-cut or start a stroke,
//! a landing that has to wait for its re-cut included (docs/CUTTING.md). Counted per
//! thread: the re-cut's own work is the worker's.

// A counting global allocator needs `unsafe impl GlobalAlloc`; this test crate allows it.
#![allow(unsafe_code)]

#[path = "../sim/tests/common/counting_alloc.rs"]
mod counting_alloc;

use counting_alloc::allocations;
use scalpel_sim::progress::Silent;
use scalpel_sim::scene::{build_scene, builtin};

/// A cutting tick's allocations, by what the tick did.
#[derive(Debug, Default)]
struct CutAllocations {
    /// Ticks with no new cut surface and no change of the drawn surface.
    plain_ticks: u64,
    /// Ticks that grew Σ and removed the pairs it separates (MLS rows refitted), handed a
    /// re-cut to its worker thread, or placed virtual points: topology changes that must
    /// not allocate either.
    topology_ticks: u64,
    allocations: u64,
    /// Ticks where a re-cut landed (the drawn surface replaced).
    landing_ticks: u64,
    landing_allocations: u64,
    /// Of those, the ones whose re-cut was not ready: the tick waited for the worker.
    late_landings: u64,
    /// Ticks where a stroke started (its base surface copied).
    stroke_starts: u64,
    stroke_start_allocations: u64,
}

/// A cut on `scene` (the default stroke, or a lab session of `strokes` strokes), counting
/// each tick's allocations after warm-up by what the tick did.
fn cut_allocations(scene: &str, strokes: usize) -> CutAllocations {
    use scalpel_sim::pipeline::{CutScript, NoClock, Simulation};
    let mut spec = builtin(scene).unwrap();
    spec.features.cutting = true;
    let scene = build_scene(&spec, None, &mut Silent).unwrap();
    let surface = &scalpel_sim::pipeline::start_surface(&scene);
    let script = match strokes {
        0 => CutScript::default_for(surface),
        n => CutScript::session_for(surface, n, 1),
    }
    .unwrap();
    let mut sim = Simulation::new(&scene);
    scalpel_server::recut_worker::attach(&mut sim);
    let ticks = (script.duration_s() / 1e-3) as usize;
    let mut seen = CutAllocations::default();
    // Warm-up: the approach, the press and the first second of cutting (scratch buffers
    // reach their working size).
    let warm_up = ticks / 4;
    let stats = |sim: &Simulation| {
        sim.incisions()
            .map_or((0, 0, 0), |s| (s.runs, s.strokes, s.late_recuts))
    };
    for k in 0..ticks {
        sim.handle_tool_pose(Some(script.pose_at(k as f64 * 1e-3)));
        let triangles = sim.surface().triangles.len();
        let (runs, begun, late) = stats(&sim);
        // Virtual points still to be placed after a re-mesh (a few a tick).
        let placing = sim.virtual_points().is_some_and(|v| v.has_pending());
        let before = allocations();
        let report = sim.tick(1e-3, &mut NoClock);
        let during = allocations() - before;
        if k < warm_up {
            continue;
        }
        let cut = report.cut.as_ref().unwrap();
        let (runs_now, begun_now, late_now) = stats(&sim);
        if report.remeshed || sim.surface().triangles.len() != triangles {
            seen.landing_ticks += 1;
            seen.landing_allocations += during;
            seen.late_landings += (late_now - late) as u64;
            continue;
        }
        if begun_now != begun {
            seen.stroke_starts += 1;
            seen.stroke_start_allocations += during;
            continue;
        }
        let topology =
            !cut.new_sigma.is_empty() || cut.pairs_removed > 0 || placing || runs_now != runs;
        if during > 0 {
            println!("tick {k} (topology: {topology}): {during} allocations, {cut:?}");
        }
        if topology {
            seen.topology_ticks += 1;
        } else {
            seen.plain_ticks += 1;
        }
        seen.allocations += during;
    }
    println!("{seen:?}");
    seen
}

/// No cutting tick allocates after warm-up, a landing that waits for its re-cut worker
/// included. Plain ticks and every kind of topology tick: those that grow Σ and refit the
/// rows it cuts, hand a re-cut to the worker, place virtual points, land a re-cut or
/// start a stroke. On the
/// liver, on the cerebroma (whose cut places virtual points over dozens of ticks), and
/// over a lab session of six strokes on the liver (later strokes start after warm-up,
/// some crossing earlier wounds).
#[test]
fn cutting_ticks_do_not_allocate_after_warm_up() {
    for (scene, strokes) in [("liver", 0), ("cerebroma", 0), ("liver", 6)] {
        let seen = cut_allocations(scene, strokes);
        let what = format!("{scene}, {strokes} strokes: {seen:?}");
        assert!(seen.plain_ticks > 1000, "{what}");
        assert!(
            seen.topology_ticks > 40,
            "the cut should have grown: {what}"
        );
        assert!(seen.landing_ticks > 2, "{what}");
        assert_eq!(seen.allocations, 0, "{what}");
        // A landing fills kept buffers (rows, indices, flags, the virtual points' wall
        // sites), and one that is due before its worker is done parks until it is (std's
        // channel would allocate the first time this thread blocked in it). Once ~1560
        // allocations a landing on the cerebroma, with a vector per vertex's row.
        assert_eq!(seen.landing_allocations, 0, "{what}");
        // A stroke's start copies the surface into the last stroke's base.
        assert!(strokes < 2 || seen.stroke_starts > 0, "{what}");
        assert_eq!(seen.stroke_start_allocations, 0, "{what}");
    }
}
