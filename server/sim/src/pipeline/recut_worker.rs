//! The incision's re-cut off the simulation thread.
//!
//! A stroke's incision is recomputed from the surface as it was when the stroke started
//! (`incision`). That re-cut grows with the wound: 7–17 ms on the cerebroma's 60 mm cut, a
//! tick's whole budget many times over, every 2 mm of travel. Its inputs are the tracker's
//! own (the base surface and the path), so it runs on a worker thread while the simulation
//! goes on, and its result is applied a fixed number of ticks later
//! ([`RECUT_HANDOVER_TICKS`]). Fixed, not "when it is ready": a run is then the same bits
//! whatever the machine's timing (the journal's replay and the cut regression rely on it).
//! A result not ready when due is waited for: a late tick, never a different run.
//!
//! The thread is spawned with the simulation (`Simulation::new`), before the station sets
//! real-time scheduling on its threads, so it runs under the normal scheduler, on any CPU:
//! a SCHED_FIFO thread pinned beside the simulation would take that CPU from it for the
//! whole re-cut. It ends when the simulation is dropped.

use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use crate::cut::{FaceKind, IncisionParams, PathSample, StrokeOutcome, Wound, open_stroke};
use crate::geometry::TriMesh;

/// Ticks from a re-cut's request to its result on the surface: 40 ms at 1 kHz. The
/// cerebroma's longest re-cut takes 17 ms on this project's 2-core machine (up to about
/// 35 ms in a noisy hour); the lips open 0.2 mm behind where they would at the default
/// 5 mm/s stroke.
pub const RECUT_HANDOVER_TICKS: u64 = 40;

/// The surface a stroke is cut from, shared with the worker (it does not change during
/// the stroke).
#[derive(Debug)]
pub(crate) struct BaseShape {
    pub mesh: TriMesh,
    pub kinds: Vec<FaceKind>,
    pub wounds: Vec<Wound>,
}

/// One re-cut: the stroke's path opened on its base surface.
pub(crate) struct RecutJob {
    pub shape: Arc<BaseShape>,
    pub path: Vec<PathSample>,
    pub margin: f64,
    pub params: IncisionParams,
}

impl RecutJob {
    /// Computes the re-cut (on whichever thread calls it).
    pub fn run(&self) -> StrokeOutcome {
        open_stroke(
            &self.shape.mesh,
            &self.shape.kinds,
            &self.shape.wounds,
            &self.path,
            self.margin,
            &self.params,
        )
    }
}

/// The worker thread: one job at a time.
pub(crate) struct RecutWorker {
    jobs: SyncSender<RecutJob>,
    done: Receiver<StrokeOutcome>,
}

impl RecutWorker {
    /// Starts the thread; `None` if it cannot be started (the re-cuts then run on the
    /// simulation thread, as they did before).
    pub fn spawn() -> Option<Self> {
        let (jobs, inbox) = sync_channel::<RecutJob>(1);
        let (outbox, done) = sync_channel::<StrokeOutcome>(1);
        std::thread::Builder::new()
            .name("scalpel-recut".into())
            .spawn(move || {
                // Ends when the tracker (and with it `jobs`) is dropped.
                while let Ok(job) = inbox.recv() {
                    if outbox.send(job.run()).is_err() {
                        break;
                    }
                }
            })
            .ok()?;
        Some(Self { jobs, done })
    }

    /// Hands a job over. Gives it back if the worker is gone.
    pub fn send(&self, job: RecutJob) -> Result<(), RecutJob> {
        self.jobs.send(job).map_err(|e| e.0)
    }

    /// The result of the job handed over last, waiting for it if need be; `None` if the
    /// worker died on it (a panic in the re-cut: the surface stays as it was).
    pub fn wait(&self) -> Option<StrokeOutcome> {
        self.done.recv().ok()
    }
}
