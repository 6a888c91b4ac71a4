//! The lesson on the observer stream (docs/PROTOCOL.md, protocol 3): the plan as observers
//! get it first, the running score at 10 Hz, and events when a force limit is crossed or a
//! no-go structure touched or cut, read from the counters of the metrics the simulation
//! thread hands over.

use scalpel_proto::wire::{EventKind, LessonPlan, LessonScore, NoGoStructure, PlannedPath};
use scalpel_sim::lesson::{Metrics, NoGoShape, Plan};

/// Plan points sent every this many samples (2 mm).
const POINT_EVERY: usize = 4;

/// The plan as observers get it; `trainee` as the station's configuration names them.
pub fn plan_message(plan: &Plan, trainee: &str) -> LessonPlan {
    let mm =
        |v: scalpel_sim::math::Vec3| [(v.x * 1e3) as f32, (v.y * 1e3) as f32, (v.z * 1e3) as f32];
    let spec = &plan.spec;
    LessonPlan {
        name: spec.name.clone(),
        description: spec.description.clone(),
        trainee: trainee.to_string(),
        incisions: plan
            .incisions
            .iter()
            .map(|c| {
                let last = c.samples.len() - 1;
                let mut points_mm: Vec<[f32; 3]> = c
                    .samples
                    .iter()
                    .step_by(POINT_EVERY)
                    .map(|s| mm(s.at))
                    .collect();
                if last % POINT_EVERY != 0 {
                    points_mm.push(mm(c.samples[last].at));
                }
                PlannedPath {
                    name: c.name.clone(),
                    points_mm,
                    depth_mm: (c.depth_m * 1e3) as f32,
                    depth_tolerance_mm: (c.depth_tolerance_m * 1e3) as f32,
                    deviation_mm: (c.deviation_m * 1e3) as f32,
                }
            })
            .collect(),
        no_go: spec
            .no_go
            .iter()
            .map(|g| {
                let (from, to, radius) = match g.shape {
                    NoGoShape::Sphere { centre, radius } => (centre, centre, radius),
                    NoGoShape::Tube { from, to, radius } => (from, to, radius),
                };
                NoGoStructure {
                    name: g.name.clone(),
                    from_mm: mm(from),
                    to_mm: mm(to),
                    radius_mm: (radius * 1e3) as f32,
                }
            })
            .collect(),
        warning_n: spec.force.warning_n as f32,
        critical_n: spec.force.critical_n as f32,
        time_limit_s: spec.time_limit_s as f32,
        min_score: spec.pass.min_score as f32,
    }
}

/// The metrics as observers get them.
pub fn score_message(m: &Metrics, sim_tick: u64) -> LessonScore {
    LessonScore {
        sim_tick,
        time_s: m.time_s as f32,
        rms_deviation_mm: (m.rms_deviation_m * 1e3) as f32,
        max_deviation_mm: (m.max_deviation_m * 1e3) as f32,
        rms_depth_error_mm: (m.rms_depth_error_m * 1e3) as f32,
        max_depth_error_mm: (m.max_depth_error_m * 1e3) as f32,
        completed_percent: (m.completed * 100.0) as f32,
        strokes: m.strokes,
        economy: m.economy as f32,
        warning_events: m.warning_events,
        critical_events: m.critical_events,
        peak_force_n: m.peak_force_n as f32,
        no_go_contacts: m.no_go_contacts,
        no_go_cuts: m.no_go_cuts,
        lip_turn_deg: m.lip_turn_deg as f32,
        wounds: m.wounds,
        off_band_area_mm2: (m.off_band_area_m2 * 1e6) as f32,
        score: m.score as f32,
        passed: m.passed,
        shortfalls: m.shortfalls.0,
    }
}

/// The events since the last metrics seen: a counter that grew is an event.
#[derive(Default)]
pub struct LessonEvents {
    last: Metrics,
    /// The lesson's no-go structures, by index.
    no_go: Vec<String>,
}

impl LessonEvents {
    /// The events of `plan`'s metrics.
    pub fn new(plan: Option<&Plan>) -> Self {
        Self {
            last: Metrics::default(),
            no_go: plan.map_or_else(Vec::new, |p| {
                p.spec.no_go.iter().map(|g| g.name.clone()).collect()
            }),
        }
    }

    /// The name of no-go structure `g`.
    fn structure(&self, g: Option<u16>) -> &str {
        g.and_then(|g| self.no_go.get(usize::from(g)))
            .map_or("a no-go structure", String::as_str)
    }

    /// The events `now` brings over the last metrics, with a line each for people.
    pub fn since(&mut self, now: &Metrics) -> Vec<(EventKind, String)> {
        let was = std::mem::replace(&mut self.last, *now);
        // Counters read every 10 ticks: several rises between two reads are said as one
        // event with how many.
        let times = |n: u32| {
            if n == 1 {
                String::new()
            } else {
                format!(" ({n} times)")
            }
        };
        let mut out = Vec::new();
        for (kind, limit, before, after) in [
            (
                EventKind::ForceWarning,
                "warning",
                was.warning_events,
                now.warning_events,
            ),
            (
                EventKind::ForceCritical,
                "critical",
                was.critical_events,
                now.critical_events,
            ),
        ] {
            if after > before {
                out.push((
                    kind,
                    format!(
                        "force over the lesson's {limit} limit{} (peak so far {:.2} N)",
                        times(after - before),
                        now.peak_force_n
                    ),
                ));
            }
        }
        for (kind, what, before, after, structure) in [
            (
                EventKind::NoGoContact,
                "the blade touched",
                was.no_go_contacts,
                now.no_go_contacts,
                now.last_no_go_contact,
            ),
            (
                EventKind::NoGoCut,
                "the cut reached into",
                was.no_go_cuts,
                now.no_go_cuts,
                now.last_no_go_cut,
            ),
        ] {
            if after > before {
                out.push((
                    kind,
                    format!(
                        "{what} {}{}",
                        self.structure(structure),
                        times(after - before)
                    ),
                ));
            }
        }
        out
    }
}
