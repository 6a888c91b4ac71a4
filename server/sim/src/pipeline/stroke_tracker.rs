//! Progressive surface incisions: path sampling, hysteresis and re-runs (physics.md §5.2
//! step 9).
//!
//! While the blade cuts, the entry point (rest space) is sampled every quarter of a local
//! edge, each sample keeping the deepest tip seen there. A blade back over the stroke's own
//! path adds no path (a path folded onto itself is no incision), but deepens the samples
//! it goes deeper than (sawing down in its cut); past the path's start it extends the path
//! there. The incision of the stroke is recomputed from the surface as it was when the
//! stroke started, up to the blade's entry, each time the entry has gone a progress step
//! (0.5 mm) past the last run's end — so the surface opens just behind the blade, each
//! landing moving the drawn surface by a fraction of a millimetre — when its samples have
//! gone a quarter of an edge deeper between them, and once more when the stroke ends. Parts of the
//! path that run over an earlier wound (its lid or walls) open no incision — crossing cuts
//! split into separate incisions on either side of the earlier one — but take the wound's
//! walls down where they cut deeper than them (`cut::open_stroke`).

use std::sync::Arc;

use serde::Serialize;

use crate::cut::{IncisionParams, PathSample, SweptSurface};
use crate::geometry::predicates::distance_sq_to_segment;
use crate::math::Vec3;
use crate::mls::MlsOperator;
use crate::model::{CoupledModel, RestGrid};
use crate::solver::Solver;

use super::recut::{
    BaseShape, InlineRecuts, JobBuffers, RECUT_HANDOVER_TICKS, RecutJob, RecutResult, RecutRunner,
    RestSpace, StrokeSamples,
};
use super::surface::{CurrentSurface, SURFACE_ROOM};

/// Figures of the incisions so far.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct IncisionStats {
    /// Strokes begun (the blade's edge in the tissue after being out of it).
    pub strokes: usize,
    /// Strokes that opened the surface.
    pub incisions: usize,
    /// Times an incision was (re)computed.
    pub runs: usize,
    /// Pieces of runs that were refused (the surface stayed as it was under them).
    pub refused: usize,
    /// Why the last refused run was refused.
    pub last_refusal: Option<String>,
    /// Largest lip turn of any incision (degrees).
    pub lip_max_turn_deg: f64,
    /// Smallest angle of any remeshed triangle (degrees), 180 before any incision.
    pub min_angle_deg: f64,
    /// Largest half-opening (m).
    pub opening_m: f64,
    /// Deepest wound wall (m).
    pub depth_m: f64,
    /// Re-cut results not ready when due: the tick waited for the runner.
    pub late_recuts: usize,
    /// Ticks of a new stroke held until the last stroke's final re-cut was due.
    pub held_ticks: usize,
    /// Time the re-cuts read so far took on a worker's thread (s): the surface incision's
    /// work done off the tick, to be added to the ticks they serve (0 with re-cuts inline,
    /// whose time is the tick's own).
    pub worker_s: f64,
}

/// The surface at the start of the current stroke, and what its re-cuts have made of it.
struct Base {
    shape: Arc<BaseShape>,
    /// The current vertex each base vertex is now.
    to_current: Vec<Option<u32>>,
    /// The map before the last landing, whose buffer the next one fills.
    spare_map: Vec<Option<u32>>,
    /// Pieces the last applied run of this stroke opened over intact skin.
    opened_pieces: usize,
}

/// A re-cut handed to the runner, applied at tick `due`.
struct InFlight {
    due: u64,
    /// The stroke it finishes, when it is the last re-cut of a stroke that has ended.
    ended: Option<Base>,
}

/// One tick's inputs to [`StrokeTracker::update`], held back.
#[derive(Debug, Clone, Copy)]
struct HeldTick {
    edge: [Vec3; 2],
    direction: Vec3,
    withdrawing: bool,
    slit: Option<Vec3>,
}

/// Follows the blade along the surface and keeps the drawn incision up to date.
pub struct StrokeTracker {
    params: IncisionParams,
    sample_step_m: f64,
    rerun_step_m: f64,
    /// Travel of the blade's entry past the last run's end that runs the incision again
    /// (the surface follows the crack within it plus the hand-over's travel).
    progress_step_m: f64,
    /// Where the last run's path ended (rest space), this stroke.
    run_end: Option<Vec3>,
    base: Option<Base>,
    samples: Vec<PathSample>,
    /// Whether the incision was computed in this stroke, and the samples added since.
    ran_this_stroke: bool,
    added_since_run: usize,
    /// How much deeper the samples went since the last run, summed over them (m).
    deepened_since_run_m: f64,
    /// The most advanced entry since the last sample, taken as the path's end when the
    /// stroke finishes between two samples.
    front: Option<PathSample>,
    /// The slit the blade's flat opened behind the path's first sample, pushed in point
    /// first there (rest, from the edge to the back), and whether it grew since the last
    /// run: a stroke that only stabbed is drawn when it ends.
    slit: Option<Vec3>,
    slit_grew: bool,
    /// Ticks so far (`update` runs once a tick).
    tick: u64,
    /// Where re-cuts run (the caller's: `recut`), and the one out there.
    runner: Box<dyn RecutRunner>,
    in_flight: Option<InFlight>,
    /// A new stroke's first ticks, held until the last stroke's final re-cut is due
    /// ([`Self::update`]).
    held: Vec<HeldTick>,
    /// Results the runner gives before the one in flight, of re-cuts a stroke's last one
    /// superseded: read and dropped.
    superseded: u32,
    /// The body's rest space, for the re-cut to embed new vertices.
    space: Arc<RestSpace>,
    /// Buffers finished jobs handed back, for the next ones.
    spare: Vec<JobBuffers>,
    /// The last stroke's base, for the next stroke to copy its surface into.
    spare_base: Option<Base>,
    /// Figures so far.
    pub stats: IncisionStats,
}

/// What the cutting stage knows that the incision needs.
pub struct TrackerInputs<'a> {
    /// Rest positions of the points.
    pub rest_points: &'a [Vec3],
    /// Their grid.
    pub grid: &'a RestGrid,
    /// The cut surface Σ so far.
    pub sigma: &'a SweptSurface,
    /// The MLS operator (to place new vertices).
    pub op: &'a MlsOperator,
    /// Current positions of the points.
    pub positions: &'a [Vec3],
}

impl<'a> TrackerInputs<'a> {
    /// What `solver`'s points, their `grid` and the cut surface `sigma` give the incision.
    pub fn of(solver: &'a Solver, grid: &'a RestGrid, sigma: &'a SweptSurface) -> Self {
        Self {
            rest_points: solver.rest(),
            grid,
            sigma,
            op: solver.operator(),
            positions: solver.positions(),
        }
    }
}

/// How far the blade's entry goes past the drawn incision before it is run again: the
/// lips follow the blade within this plus the hand-over's travel (issue 41: ≤ 1 mm).
const PROGRESS_STEP_M: f64 = 0.5e-3;

/// The shortest path the first run of a stroke draws.
const MIN_FIRST_RUN_M: f64 = 1e-3;

/// Path samples preallocated per stroke.
const PATH_SAMPLE_CAPACITY: usize = 1024;

/// Sets of job buffers kept for the next re-cuts.
const SPARE_JOBS: usize = 3;

impl StrokeTracker {
    /// A tracker for `model`'s surface (mean edge length `edge_m`), whose re-cuts run on
    /// the simulation's thread ([`InlineRecuts`]) until [`StrokeTracker::set_runner`] gives
    /// them another, and land [`RECUT_HANDOVER_TICKS`] after they are asked for (`recut`).
    pub fn new(edge_m: f64, params: IncisionParams, model: &CoupledModel) -> Self {
        let surface = &model.surface;
        Self {
            params,
            sample_step_m: 0.25 * edge_m,
            rerun_step_m: edge_m,
            progress_step_m: PROGRESS_STEP_M.min(edge_m),
            run_end: None,
            base: None,
            // A 250 mm stroke at a quarter of a 1 mm edge: the path grows without
            // allocating on the tick.
            samples: Vec::with_capacity(PATH_SAMPLE_CAPACITY),
            ran_this_stroke: false,
            added_since_run: 0,
            deepened_since_run_m: 0.0,
            front: None,
            slit: None,
            slit_grew: false,
            tick: 0,
            runner: Box::new(InlineRecuts::new()),
            in_flight: None,
            held: Vec::with_capacity(RECUT_HANDOVER_TICKS as usize),
            superseded: 0,
            space: Arc::new(RestSpace::of(model)),
            // Buffers for the jobs a stroke's end may have in flight at once (the one
            // running and the last re-cut, which supersedes it), made now.
            spare: {
                let mut spare = Vec::with_capacity(SPARE_JOBS);
                spare.extend((0..2).map(|_| JobBuffers::with_room(PATH_SAMPLE_CAPACITY)));
                spare
            },
            spare_base: Some(Base::with_room(
                surface.positions.len(),
                surface.triangles.len(),
            )),
            stats: IncisionStats {
                min_angle_deg: 180.0,
                ..IncisionStats::default()
            },
        }
    }

    /// Re-cuts run on `runner` from now on (set before the first tick: a job out on the
    /// last one would be lost).
    pub fn set_runner(&mut self, runner: Box<dyn RecutRunner>) {
        self.runner = runner;
    }

    /// One tick: `edge` is the blade's rest-space (tip, entry) while it cuts, `None`
    /// otherwise; `direction` is the blade's latest motion; a `withdrawing` blade neither
    /// extends nor deepens the path; `slit` is what its flat slit at the surface, going in
    /// point first. Returns whether the surface was re-meshed.
    pub fn update(
        &mut self,
        edge: Option<[Vec3; 2]>,
        direction: Vec3,
        withdrawing: bool,
        slit: Option<Vec3>,
        surface: &mut CurrentSurface,
        inputs: &TrackerInputs<'_>,
    ) -> bool {
        self.tick += 1;
        let due = (self.in_flight.as_ref()).is_some_and(|f| self.tick >= f.due);
        // A new stroke starts from the last one's finished surface. Begun before that
        // stroke's final re-cut is due, its ticks are held until then, not the re-cut
        // waited for (up to a re-cut's time in one tick); their path samples are the same
        // either way. A stroke that ends while held, or more held ticks than there is room
        // for, lands the re-cut at once.
        let starting = edge.is_some() && self.base.is_none();
        let holding = starting || !self.held.is_empty();
        if let Some(edge) = edge
            && holding
            && self.in_flight.is_some()
            && !due
            && self.held.len() < self.held.capacity()
        {
            self.held.push(HeldTick {
                edge,
                direction,
                withdrawing,
                slit,
            });
            self.stats.held_ticks += 1;
            return false;
        }
        let landed = match &self.in_flight {
            Some(_) if due || holding => self.land(surface, inputs),
            _ => false,
        };
        let replayed = self.follow_held(surface, inputs);
        self.follow_blade(edge, direction, withdrawing, slit, surface, inputs) || landed || replayed
    }

    /// The held ticks, in order, now that the re-cut they waited for has landed.
    fn follow_held(&mut self, surface: &mut CurrentSurface, inputs: &TrackerInputs<'_>) -> bool {
        let mut changed = false;
        for k in 0..self.held.len() {
            let h = self.held[k];
            changed |= self.follow_blade(
                Some(h.edge),
                h.direction,
                h.withdrawing,
                h.slit,
                surface,
                inputs,
            );
        }
        self.held.clear();
        changed
    }

    /// [`Self::update`] after any re-cut due has landed.
    fn follow_blade(
        &mut self,
        edge: Option<[Vec3; 2]>,
        direction: Vec3,
        withdrawing: bool,
        slit: Option<Vec3>,
        surface: &mut CurrentSurface,
        inputs: &TrackerInputs<'_>,
    ) -> bool {
        let Some([tip, entry]) = edge else {
            return self.finish_stroke(inputs);
        };
        if self.base.is_none() {
            // The stroke's base surface, copied for its re-cuts into the last stroke's
            // buffers (docs/CUTTING.md, "The real-time path"); new ones only if the last
            // base was lost with a runner that died on its re-cut.
            self.stats.strokes += 1;
            let n = surface.mesh.positions.len();
            let mut base = (self.spare_base.take())
                .unwrap_or_else(|| Base::with_room(n, surface.mesh.triangles.len()));
            base.start_on(surface);
            self.base = Some(base);
        }
        if withdrawing {
            return false;
        }
        // Pushed in point first where the path starts, the blade's flat slits behind its
        // edge: the path starts that far back (`stroke_path`). The slit is drawn when the
        // blade moves on or leaves: while it is in, the blade fills it. (Drawn as it grew,
        // the short, steep slits of a blade going in made wall cells under 15°.)
        if let (Some(v), true) = (slit, self.samples.len() <= 1)
            && self.slit.is_none_or(|s| v.norm() > s.norm())
        {
            self.slit = Some(v);
            self.slit_grew = true;
        }
        match self.samples.last_mut() {
            Some(last) if (entry - last.surface).norm() < self.sample_step_m => {
                let (depth, was) = ((tip - entry).norm(), (last.bottom - last.surface).norm());
                if depth > was {
                    last.bottom = last.surface + (tip - entry);
                    if self.ran_this_stroke {
                        self.deepened_since_run_m += depth - was;
                    }
                }
                // Ahead along the path: a blade going in point first moves the entry only
                // as the surface gives under it.
                let step = entry - last.surface;
                let plunging = (tip - entry)
                    .try_normalize(1e-12)
                    .is_some_and(|down| down.dot(&direction) > 0.5);
                let ahead = !plunging && step.dot(&direction) >= 0.5 * step.norm();
                if ahead
                    && self
                        .front
                        .is_none_or(|f| step.norm() > (f.surface - last.surface).norm())
                {
                    self.front = Some(PathSample {
                        surface: entry,
                        bottom: tip,
                    });
                }
                return self.progressed() && self.run_to_front(inputs);
            }
            _ => {}
        }
        // Back over its own path (sawing to and fro in its cut) the blade adds no path: a
        // path folded onto itself is no incision (it may deepen the samples there, below).
        // Past the path's start it extends the path there.
        let sample = PathSample {
            surface: entry,
            bottom: tip,
        };
        let (Some(first), Some(last)) =
            (self.samples.first().copied(), self.samples.last().copied())
        else {
            self.samples.push(sample);
            self.added_since_run += 1;
            return false;
        };
        let on_path = |x: &Vec3| {
            let near = self.sample_step_m.powi(2);
            self.samples
                .windows(2)
                .any(|w| distance_sq_to_segment(x, &w[0].surface, &w[1].surface) < near)
        };
        if self.samples.len() >= 2 && on_path(&entry) {
            // Deeper than before there (sawing down in its own cut), it deepens the
            // samples it is over, and the incision is run again once they have gone a
            // quarter of an edge deeper between them.
            let cut = tip - entry;
            let depth = cut.norm();
            for s in &mut self.samples {
                let was = (s.bottom - s.surface).norm();
                if depth > was && (s.surface - entry).norm() < self.sample_step_m {
                    s.bottom = s.surface + cut;
                    if self.ran_this_stroke {
                        self.deepened_since_run_m += depth - was;
                    }
                }
            }
            return self.deepened() && self.run(inputs);
        }
        // (Past the start means on from the start the way the path leaves it: an entry
        // that hops onto another sheet of a thin part is not an extension.)
        let at_start = self.samples.len() >= 2
            && (entry - first.surface).norm() < (entry - last.surface).norm()
            && {
                let out = first.surface - self.samples[1].surface;
                (entry - first.surface).dot(&out)
                    >= 0.5 * (entry - first.surface).norm() * out.norm()
            };
        let end = if at_start { first } else { last };
        // The path goes where the blade goes: an entry point that moved against the
        // blade (the torn surface around it maps to rest space only roughly while the
        // blade plunges or drags the tissue) is not a new sample.
        if (entry - end.surface).dot(&direction) < 0.5 * (entry - end.surface).norm() {
            return false;
        }
        if at_start {
            // The path now starts elsewhere, over any slit made where it started.
            self.slit = None;
            self.samples.insert(0, sample);
        } else {
            self.front = None;
            self.samples.push(sample);
        }
        self.added_since_run += 1;
        let due = if self.ran_this_stroke {
            self.added_since_run as f64 * self.sample_step_m >= self.rerun_step_m
        } else {
            let (a, b) = (
                self.samples[0].surface,
                self.samples[self.samples.len() - 1].surface,
            );
            (b - a).norm() >= self.rerun_step_m
        };
        due && self.run(inputs)
    }

    /// The blade left the tissue: the path's end (the most advanced entry since the last
    /// sample), the stroke's last re-cut asked for if the path grew or deepened since the
    /// last, the base handed to the re-cut in flight (or kept for the next stroke), and the
    /// stroke forgotten. Returns whether the surface changed.
    fn finish_stroke(&mut self, inputs: &TrackerInputs<'_>) -> bool {
        // The stroke ended: settle its incision on the final path, up to the most
        // advanced entry past its last sample (past it along the path: a blade that
        // turned round within a sample step leaves no fold).
        if let Some(front) = self.front_ahead() {
            self.samples.push(front);
            self.added_since_run += 1;
        }
        self.front = None;
        let rerun = (self.samples.len() >= 2 || self.slit.is_some())
            && (self.added_since_run > 0 || self.deepened() || self.slit_grew);
        // The last re-cut covers the whole path: one still in flight is superseded (its
        // result read and dropped when this one lands).
        if rerun && self.in_flight.take().is_some() {
            self.superseded += 1;
        }
        let changed = rerun && self.run(inputs);
        // Landing after the stroke, it applies to the stroke it finishes (this branch
        // runs every tick the blade is not cutting: only a stroke that just ended has a
        // base to hand on).
        if let Some(base) = self.base.take() {
            match &mut self.in_flight {
                Some(f) => f.ended = Some(base),
                None => self.spare_base = Some(base),
            }
        }
        self.samples.clear();
        self.run_end = None;
        self.ran_this_stroke = false;
        self.added_since_run = 0;
        self.deepened_since_run_m = 0.0;
        self.slit = None;
        self.slit_grew = false;
        changed
    }

    /// Whether the samples have gone deep enough below the last run's to run again: a
    /// quarter of an edge between them.
    fn deepened(&self) -> bool {
        self.deepened_since_run_m >= 0.25 * self.rerun_step_m
    }

    /// The most advanced entry since the last sample, if it is on past the last sample
    /// along the path (a blade that turned round within a sample step leaves no fold).
    fn front_ahead(&self) -> Option<PathSample> {
        let (front, last) = (self.front?, self.samples.last()?);
        let n = self.samples.len();
        let on = (front.surface - last.surface).norm() > 0.1 * self.sample_step_m
            && (n < 2
                || (front.surface - last.surface)
                    .dot(&(last.surface - self.samples[n - 2].surface))
                    > 0.0);
        on.then_some(front)
    }

    /// Whether the blade's entry has gone a progress step on past where the last run's
    /// path ended (before the first run: the path to it is `MIN_FIRST_RUN_M` long).
    fn progressed(&self) -> bool {
        let (Some(front), Some(first)) = (self.front_ahead(), self.samples.first()) else {
            return false;
        };
        match self.run_end {
            Some(end) => (front.surface - end).norm() >= self.progress_step_m,
            None => (front.surface - first.surface).norm() >= MIN_FIRST_RUN_M,
        }
    }

    /// The current stroke's path samples (empty between strokes).
    pub fn path(&self) -> &[PathSample] {
        &self.samples
    }

    /// Recomputes the stroke's incision from the base surface: hands it to the runner (it
    /// lands later, and this returns `false`). With a re-cut still in flight it waits: the
    /// samples since keep counting, so the next sample asks again.
    fn run(&mut self, inputs: &TrackerInputs<'_>) -> bool {
        self.start_run(inputs, false)
    }

    /// [`Self::run`] with the path drawn up to the blade's entry (the blade going on
    /// past the last sample).
    fn run_to_front(&mut self, inputs: &TrackerInputs<'_>) -> bool {
        self.start_run(inputs, true)
    }

    fn start_run(&mut self, inputs: &TrackerInputs<'_>, to_front: bool) -> bool {
        if self.in_flight.is_some() {
            return false;
        }
        let Some(job) = self.job(inputs.sigma, to_front) else {
            return false;
        };
        self.runner.start(job);
        self.in_flight = Some(InFlight {
            due: self.tick + RECUT_HANDOVER_TICKS,
            ended: None,
        });
        false
    }

    /// Applies the re-cut in flight now, if there is one (waiting for it if need be), and
    /// follows the ticks held for it: at the end of an offline run. Returns whether the
    /// surface changed.
    pub fn settle(&mut self, surface: &mut CurrentSurface, inputs: &TrackerInputs<'_>) -> bool {
        let mut changed = false;
        // Held ticks followed may ask for a re-cut again: landed too.
        while self.in_flight.is_some() || !self.held.is_empty() {
            changed |= self.in_flight.is_some() && self.land(surface, inputs);
            changed |= self.follow_held(surface, inputs);
        }
        changed
    }

    /// The re-cut of the stroke's path so far, with the embedding of its new vertices
    /// against `sigma`; counts it as a run. Its copies of the
    /// samples and of Σ go into buffers an earlier job handed back.
    fn job(&mut self, sigma: &SweptSurface, to_front: bool) -> Option<RecutJob> {
        let base = self.base.as_ref()?;
        let shape = base.shape.clone();
        let JobBuffers {
            mut samples,
            sigma: mut snapshot,
        } = self.spare.pop().unwrap_or_default();
        samples.clone_from(&self.samples);
        // The blade's entry past the last sample ends the path drawn now (it stays
        // provisional: the next sample is taken where the step says).
        if let Some(front) = self.front_ahead().filter(|_| to_front) {
            samples.push(front);
        }
        self.run_end = samples.last().map(|s| s.surface);
        self.ran_this_stroke = true;
        self.added_since_run = 0;
        self.deepened_since_run_m = 0.0;
        self.slit_grew = false;
        self.stats.runs += 1;
        Some(RecutJob {
            shape,
            stroke: StrokeSamples {
                samples,
                slit: self.slit,
                sample_step_m: self.sample_step_m,
            },
            margin: 0.5 * self.rerun_step_m,
            params: self.params,
            embed: {
                snapshot.triangles.clone_from(&sigma.triangles);
                snapshot.boxes.clone_from(&sigma.boxes);
                Some((self.space.clone(), snapshot))
            },
        })
    }

    /// Keeps a finished job's buffers for the next one.
    fn keep_buffers(&mut self, spent: JobBuffers) {
        if self.spare.len() < SPARE_JOBS {
            self.spare.push(spent);
        }
    }

    /// Applies the re-cut in flight, waiting for it if need be.
    fn land(&mut self, surface: &mut CurrentSurface, inputs: &TrackerInputs<'_>) -> bool {
        let Some(flight) = self.in_flight.take() else {
            return false;
        };
        let superseded = std::mem::take(&mut self.superseded);
        // Superseded results are read and dropped, their buffers kept.
        let mut recut = None;
        for left in (0..=superseded).rev() {
            let mut waited = false;
            recut = self.runner.finish(&mut waited);
            self.stats.late_recuts += usize::from(waited);
            self.stats.worker_s += recut.as_ref().map_or(0.0, |r| r.worker_s);
            match &mut recut {
                Some(r) if left > 0 => self.keep_buffers(std::mem::take(&mut r.spent)),
                Some(_) => {}
                None => break,
            }
        }
        let Some(mut recut) = recut else {
            // The runner lost it (its thread died on it): the surface stays as it was.
            self.stats.refused += 1;
            self.stats.last_refusal = Some("the re-cut failed on its runner's thread".into());
            return false;
        };
        self.keep_buffers(std::mem::take(&mut recut.spent));
        match flight.ended {
            // The stroke it finishes has ended (no new stroke has begun: it would have
            // landed this first); its base goes with it.
            Some(mut ended) => {
                let changed = ended.apply(&mut self.stats, recut, surface, inputs);
                self.spare_base = Some(ended);
                changed
            }
            None => self.apply_here(recut, surface, inputs),
        }
    }

    /// Applies a re-cut to the current stroke.
    fn apply_here(
        &mut self,
        recut: RecutResult,
        surface: &mut CurrentSurface,
        inputs: &TrackerInputs<'_>,
    ) -> bool {
        self.base
            .as_mut()
            .is_some_and(|base| base.apply(&mut self.stats, recut, surface, inputs))
    }
}

impl Base {
    /// A base with room for a surface [`SURFACE_ROOM`] times `vertices` and `triangles`.
    fn with_room(vertices: usize, triangles: usize) -> Self {
        let (vertices, triangles) = (SURFACE_ROOM * vertices, SURFACE_ROOM * triangles);
        Self {
            shape: Arc::new(BaseShape::with_room(vertices, triangles)),
            to_current: Vec::with_capacity(vertices),
            spare_map: Vec::with_capacity(vertices),
            opened_pieces: 0,
        }
    }

    /// Makes this the base of a stroke starting on `surface`: its rest shape copied into
    /// the buffers (a new shape only while the worker still holds the last one), every
    /// vertex its own.
    fn start_on(&mut self, surface: &CurrentSurface) {
        let (rest, triangles) = (surface.rest_positions(), &surface.mesh.triangles);
        if Arc::get_mut(&mut self.shape).is_none() {
            self.shape = Arc::new(BaseShape::with_room(rest.len(), triangles.len()));
        }
        let shape = Arc::get_mut(&mut self.shape).expect("a shape of its own");
        shape.copy_from(rest, triangles, &surface.kinds, &surface.wounds);
        self.to_current.clear();
        (self.to_current).extend((0..rest.len() as u32).map(Some));
        self.spare_map.clear();
        self.opened_pieces = 0;
    }

    /// Puts a re-cut of this stroke in place of the current surface (unless it opens fewer
    /// pieces than the last one applied), counting it in `stats`.
    fn apply(
        &mut self,
        stats: &mut IncisionStats,
        recut: RecutResult,
        surface: &mut CurrentSurface,
        inputs: &TrackerInputs<'_>,
    ) -> bool {
        let RecutResult {
            outcome,
            rows,
            index,
            wounds,
            ..
        } = recut;
        stats.refused += outcome.refusals.len();
        if let Some(e) = outcome.refusals.last() {
            stats.last_refusal = Some(e.to_string());
        }
        // A piece refused now may have opened in an earlier run of this stroke: a run that
        // opens fewer pieces than the last one applied would lose that incision, so the
        // surface keeps the last one.
        if outcome.opened < self.opened_pieces {
            return false;
        }
        let Some(out) = outcome.surface else {
            return false;
        };
        stats.lip_max_turn_deg = stats.lip_max_turn_deg.max(outcome.lip_max_turn_deg);
        stats.min_angle_deg = stats.min_angle_deg.min(outcome.min_angle_deg);
        stats.opening_m = stats.opening_m.max(outcome.opening_m);
        stats.depth_m = stats.depth_m.max(outcome.depth_m);
        let mut next = std::mem::take(&mut self.spare_map);
        surface.replace(
            out,
            wounds,
            &self.to_current,
            &mut next,
            inputs.rest_points,
            inputs.grid,
            inputs.sigma,
            inputs.op,
            inputs.positions,
            rows,
            index,
        );
        self.spare_map = std::mem::replace(&mut self.to_current, next);
        if outcome.opened > 0 && self.opened_pieces == 0 {
            stats.incisions += 1;
        }
        self.opened_pieces = outcome.opened;
        true
    }
}
