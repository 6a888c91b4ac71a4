//! A tick on the caller's pool, with the pool's other thread kept at hand through it.

use std::sync::atomic::{AtomicBool, Ordering};

/// Runs `tick` on `pool` (where it is called, when that is a thread of the pool) beside a
/// job that keeps the pool's other thread taking the tick's parts as they come: a worker
/// rayon put to sleep between two force evaluations of a tick takes tens of microseconds
/// to wake for the next, often longer than the part itself. Nothing here allocates.
pub(crate) fn on_pool<R: Send>(pool: &rayon::ThreadPool, tick: impl FnOnce() -> R + Send) -> R {
    pool.install(|| {
        let done = AtomicBool::new(false);
        let (result, ()) = rayon::join(
            || {
                let _done = SetOnDrop(&done);
                tick()
            },
            || keep_awake(&done),
        );
        result
    })
}

/// Runs the pool's pending jobs (the parts a tick pushes) until `done`, spinning in between.
/// If no other thread has taken this job by the end of the tick, the tick's own thread runs
/// it, and it returns at once.
fn keep_awake(done: &AtomicBool) {
    while !done.load(Ordering::Acquire) {
        if rayon::yield_now() != Some(rayon::Yield::Executed) {
            std::hint::spin_loop();
        }
    }
}

/// Sets its flag when dropped: the tick's end, a panicking one included (the job beside it
/// would spin for ever).
struct SetOnDrop<'a>(&'a AtomicBool);

impl Drop for SetOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Release);
    }
}
