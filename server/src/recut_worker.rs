//! The re-cut worker: a thread of the station's own that runs the simulation's re-cuts
//! (`scalpel_sim::pipeline::recut`) while the simulation goes on.
//!
//! Both hand-offs are SPSC rings (rtrb) with park/unpark: the simulation thread pushes a job
//! and unparks the worker; the worker pushes the result and unparks the thread waiting for
//! it. Neither side locks or allocates when it hands over or waits (std's channel allocated
//! its wait context the first time the simulation thread blocked in it). The worker is
//! spawned with the simulation, before the station sets real-time scheduling on its threads,
//! so it runs under the normal scheduler, on any CPU: a SCHED_FIFO thread pinned beside the
//! simulation would take that CPU from it for the whole re-cut. It ends when the simulation
//! (which owns this runner) is dropped.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::thread::{JoinHandle, Thread};
use std::time::{Duration, Instant};

use scalpel_sim::pipeline::recut::RECUTS_OUT;
use scalpel_sim::pipeline::{InlineRecuts, RecutJob, RecutResult, RecutRunner};

/// The longest a thread waiting for a result stays parked before it looks again: a
/// backstop for a wake-up that cannot come (the worker died mid-job).
const PARK_LIMIT: Duration = Duration::from_millis(1);

/// Jobs and results in flight at most (the simulation has [`RECUTS_OUT`] out at once;
/// room for more, so a push never fails).
const RING: usize = 2 * RECUTS_OUT;

/// The runner the simulation holds.
pub struct WorkerRecuts {
    jobs: rtrb::Producer<RecutJob>,
    results: rtrb::Consumer<RecutResult>,
    /// The thread that waits for results (the simulation's, set when it first waits).
    waiter: Arc<OnceLock<Thread>>,
    stop: Arc<AtomicBool>,
    worker: Option<JoinHandle<()>>,
    /// Jobs on the worker whose results have not been read.
    out_on_worker: usize,
    /// Where jobs run once the worker has died (a panic in a re-cut): on the simulation's
    /// thread, as without a worker.
    fallback: InlineRecuts,
}

impl WorkerRecuts {
    /// Starts the worker thread; `None` if it cannot be started (the simulation then keeps
    /// its inline runner).
    pub fn spawn() -> Option<Self> {
        let (jobs, mut inbox) = rtrb::RingBuffer::<RecutJob>::new(RING);
        let (mut outbox, results) = rtrb::RingBuffer::<RecutResult>::new(RING);
        let waiter: Arc<OnceLock<Thread>> = Arc::default();
        let stop = Arc::new(AtomicBool::new(false));
        let worker = {
            let (waiter, stop) = (waiter.clone(), stop.clone());
            std::thread::Builder::new()
                .name("scalpel-recut".into())
                .spawn(move || {
                    loop {
                        while let Ok(job) = inbox.pop() {
                            // Timed here (the core has no clock): the incision's work is
                            // the ticks' it serves, wherever it runs.
                            let started = Instant::now();
                            let mut result = job.run();
                            result.set_worker_time(started.elapsed().as_secs_f64());
                            // Room for every job's result: the simulation reads them as
                            // they are due, and never has more than RECUTS_OUT out.
                            if outbox.push(result).is_err() {
                                return;
                            }
                            if let Some(t) = waiter.get() {
                                t.unpark();
                            }
                        }
                        if stop.load(Ordering::Acquire) {
                            return;
                        }
                        std::thread::park();
                    }
                })
                .ok()?
        };
        Some(Self {
            jobs,
            results,
            waiter,
            stop,
            worker: Some(worker),
            out_on_worker: 0,
            fallback: InlineRecuts::new(),
        })
    }

    fn worker_alive(&self) -> bool {
        self.worker.as_ref().is_some_and(|w| !w.is_finished())
    }

    fn wake_worker(&self) {
        if let Some(w) = &self.worker {
            w.thread().unpark();
        }
    }
}

impl RecutRunner for WorkerRecuts {
    fn start(&mut self, job: RecutJob) {
        if !self.worker_alive() {
            return self.fallback.start(job);
        }
        // The ring has room for twice what the simulation has out: a push cannot fail.
        match self.jobs.push(job) {
            Ok(()) => {
                self.out_on_worker += 1;
                self.wake_worker();
            }
            Err(rtrb::PushError::Full(job)) => self.fallback.start(job),
        }
    }

    fn finish(&mut self, waited: &mut bool) -> Option<RecutResult> {
        // Jobs are finished in the order they came: the worker's first, then any the
        // fallback took after it died.
        if self.out_on_worker == 0 {
            return self.fallback.finish(waited);
        }
        self.waiter.get_or_init(std::thread::current);
        loop {
            if let Ok(result) = self.results.pop() {
                self.out_on_worker -= 1;
                return Some(result);
            }
            // A worker that ended (a panic in a re-cut) sends nothing more: its job is
            // lost, and the next ones run on this thread.
            if !self.worker_alive() {
                let last = self.results.pop().ok();
                self.out_on_worker -= 1;
                return last;
            }
            *waited = true;
            std::thread::park_timeout(PARK_LIMIT);
        }
    }
}

impl Drop for WorkerRecuts {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        self.wake_worker();
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

/// `sim`'s re-cuts on a worker of their own (kept inline if the thread cannot start).
pub fn attach(sim: &mut scalpel_sim::pipeline::Simulation) {
    if let Some(worker) = WorkerRecuts::spawn() {
        sim.set_recut_runner(Box::new(worker));
    }
}
