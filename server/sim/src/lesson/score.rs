//! The trainee's metrics, read from the simulation tick by tick: the same code live on a
//! station's simulation thread (no allocation after [`Scorer::new`]) and replaying a journal
//! (`scalpel report`). Definitions: docs/LESSONS.md, "Metrics".

use super::plan::Plan;
use crate::math::Vec3;
use crate::pipeline::{Simulation, TickReport};

/// Events the scorer keeps for a caller to poll before they are overwritten.
pub const EVENT_ROOM: usize = 64;

/// What happened, for the instructor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LessonEventKind {
    /// The force went over the lesson's warning limit.
    ForceWarning,
    /// The force went over the critical limit.
    ForceCritical,
    /// The blade's edge came within the contact margin of a no-go structure (its index).
    NoGoContact(u16),
    /// The cut reached into a no-go structure (its index).
    NoGoCut(u16),
}

/// An event with its time (s, simulated) and value (the force in N, or the distance in m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LessonEvent {
    /// Simulated time.
    pub time_s: f64,
    /// What.
    pub kind: LessonEventKind,
    /// The force (N) for force events; for a contact, the edge's distance from the
    /// structure's surface (m, negative inside); for a cut, how far the cut surface reached
    /// inside it (m, negative).
    pub value: f64,
}

/// Why a trainee has not passed (yet): one bit a criterion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Shortfalls(pub u16);

impl Shortfalls {
    /// The blade never entered the tissue.
    pub const NOT_STARTED: u16 = 1;
    /// Less of the plan cut to depth than the lesson asks.
    pub const INCOMPLETE: u16 = 1 << 1;
    /// The cut strayed from the path.
    pub const DEVIATION: u16 = 1 << 2;
    /// The cut's depth missed the target.
    pub const DEPTH: u16 = 1 << 3;
    /// Too many critical force events.
    pub const CRITICAL_FORCE: u16 = 1 << 4;
    /// A no-go structure was cut.
    pub const NO_GO_CUT: u16 = 1 << 5;
    /// Over the time limit.
    pub const TIME: u16 = 1 << 6;
    /// The score is under the lesson's minimum.
    pub const SCORE: u16 = 1 << 7;

    /// Whether `bit` is set.
    pub fn has(self, bit: u16) -> bool {
        self.0 & bit != 0
    }
}

/// The metrics at one moment (docs/LESSONS.md, "Metrics"). Lengths in m, times in s.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Metrics {
    /// The blade has entered the tissue.
    pub started: bool,
    /// From the blade's first entry to its last exit (or now, while in).
    pub time_s: f64,
    /// RMS distance of the blade's entry from the plan over the ticks it was cutting.
    pub rms_deviation_m: f64,
    /// Largest such distance.
    pub max_deviation_m: f64,
    /// RMS of the depth reached minus the target, over the samples of the plan reached.
    pub rms_depth_error_m: f64,
    /// The depth error of largest size, with its sign (+ too deep).
    pub max_depth_error_m: f64,
    /// Share of the planned length cut to depth (within the tolerance's shallow side) and
    /// within the allowed deviation (0–1).
    pub completed: f64,
    /// Strokes (the edge in the tissue after being out of it).
    pub strokes: u32,
    /// The tip's path over the exercise (m).
    pub tool_path_m: f64,
    /// Tool path over planned length.
    pub economy: f64,
    /// Times the force went over the warning limit, and for how long in all.
    pub warning_events: u32,
    /// Seconds over the warning limit.
    pub warning_s: f64,
    /// Times the force went over the critical limit.
    pub critical_events: u32,
    /// Seconds over the critical limit.
    pub critical_s: f64,
    /// Largest force (N).
    pub peak_force_n: f64,
    /// Times the edge came within a no-go structure's contact margin.
    pub no_go_contacts: u32,
    /// No-go structures cut into.
    pub no_go_cuts: u32,
    /// The structure the edge last came in contact with (its index in the lesson).
    pub last_no_go_contact: Option<u16>,
    /// The structure last cut into.
    pub last_no_go_cut: Option<u16>,
    /// Largest turn of a wound's lip (degrees): how jagged the incision is.
    pub lip_turn_deg: f64,
    /// Separate wounds drawn in the surface.
    pub wounds: u32,
    /// Area of the cut made outside the planned band (m²).
    pub off_band_area_m2: f64,
    /// Score, 0–100.
    pub score: f64,
    /// Every pass criterion holds.
    pub passed: bool,
    /// The criteria that do not.
    pub shortfalls: Shortfalls,
}

/// Over or under a force limit.
#[derive(Debug, Clone, Copy, Default)]
struct Band {
    over: bool,
    events: u32,
    seconds: f64,
}

impl Band {
    /// Returns true when the force has just gone over.
    fn observe(&mut self, over: bool, dt: f64) -> bool {
        let rose = over && !self.over;
        if rose {
            self.events += 1;
        }
        if over {
            self.seconds += dt;
        }
        self.over = over;
        rose
    }
}

#[derive(Debug, Clone, Copy, Default)]
struct NoGoState {
    contact: bool,
    contacts: u32,
    cut: bool,
}

/// Scores one trainee's exercise on one plan.
pub struct Scorer {
    plan: Plan,
    /// Deepest the cut reached under each sample of each incision (m); −∞ where not.
    reached: Vec<Vec<f64>>,
    /// The sample the last cutting tick was on, to fill the samples between two ticks.
    last_on_plan: Option<(usize, usize)>,
    dev_sq: f64,
    dev_n: u64,
    dev_max: f64,
    first_in_s: Option<f64>,
    last_in_s: f64,
    last_time_s: f64,
    in_tissue: bool,
    travel_m: f64,
    travel_at_last_in_m: f64,
    last_tip: Option<Vec3>,
    warning: Band,
    critical: Band,
    peak_force_n: f64,
    no_go: Vec<NoGoState>,
    sigma_seen: usize,
    off_band_area_m2: f64,
    last_contact: Option<u16>,
    last_cut: Option<u16>,
    strokes: u32,
    wounds: u32,
    lip_turn_deg: f64,
    events: [Option<LessonEvent>; EVENT_ROOM],
    events_head: usize,
    events_len: usize,
    events_lost: u64,
}

impl Scorer {
    /// A scorer for `plan`; all its room is made here.
    pub fn new(plan: Plan) -> Self {
        let reached = plan
            .incisions
            .iter()
            .map(|c| vec![f64::NEG_INFINITY; c.samples.len()])
            .collect();
        let no_go = vec![NoGoState::default(); plan.spec.no_go.len()];
        Self {
            plan,
            reached,
            last_on_plan: None,
            dev_sq: 0.0,
            dev_n: 0,
            dev_max: 0.0,
            first_in_s: None,
            last_in_s: 0.0,
            last_time_s: 0.0,
            in_tissue: false,
            travel_m: 0.0,
            travel_at_last_in_m: 0.0,
            last_tip: None,
            warning: Band::default(),
            critical: Band::default(),
            peak_force_n: 0.0,
            no_go,
            sigma_seen: 0,
            off_band_area_m2: 0.0,
            last_contact: None,
            last_cut: None,
            strokes: 0,
            wounds: 0,
            lip_turn_deg: 0.0,
            events: [None; EVENT_ROOM],
            events_head: 0,
            events_len: 0,
            events_lost: 0,
        }
    }

    /// The plan it scores against.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// Deepest the cut reached under each sample of incision `i` (m; −∞ where it did not).
    pub fn depth_reached(&self, i: usize) -> &[f64] {
        &self.reached[i]
    }

    /// Reads the tick `sim` has just made (its report `report`, `dt` long).
    pub fn observe(&mut self, sim: &Simulation, report: &TickReport, dt: f64) {
        let now = report.time_s;
        self.last_time_s = now;
        self.observe_force(report, now, dt);
        let cut = report.cut.as_ref();
        let in_tissue = cut.is_some_and(|c| c.in_tissue);
        let tip = sim.blade_pose().map(|p| p.tip_m);
        if let (Some(tip), Some(last)) = (tip, self.last_tip)
            && self.first_in_s.is_some()
        {
            self.travel_m += (tip - last).norm();
        }
        self.last_tip = tip;
        if in_tissue {
            if self.first_in_s.is_none() {
                self.first_in_s = Some(now);
            }
            self.last_in_s = now;
            self.travel_at_last_in_m = self.travel_m;
            if let Some([tip_rest, entry_rest]) = cut.and_then(|c| c.edge_rest) {
                self.observe_edge(&tip_rest, &entry_rest, now);
            }
        } else {
            self.last_on_plan = None;
            for g in &mut self.no_go {
                g.contact = false;
            }
        }
        self.in_tissue = in_tissue;
        if let Some(stage) = sim.cutting() {
            let sigma = &stage.sigma.triangles;
            for t in self.sigma_seen..sigma.len() {
                self.observe_sigma(&sigma[t], now);
            }
            self.sigma_seen = sigma.len();
        }
        if let Some(stats) = sim.incisions() {
            self.strokes = stats.strokes as u32;
            self.lip_turn_deg = stats.lip_max_turn_deg;
        }
        self.wounds = sim.current_surface().wounds.len() as u32;
    }

    fn observe_force(&mut self, report: &TickReport, now: f64, dt: f64) {
        let f = report.tool_force_n.norm();
        let f = if f.is_finite() { f } else { 0.0 };
        self.peak_force_n = self.peak_force_n.max(f);
        let limits = self.plan.spec.force;
        if self.warning.observe(f > limits.warning_n, dt) {
            self.push_event(now, LessonEventKind::ForceWarning, f);
        }
        if self.critical.observe(f > limits.critical_n, dt) {
            self.push_event(now, LessonEventKind::ForceCritical, f);
        }
    }

    /// The edge from its tip to where it enters the surface, in rest space.
    fn observe_edge(&mut self, tip: &Vec3, entry: &Vec3, now: f64) {
        if let Some(on) = self.plan.nearest(entry) {
            let d = on.distance_m;
            self.dev_sq += d * d;
            self.dev_n += 1;
            self.dev_max = self.dev_max.max(d);
            let inc = &self.plan.incisions[on.incision];
            if d <= inc.deviation_m {
                // Fill the samples passed since the last tick on this incision (a fast hand
                // moves more than a sample a tick).
                let from = match self.last_on_plan {
                    Some((i, k)) if i == on.incision && k.abs_diff(on.sample) <= 20 => k,
                    _ => on.sample,
                };
                let (lo, hi) = (from.min(on.sample), from.max(on.sample));
                for k in lo..=hi {
                    let s = &inc.samples[k];
                    let depth = (s.at - tip).dot(&s.out);
                    let r = &mut self.reached[on.incision][k];
                    *r = r.max(depth);
                }
                self.last_on_plan = Some((on.incision, on.sample));
            } else {
                self.last_on_plan = None;
            }
        }
        for g in 0..self.no_go.len() {
            let spec = &self.plan.spec.no_go[g];
            let d = spec.shape.segment_distance(tip, entry);
            let contact = d <= spec.contact_margin_m;
            if contact && !self.no_go[g].contact {
                self.no_go[g].contacts += 1;
                self.last_contact = Some(g as u16);
                self.push_event(now, LessonEventKind::NoGoContact(g as u16), d);
            }
            self.no_go[g].contact = contact;
        }
    }

    /// A new triangle of the cut surface Σ (rest space).
    fn observe_sigma(&mut self, tri: &[Vec3; 3], now: f64) {
        let area = 0.5 * (tri[1] - tri[0]).cross(&(tri[2] - tri[0])).norm();
        let centre = (tri[0] + tri[1] + tri[2]) / 3.0;
        if self.plan.distance_to_band(&centre) > self.plan.widest_deviation_m {
            self.off_band_area_m2 += area;
        }
        for g in 0..self.no_go.len() {
            if self.no_go[g].cut {
                continue;
            }
            let deepest = self.plan.spec.no_go[g].shape.triangle_distance(tri);
            if deepest < 0.0 {
                self.no_go[g].cut = true;
                self.last_cut = Some(g as u16);
                self.push_event(now, LessonEventKind::NoGoCut(g as u16), deepest);
            }
        }
    }

    fn push_event(&mut self, time_s: f64, kind: LessonEventKind, value: f64) {
        let e = LessonEvent {
            time_s,
            kind,
            value,
        };
        let slot = (self.events_head + self.events_len) % EVENT_ROOM;
        self.events[slot] = Some(e);
        if self.events_len == EVENT_ROOM {
            self.events_head = (self.events_head + 1) % EVENT_ROOM;
            self.events_lost += 1;
        } else {
            self.events_len += 1;
        }
    }

    /// The oldest event not yet polled.
    pub fn poll_event(&mut self) -> Option<LessonEvent> {
        if self.events_len == 0 {
            return None;
        }
        let e = self.events[self.events_head].take();
        self.events_head = (self.events_head + 1) % EVENT_ROOM;
        self.events_len -= 1;
        e
    }

    /// Events overwritten before they were polled.
    pub fn events_lost(&self) -> u64 {
        self.events_lost
    }

    /// Whether no-go structure `g` has been cut into.
    pub fn no_go_cut(&self, g: usize) -> bool {
        self.no_go[g].cut
    }

    /// The metrics now (no allocation; a pass over the plan's samples).
    pub fn metrics(&self) -> Metrics {
        let started = self.first_in_s.is_some();
        let time_s = self.first_in_s.map_or(0.0, |t0| {
            if self.in_tissue {
                self.last_time_s - t0
            } else {
                self.last_in_s - t0
            }
        });
        let (mut depth_sq, mut depth_n, mut depth_max) = (0.0, 0usize, 0.0f64);
        let mut done_m = 0.0;
        for (inc, reached) in self.plan.incisions.iter().zip(&self.reached) {
            for (k, &r) in reached.iter().enumerate() {
                if !r.is_finite() {
                    continue;
                }
                let e = r - inc.depth_m;
                depth_sq += e * e;
                depth_n += 1;
                if e.abs() > depth_max.abs() {
                    depth_max = e;
                }
                if r >= inc.depth_m - inc.depth_tolerance_m {
                    // The sample stands for half of each piece of path beside it.
                    let s = &inc.samples;
                    let before = if k > 0 { s[k].s_m - s[k - 1].s_m } else { 0.0 };
                    let after = if k + 1 < s.len() {
                        s[k + 1].s_m - s[k].s_m
                    } else {
                        0.0
                    };
                    done_m += 0.5 * (before + after);
                }
            }
        }
        let rms = |sq: f64, n: f64| if n > 0.0 { (sq / n).sqrt() } else { 0.0 };
        let tool_path_m = self.travel_at_last_in_m;
        let mut m = Metrics {
            started,
            time_s,
            rms_deviation_m: rms(self.dev_sq, self.dev_n as f64),
            max_deviation_m: self.dev_max,
            rms_depth_error_m: rms(depth_sq, depth_n as f64),
            max_depth_error_m: depth_max,
            completed: if self.plan.length_m > 0.0 {
                (done_m / self.plan.length_m).min(1.0)
            } else {
                0.0
            },
            strokes: self.strokes,
            tool_path_m,
            economy: if self.plan.length_m > 0.0 {
                tool_path_m / self.plan.length_m
            } else {
                0.0
            },
            warning_events: self.warning.events,
            warning_s: self.warning.seconds,
            critical_events: self.critical.events,
            critical_s: self.critical.seconds,
            peak_force_n: self.peak_force_n,
            no_go_contacts: self.no_go.iter().map(|g| g.contacts).sum(),
            no_go_cuts: self.no_go.iter().filter(|g| g.cut).count() as u32,
            last_no_go_contact: self.last_contact,
            last_no_go_cut: self.last_cut,
            lip_turn_deg: self.lip_turn_deg,
            wounds: self.wounds,
            off_band_area_m2: self.off_band_area_m2,
            ..Metrics::default()
        };
        m.score = score(&m, &self.plan);
        m.shortfalls = shortfalls(&m, &self.plan);
        m.passed = m.shortfalls.0 == 0;
        m
    }
}

/// Weights of the score's parts (docs/LESSONS.md, "Score"); they sum to 1.
const W_COMPLETED: f64 = 0.25;
const W_PATH: f64 = 0.20;
const W_DEPTH: f64 = 0.20;
const W_ECONOMY: f64 = 0.10;
const W_FORCE: f64 = 0.15;
const W_DAMAGE: f64 = 0.10;
/// Seconds over the warning limit that take the force part to nothing.
const WARNING_S_TO_ZERO: f64 = 5.0;
/// The economy part is whole up to this tool path over planned length, nothing from
/// [`ECONOMY_NOTHING`] on.
const ECONOMY_WHOLE: f64 = 1.5;
const ECONOMY_NOTHING: f64 = 3.0;

/// The score (0–100) of metrics `m` on `plan`.
fn score(m: &Metrics, plan: &Plan) -> f64 {
    if !m.started {
        return 0.0;
    }
    let pass = &plan.spec.pass;
    let part = |x: f64| x.clamp(0.0, 1.0);
    let path = part(1.0 - m.rms_deviation_m / (2.0 * pass.max_rms_deviation_m));
    let depth = part(1.0 - m.rms_depth_error_m / (2.0 * pass.max_rms_depth_error_m));
    let economy = part((ECONOMY_NOTHING - m.economy) / (ECONOMY_NOTHING - ECONOMY_WHOLE));
    let force = if m.critical_events > 0 {
        0.0
    } else {
        part(1.0 - m.warning_s / WARNING_S_TO_ZERO)
    };
    let damage = part(1.0 - m.off_band_area_m2 / plan.band_area_m2.max(1e-12));
    // How well is worth as much as how much was done: a poke beside the plan (nothing
    // reached, a short path, no force) is not a good cut.
    let how_well =
        W_PATH * path + W_DEPTH * depth + W_ECONOMY * economy + W_FORCE * force + W_DAMAGE * damage;
    let whole = W_COMPLETED * m.completed + m.completed * how_well;
    let no_go = if m.no_go_cuts > 0 { 0.5 } else { 1.0 };
    100.0 * whole * no_go
}

/// The pass criteria `m` does not meet on `plan`.
fn shortfalls(m: &Metrics, plan: &Plan) -> Shortfalls {
    let pass = &plan.spec.pass;
    let mut bits = 0;
    if !m.started {
        bits |= Shortfalls::NOT_STARTED;
    }
    // Judged on the figures as a report prints them (a tenth of a per cent, a whole
    // point): "completed 90.0 % (needs 90 %)" never fails.
    let shown = |v: f64, per: f64| (v * per).round() / per;
    if shown(m.completed, 1000.0) < pass.min_completed {
        bits |= Shortfalls::INCOMPLETE;
    }
    if m.rms_deviation_m > pass.max_rms_deviation_m {
        bits |= Shortfalls::DEVIATION;
    }
    if m.rms_depth_error_m > pass.max_rms_depth_error_m {
        bits |= Shortfalls::DEPTH;
    }
    if m.critical_events > pass.max_critical_events {
        bits |= Shortfalls::CRITICAL_FORCE;
    }
    if m.no_go_cuts > pass.max_no_go_cuts {
        bits |= Shortfalls::NO_GO_CUT;
    }
    if m.time_s > plan.spec.time_limit_s {
        bits |= Shortfalls::TIME;
    }
    if m.score.round() < pass.min_score {
        bits |= Shortfalls::SCORE;
    }
    Shortfalls(bits)
}

impl Scorer {
    /// Why metrics `m` (this scorer's) fail, one sentence a criterion, for people
    /// (allocates: for reports, not for the tick).
    pub fn reasons(&self, m: &Metrics) -> Vec<String> {
        reasons(m, &self.plan, |g| self.no_go[g].cut)
    }
}

fn reasons(m: &Metrics, plan: &Plan, cut: impl Fn(usize) -> bool) -> Vec<String> {
    let pass = &plan.spec.pass;
    let f = m.shortfalls;
    let mut out = Vec::new();
    if f.has(Shortfalls::NOT_STARTED) {
        out.push("the blade never entered the tissue".to_string());
    }
    if f.has(Shortfalls::INCOMPLETE) {
        out.push(format!(
            "completed {:.1} % of the planned length (needs {:.0} %)",
            100.0 * m.completed,
            100.0 * pass.min_completed
        ));
    }
    if f.has(Shortfalls::DEVIATION) {
        out.push(format!(
            "strayed {:.1} mm RMS from the path (at most {:.1} mm)",
            m.rms_deviation_m * 1e3,
            pass.max_rms_deviation_m * 1e3
        ));
    }
    if f.has(Shortfalls::DEPTH) {
        out.push(format!(
            "depth off by {:.1} mm RMS (at most {:.1} mm; worst {:+.1} mm)",
            m.rms_depth_error_m * 1e3,
            pass.max_rms_depth_error_m * 1e3,
            m.max_depth_error_m * 1e3
        ));
    }
    if f.has(Shortfalls::CRITICAL_FORCE) {
        out.push(format!(
            "the force went over the critical {:.1} N {} (peak {:.1} N)",
            plan.spec.force.critical_n,
            match m.critical_events {
                1 => "once".to_string(),
                n => format!("{n} times"),
            },
            m.peak_force_n
        ));
    }
    if f.has(Shortfalls::NO_GO_CUT) {
        let names: Vec<&str> = plan
            .spec
            .no_go
            .iter()
            .enumerate()
            .filter(|(g, _)| cut(*g))
            .map(|(_, n)| n.name.as_str())
            .collect();
        out.push(format!("cut into {}", names.join(", ")));
    }
    if f.has(Shortfalls::TIME) {
        out.push(format!(
            "took {:.1} s (limit {:.0} s)",
            m.time_s, plan.spec.time_limit_s
        ));
    }
    if f.has(Shortfalls::SCORE) {
        out.push(format!(
            "scored {:.0} (needs {:.0})",
            m.score.round(),
            pass.min_score
        ));
    }
    out
}
