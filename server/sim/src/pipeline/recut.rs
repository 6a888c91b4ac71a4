//! The incision's re-cut, handed out of the simulation.
//!
//! A stroke's incision is recomputed from the surface as it was when the stroke started
//! (`stroke_tracker`). That re-cut grows with the wound: 7–17 ms on the cerebroma's 60 mm cut, a
//! tick's whole budget many times over, every 2 mm of travel. Its inputs are the tracker's
//! own (the base surface and the path), so it can run elsewhere while the simulation goes
//! on: the simulation hands each [`RecutJob`] to its [`RecutRunner`] when the stroke asks for
//! it, and takes the [`RecutResult`] a fixed number of ticks later
//! ([`RECUT_HANDOVER_TICKS`]), or at the next stroke's start. Fixed, not "when it is
//! ready": a run is then the same bits whatever the machine's timing (the journal's replay
//! and the cut regression rely on it). Where the runner's result is not ready when due, the
//! runner waits for it: a late tick, never a different run.
//!
//! The core owns no thread (it is sans-IO): the runner is the caller's. [`InlineRecuts`],
//! the default, runs each job on the simulation's own thread when its result is due; the
//! station's simulation thread and the offline tools hand the core a worker thread of
//! their own (`scalpel_server::recut_worker`).

use std::collections::VecDeque;
use std::sync::Arc;

use crate::cut::wall_grid::first_hit;
use crate::cut::{
    FaceKind, IncisionParams, PathSample, SIGMA_ROOM, StrokeOutcome, Wound, open_stroke,
};
use crate::geometry::TriMesh;
use crate::math::{Aabb, Vec3};
use crate::model::{CoupledModel, Kernel, RestGrid, SurfaceEmbedding};

use super::surface::{PrecomputedRows, SurfaceIndex};

/// Ticks from a re-cut's request to its result on the surface: 40 ms at 1 kHz. The
/// cerebroma's longest re-cut took 17 ms on this project's 2-core machine, so a busy hour
/// has more than twice that; the lips open 0.2 mm behind where they would at the default
/// 5 mm/s stroke.
pub const RECUT_HANDOVER_TICKS: u64 = 40;

/// The surface a stroke is cut from, shared with the worker (it does not change during
/// the stroke).
#[derive(Debug)]
pub(crate) struct BaseShape {
    pub mesh: TriMesh,
    pub kinds: Vec<FaceKind>,
    /// The wounds, shared with the surface they are the wounds of (a re-cut makes new ones).
    pub wounds: Arc<Vec<Wound>>,
}

impl BaseShape {
    /// An empty shape with room for a surface of `vertices` and `triangles`.
    pub fn with_room(vertices: usize, triangles: usize) -> Self {
        Self {
            mesh: TriMesh {
                positions: Vec::with_capacity(vertices),
                triangles: Vec::with_capacity(triangles),
            },
            kinds: Vec::with_capacity(triangles),
            wounds: Arc::default(),
        }
    }

    /// Becomes `rest` (positions), `triangles`, `kinds` and `wounds`, in its own buffers.
    pub fn copy_from(
        &mut self,
        rest: &[Vec3],
        triangles: &[[u32; 3]],
        kinds: &[FaceKind],
        wounds: &Arc<Vec<Wound>>,
    ) {
        self.mesh.positions.clear();
        self.mesh.positions.extend_from_slice(rest);
        self.mesh.triangles.clear();
        self.mesh.triangles.extend_from_slice(triangles);
        self.kinds.clear();
        self.kinds.extend_from_slice(kinds);
        self.wounds = Arc::clone(wounds);
    }
}

/// What embedding a new surface vertex reads of the body: its points' rest positions, their
/// grid and the kernel (none of which a cut changes), shared with the worker.
#[derive(Debug)]
pub(crate) struct RestSpace {
    pub points: Vec<Vec3>,
    pub grid: RestGrid,
    pub kernel: Kernel,
}

impl RestSpace {
    pub fn of(model: &CoupledModel) -> Self {
        Self {
            points: model.points.rest.clone(),
            grid: model.grid.clone(),
            kernel: model.kernel,
        }
    }
}

/// The cut surface Σ as it was when a re-cut was asked for (Σ only grows: its first
/// `triangles.len()` triangles are these at any later tick).
#[derive(Debug, Default)]
pub(crate) struct SigmaSnapshot {
    pub triangles: Vec<[Vec3; 3]>,
    pub boxes: Vec<Aabb>,
}

/// One re-cut: the stroke's path opened on its base surface, and the embedding rows of its
/// new vertices against Σ as it was asked for. Run it on any thread ([`RecutJob::run`])
/// and hand the result to the [`RecutRunner`]'s caller in the order the jobs came.
pub struct RecutJob {
    pub(crate) shape: Arc<BaseShape>,
    /// The stroke as sampled; its path on the base surface is resolved by the job.
    pub(crate) stroke: StrokeSamples,
    pub(crate) margin: f64,
    pub(crate) params: IncisionParams,
    pub(crate) embed: Option<(Arc<RestSpace>, SigmaSnapshot)>,
}

/// What a job copies from the simulation thread (its samples and Σ), handed back with
/// its result so that the next job fills these again: handing a re-cut over then does
/// not allocate on the simulation thread.
#[derive(Debug, Default)]
pub(crate) struct JobBuffers {
    pub samples: Vec<PathSample>,
    pub sigma: SigmaSnapshot,
}

impl JobBuffers {
    /// Buffers with room for a long stroke's samples and for Σ as it starts out.
    pub fn with_room(samples: usize) -> Self {
        Self {
            samples: Vec::with_capacity(samples),
            sigma: SigmaSnapshot {
                triangles: Vec::with_capacity(SIGMA_ROOM),
                boxes: Vec::with_capacity(SIGMA_ROOM),
            },
        }
    }
}

/// A stroke as the tracker sampled it, copied for a re-cut: the job resolves its path on
/// the base surface (on the worker, where the slit's rays against the surface cost the
/// simulation thread nothing).
#[derive(Debug)]
pub(crate) struct StrokeSamples {
    pub samples: Vec<PathSample>,
    pub slit: Option<Vec3>,
    pub sample_step_m: f64,
}

impl StrokeSamples {
    /// The stroke's path on `mesh`: its samples, after the slit the blade's flat opened
    /// behind the first one (unless the path then ran back over it), sampled as the path
    /// is. Each slit sample is where the flat, a distance x behind the edge, meets the
    /// surface (up the edge from the blade's depth: in the flat's plane, so the slit runs
    /// straight on a faceted, sloping surface); its floor is the point's 45° taper, x up
    /// the edge from the tip.
    pub fn path(&self, mesh: &TriMesh, kinds: &[FaceKind]) -> Vec<PathSample> {
        let mut path = Vec::with_capacity(self.samples.len() + 16);
        if let (Some(slit), Some(first)) = (self.slit, self.samples.first()) {
            let onward = self.samples.get(1).map(|s| s.surface - first.surface);
            let cut = first.bottom - first.surface;
            if let (true, Some(up)) = (
                onward.is_none_or(|o| o.dot(&slit) < 0.0),
                (-cut).try_normalize(1e-12),
            ) {
                let (skin, wound): (Vec<usize>, Vec<usize>) =
                    (0..mesh.triangles.len()).partition(|&t| kinds[t] == FaceKind::Skin);
                let (length, depth) = (slit.norm(), cut.norm());
                // (Reaching a surface that rises behind the blade as steeply as 60°.)
                let reach = depth + 2.0 * length;
                let n = (length / self.sample_step_m).ceil().max(1.0) as usize;
                // From the edge back: the slit ends where its floor comes up through a
                // surface falling away behind the blade, or at an earlier wound.
                for k in 1..=n {
                    let behind = slit * (k as f64 / n as f64);
                    let below = first.bottom + behind;
                    let Some(rise) = first_hit(mesh, &skin, &below, &up, reach) else {
                        break;
                    };
                    let deep = rise - behind.norm();
                    if deep <= 0.0
                        || first_hit(mesh, &wound, &below, &up, reach).is_some_and(|w| w < rise)
                    {
                        break;
                    }
                    let surface = below + up * rise;
                    path.push(PathSample {
                        surface,
                        bottom: surface - up * deep,
                    });
                }
                path.reverse();
            }
        }
        path.extend_from_slice(&self.samples);
        path
    }
}

/// A re-cut's result.
pub struct RecutResult {
    pub(crate) outcome: StrokeOutcome,
    /// Per vertex of the new surface, for the new ones (no `source`): its embedding row
    /// over the body's points against the first `sigma_seen` triangles of Σ.
    pub(crate) rows: Option<PrecomputedRows>,
    /// The new surface's index, made beside the rows.
    pub(crate) index: Option<SurfaceIndex>,
    /// The job's buffers, for the next job.
    pub(crate) spent: JobBuffers,
    /// The incised surface's wounds, taken out of it and shared (made here, off the
    /// simulation thread; none when nothing was incised).
    pub(crate) wounds: Arc<Vec<Wound>>,
    /// How long the job took on a worker's thread (s), as its runner timed it (the core has
    /// no clock): 0 when it ran on the simulation's thread.
    pub(crate) worker_s: f64,
}

impl RecutResult {
    /// Records how long the job took on the runner's worker (s), for the incision's
    /// figures: a worker's time belongs to the ticks it serves.
    pub fn set_worker_time(&mut self, seconds: f64) {
        self.worker_s = seconds.max(0.0);
    }
}

impl RecutJob {
    /// Computes the re-cut (on whichever thread calls it) and hands the job's buffers back
    /// with it.
    pub fn run(self) -> RecutResult {
        let mut recut = self.compute();
        recut.spent = JobBuffers {
            samples: self.stroke.samples,
            sigma: self.embed.map(|(_, sigma)| sigma).unwrap_or_default(),
        };
        recut
    }

    fn compute(&self) -> RecutResult {
        let path = self.stroke.path(&self.shape.mesh, &self.shape.kinds);
        let mut outcome = open_stroke(
            &self.shape.mesh,
            &self.shape.kinds,
            &self.shape.wounds,
            &path,
            self.margin,
            &self.params,
        );
        let wounds = Arc::new(
            outcome
                .surface
                .as_mut()
                .map_or_else(Vec::new, |s| std::mem::take(&mut s.wounds)),
        );
        let index = match (&self.embed, &outcome.surface) {
            (Some((space, _)), Some(out)) => {
                Some(SurfaceIndex::of(&out.mesh, space.kernel.support_m))
            }
            _ => None,
        };
        let rows = match (&self.embed, &outcome.surface) {
            (Some((space, sigma)), Some(out)) => Some(PrecomputedRows {
                rows: (0..out.mesh.positions.len())
                    .map(|v| {
                        out.source[v].is_none().then(|| {
                            SurfaceEmbedding::row_for(
                                &out.mesh.positions[v],
                                &space.points,
                                &space.grid,
                                &space.kernel,
                                &sigma.triangles,
                                &sigma.boxes,
                            )
                        })
                    })
                    .collect(),
                sigma_seen: sigma.triangles.len(),
            }),
            _ => None,
        };
        RecutResult {
            outcome,
            rows,
            index,
            spent: JobBuffers::default(),
            wounds,
            worker_s: 0.0,
        }
    }
}

/// Where a simulation's re-cuts run. The simulation [`start`](RecutRunner::start)s a job when
/// a stroke asks for one and [`finish`](RecutRunner::finish)es the oldest when its tick comes
/// (results in the order the jobs came). Neither may allocate or lock on the calling thread
/// after warm-up: it is the simulation's, on the real-time path.
pub trait RecutRunner: Send {
    /// Takes `job` (to run it on whichever thread the runner has).
    fn start(&mut self, job: RecutJob);
    /// The result of the oldest job taken and not yet finished, waiting for it if need be
    /// (then `waited` is set); `None` if the runner lost it (its thread died on it: the
    /// surface then stays as it was).
    fn finish(&mut self, waited: &mut bool) -> Option<RecutResult>;
}

/// Jobs the simulation may have out at once: a stroke's end may follow a re-cut still out
/// with the last one, which supersedes it.
pub const RECUTS_OUT: usize = 2;

/// The default runner: each job runs on the simulation's own thread when its result is
/// due (the tick that lands it does the re-cut's work too).
#[derive(Default)]
pub struct InlineRecuts {
    jobs: VecDeque<RecutJob>,
}

impl InlineRecuts {
    /// A runner with room for the jobs a simulation has out at once.
    pub fn new() -> Self {
        Self {
            jobs: VecDeque::with_capacity(RECUTS_OUT),
        }
    }
}

impl RecutRunner for InlineRecuts {
    fn start(&mut self, job: RecutJob) {
        self.jobs.push_back(job);
    }

    fn finish(&mut self, _waited: &mut bool) -> Option<RecutResult> {
        self.jobs.pop_front().map(RecutJob::run)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three points and a vertex among them; Σ as the worker saw it (empty) and then grown
    /// by one triangle, far off or between the vertex and a point.
    #[test]
    fn a_precomputed_row_stands_only_while_no_new_cut_hides_its_points() {
        let points = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.01, 0.0, 0.0),
            Vec3::new(0.0, 0.01, 0.0),
        ];
        let kernel = Kernel { support_m: 0.02 };
        let grid = RestGrid::build(&points, kernel.support_m);
        let x = Vec3::new(0.004, 0.004, 0.0);
        let row = SurfaceEmbedding::row_for(&x, &points, &grid, &kernel, &[], &[]);
        assert_eq!(row.len(), 3);
        let far = [
            Vec3::new(1.0, 1.0, -1.0),
            Vec3::new(1.1, 1.0, 1.0),
            Vec3::new(1.0, 1.1, 1.0),
        ];
        // A wall at x = 0.002 between the vertex and the first and third points.
        let between = [
            Vec3::new(0.002, -1.0, -1.0),
            Vec3::new(0.002, 1.0, -1.0),
            Vec3::new(0.002, 0.0, 1.0),
        ];
        for (grown, kept) in [(far, true), (between, false)] {
            let sigma = vec![grown];
            let boxes = vec![Aabb::around(&grown)];
            let mut pre = PrecomputedRows {
                rows: vec![None, Some(row.clone())],
                sigma_seen: 0,
            };
            let taken = pre.take(1, &x, &points, &sigma, &boxes);
            let now = SurfaceEmbedding::row_for(&x, &points, &grid, &kernel, &sigma, &boxes);
            assert_eq!(taken.is_some(), kept);
            if let Some(taken) = taken {
                assert_eq!(taken, now, "a kept row is the row against all of Σ");
            } else {
                assert_ne!(now, row, "a dropped row was out of date");
            }
            assert!(
                pre.take(1, &x, &points, &sigma, &boxes).is_none(),
                "taken once"
            );
            assert!(
                pre.take(0, &x, &points, &sigma, &boxes).is_none(),
                "none computed"
            );
        }
    }
}
