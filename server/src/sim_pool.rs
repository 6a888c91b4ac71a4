//! The simulation's worker pool: both cores for the force evaluation (issue 42).
//!
//! The simulation thread builds the pool once it knows its own scheduling and becomes the
//! pool's thread 0 (rayon's `use_current_thread`); one worker is spawned beside it, pinned
//! and scheduled like it. A force evaluation is a `rayon::join` of two fixed parts: the
//! second part's job goes on the simulation thread's own deque, with no allocation and no
//! lock, and the worker steals it. If the worker has not taken it by the time the first
//! part is done, the simulation thread runs it itself: a worker slow to wake costs one serial
//! evaluation, never a result. A worker kept off its CPU after it took a part (viewers
//! rendering on the same cores) does make the simulation thread wait: the station then
//! holds its ticks to one thread (station/sharing.rs). The parts are summed in the same order either way, so one
//! thread and two give the same bits (server/tests/cutting_realtime.rs).
//!
//! The haptic thread is never in the pool and never waits on it: its SCHED_FIFO priority
//! is above both of the pool's threads (docs/SERVER.md, "Threads").

use std::sync::Arc;

use crate::realtime;

/// How the simulation's pool is made.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PoolPlan {
    /// Threads in all, the simulation thread included (1: no pool, no worker).
    pub threads: usize,
    /// The worker's CPUs (empty: any).
    pub worker_cpus: Vec<usize>,
    /// The worker's SCHED_FIFO priority: the simulation thread's (0: normal scheduling).
    pub fifo_priority: i32,
    /// The worker's nice value under normal scheduling: the simulation thread's (0: as
    /// the process).
    pub nice: i32,
}

/// A pool the calling thread has joined as thread 0.
pub struct SimPool {
    /// The pool, for `Simulation::use_pool`.
    pub pool: Arc<rayon::ThreadPool>,
    /// What the workers could not get (pinning, SCHED_FIFO), for the start report.
    pub warnings: Vec<String>,
}

/// The simulation threads the station can use: `asked` (config `realtime.sim_threads`),
/// at most the CPUs the process may run on; why fewer, if so.
pub fn usable_threads(asked: usize, allowed_cpus: usize) -> (usize, Option<String>) {
    let usable = asked.min(allowed_cpus.max(1));
    let why = (usable < asked).then(|| {
        format!(
            "realtime.sim_threads = {asked}, but the process may run on {allowed_cpus} CPU(s): the simulation uses {usable}"
        )
    });
    (usable, why)
}

/// Makes the pool of `plan.threads` with the calling thread as its thread 0, spawning the
/// workers (each calls `on_worker_start` before it takes work: the tests count its
/// allocations from there). `None` for a plan of one thread. Call it once per thread.
pub fn join_new_pool(plan: &PoolPlan, on_worker_start: fn()) -> Result<Option<SimPool>, String> {
    if plan.threads <= 1 {
        return Ok(None);
    }
    let (tx, rx) = std::sync::mpsc::channel::<Vec<String>>();
    let (cpus, priority, nice) = (plan.worker_cpus.clone(), plan.fifo_priority, plan.nice);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(plan.threads)
        .use_current_thread()
        .spawn_handler(|thread| {
            let (tx, cpus) = (tx.clone(), cpus.clone());
            std::thread::Builder::new()
                .name(format!("sim-worker-{}", thread.index()))
                .spawn(move || {
                    let _ = tx.send(set_up_worker(&cpus, priority, nice));
                    drop(tx);
                    on_worker_start();
                    thread.run();
                })?;
            Ok(())
        })
        .build()
        .map_err(|e| format!("the simulation's worker pool: {e}"))?;
    drop(tx);
    // Each worker says what it got before it takes work.
    let warnings = rx.iter().flatten().collect();
    Ok(Some(SimPool {
        pool: Arc::new(pool),
        warnings,
    }))
}

/// Pins the worker to `cpus` and gives it SCHED_FIFO `priority` (0: none) or else the
/// `nice` value (0: none); what failed.
fn set_up_worker(cpus: &[usize], priority: i32, nice: i32) -> Vec<String> {
    let name = std::thread::current()
        .name()
        .unwrap_or("sim-worker")
        .to_string();
    let mut warnings = Vec::new();
    if !cpus.is_empty()
        && let Err(e) = realtime::pin_thread(cpus)
    {
        warnings.push(format!("{e}: the simulation's {name} runs on any CPU"));
    }
    if priority > 0
        && let Err(e) = realtime::make_thread_fifo(priority)
    {
        warnings.push(format!(
            "{e}: the simulation's {name} runs with normal scheduling"
        ));
    }
    if priority == 0
        && nice != 0
        && let Err(e) = realtime::set_thread_nice(nice)
    {
        warnings.push(format!(
            "{e}: the simulation's {name} runs at the process's nice"
        ));
    }
    warnings
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_are_capped_by_the_cpus() {
        assert_eq!(usable_threads(2, 2), (2, None));
        assert_eq!(usable_threads(1, 8), (1, None));
        let (n, why) = usable_threads(2, 1);
        assert_eq!(n, 1);
        assert!(why.unwrap().contains("may run on 1 CPU"));
        // An unreadable affinity (0 CPUs) still leaves the simulation thread.
        assert_eq!(usable_threads(2, 0).0, 1);
    }

    #[test]
    fn a_pool_of_one_is_none_and_of_two_has_the_caller_as_thread_0() {
        let plan = PoolPlan {
            threads: 1,
            worker_cpus: Vec::new(),
            fifo_priority: 0,
            nice: 0,
        };
        assert!(join_new_pool(&plan, || {}).unwrap().is_none());
        // A thread joins one pool in its life: a thread of its own.
        std::thread::spawn(move || {
            let plan = PoolPlan { threads: 2, ..plan };
            let pool = join_new_pool(&plan, || {}).unwrap().unwrap();
            assert_eq!(pool.pool.current_thread_index(), Some(0));
            assert_eq!(pool.pool.current_num_threads(), 2);
            // The worker is a thread of this process under its own name.
            let names: Vec<String> = std::fs::read_dir("/proc/self/task")
                .unwrap()
                .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
                .collect();
            assert!(
                names.iter().any(|n| n.trim() == "sim-worker-1"),
                "{names:?}"
            );
        })
        .join()
        .unwrap();
    }
}
