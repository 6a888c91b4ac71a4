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

use counting_alloc::{allocations, count_in_group, group_allocations};
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
/// each tick's allocations after warm-up by what the tick did, on a thread of its own that
/// joins the station's simulation pool of `threads` (`scalpel_server::sim_pool`; the
/// worker's allocations count as the tick's). The state hash at the end.
fn cut_allocations(scene: &'static str, strokes: usize, threads: usize) -> (CutAllocations, u64) {
    std::thread::spawn(move || cut_allocations_here(scene, strokes, threads))
        .join()
        .unwrap()
}

/// [`cut_allocations`] on the calling thread (which joins the pool).
fn cut_allocations_here(scene: &str, strokes: usize, threads: usize) -> (CutAllocations, u64) {
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
    let plan = scalpel_server::sim_pool::PoolPlan {
        threads,
        worker_cpus: Vec::new(),
        fifo_priority: 0,
        nice: 0,
    };
    if let Some(pool) = scalpel_server::sim_pool::join_new_pool(&plan, count_in_group).unwrap() {
        sim.use_pool(pool.pool);
    }
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
        let before = allocations() + group_allocations();
        let report = sim.tick(1e-3, &mut NoClock);
        let during = allocations() + group_allocations() - before;
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
    if threads == 2 && scene.spec.name == "cerebroma" {
        // The worker took its share: not a pool that left every part to this thread (the
        // liver's ticks are below `PARALLEL_MIN_WORK` and run on one).
        let (own, worker) = (scalpel_server::realtime::thread_cpu_s(), worker_cpu_s());
        println!("CPU: simulation thread {own:.2} s, its worker {worker:.2} s");
        assert!(
            worker > 0.2 * own,
            "{worker} s of the worker's CPU against {own} s"
        );
    }
    (seen, sim.state_hash())
}

/// CPU time of this process's thread named `sim-worker-1` (s).
fn worker_cpu_s() -> f64 {
    let ticks_per_s = 100.0; // USER_HZ on Linux
    for task in std::fs::read_dir("/proc/self/task").unwrap().flatten() {
        let comm = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
        if comm.trim() == "sim-worker-1" {
            let stat = std::fs::read_to_string(task.path().join("stat")).unwrap();
            // Fields after the parenthesised name: state is field 3, utime 14, stime 15.
            let rest = &stat[stat.rfind(')').unwrap() + 2..];
            let fields: Vec<&str> = rest.split(' ').collect();
            let (user, system): (f64, f64) =
                (fields[11].parse().unwrap(), fields[12].parse().unwrap());
            return (user + system) / ticks_per_s;
        }
    }
    panic!("no sim-worker-1 thread");
}

/// No cutting tick allocates after warm-up, a landing that waits for its re-cut worker
/// included. Plain ticks and every kind of topology tick: those that grow Σ and refit the
/// rows it cuts, hand a re-cut to the worker, place virtual points, land a re-cut or
/// start a stroke. On the
/// liver, on the cerebroma (whose cut places virtual points over dozens of ticks), and
/// over a lab session of six strokes on the liver (later strokes start after warm-up,
/// some crossing earlier wounds). The station's two threads (the simulation and its pool's
/// worker, both counted) on the cerebroma and the session, giving the same bits as one (the
/// liver's ticks mostly stay under `PARALLEL_MIN_WORK`: the session checks the switches
/// between held and shared ticks; the cerebroma's share).
#[test]
fn cutting_ticks_do_not_allocate_after_warm_up() {
    let mut serial = 0;
    for (scene, strokes, threads) in [
        ("liver", 0, 1),
        ("cerebroma", 0, 1),
        ("cerebroma", 0, 2),
        ("liver", 6, 1),
        ("liver", 6, 2),
    ] {
        let (seen, hash) = cut_allocations(scene, strokes, threads);
        // Each two-thread run follows the same cut on one thread.
        if threads == 1 {
            serial = hash;
        } else {
            assert_eq!(
                hash, serial,
                "{scene}, {strokes} strokes: 2 threads against 1"
            );
        }
        let what = format!("{scene}, {strokes} strokes, {threads} thread(s): {seen:?}");
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
