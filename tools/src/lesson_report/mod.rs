//! A scored session: the scorer and the traces a report plots, fed tick by tick (from a
//! scripted trainee run offline, or replaying a station's journal), and the report written
//! from them: `report.json` and a self-contained `report.html` (docs/LESSONS.md, "Reports").

mod html;
pub mod lab;

use std::path::Path;

use anyhow::Context;
use scalpel_sim::lesson::{LessonEvent, LessonEventKind, Metrics, Plan, Scorer};
use scalpel_sim::pipeline::{Simulation, TickReport};
use serde::Serialize;
use std::time::Instant;

use crate::stats::Quantiles;

/// Ticks a trace point stands for (the plots' resolution: 10 ms).
const TRACE_EVERY: usize = 10;

/// A session being scored.
pub struct ScoredSession {
    /// The scorer.
    pub scorer: Scorer,
    /// The largest force over each [`TRACE_EVERY`] ticks, with the window's end time.
    pub force: Vec<(f64, f64)>,
    /// Where the blade entered the tissue (rest, m), every [`TRACE_EVERY`] ticks it did.
    pub entries: Vec<[f64; 3]>,
    /// Every event, in order.
    pub events: Vec<LessonEvent>,
    /// Ticks seen.
    pub ticks: usize,
    window_peak: f64,
    /// Wall time of each tick's scoring (s), and of the simulation's tick before it (the
    /// time from the last scoring's end to this one's start).
    scoring_s: Vec<f64>,
    tick_s: Vec<f64>,
    last_end: Option<Instant>,
    started: Instant,
}

impl ScoredSession {
    /// A session scored against `plan`.
    pub fn new(plan: Plan) -> Self {
        Self {
            scorer: Scorer::new(plan),
            force: Vec::new(),
            entries: Vec::new(),
            events: Vec::new(),
            ticks: 0,
            window_peak: 0.0,
            scoring_s: Vec::new(),
            tick_s: Vec::new(),
            last_end: None,
            started: Instant::now(),
        }
    }

    /// Reads the tick `sim` has just made.
    pub fn observe(&mut self, sim: &Simulation, report: &TickReport, dt: f64) {
        let start = Instant::now();
        if let Some(end) = self.last_end {
            self.tick_s.push((start - end).as_secs_f64());
        }
        self.scorer.observe(sim, report, dt);
        let scored = Instant::now();
        self.scoring_s.push((scored - start).as_secs_f64());
        self.last_end = Some(scored);
        while let Some(e) = self.scorer.poll_event() {
            self.events.push(e);
        }
        self.ticks += 1;
        let f = report.tool_force_n.norm();
        if f.is_finite() {
            self.window_peak = self.window_peak.max(f);
        }
        if self.ticks.is_multiple_of(TRACE_EVERY) {
            self.force.push((report.time_s, self.window_peak));
            self.window_peak = 0.0;
            if let Some([_, entry]) = report
                .cut
                .as_ref()
                .filter(|c| c.in_tissue)
                .and_then(|c| c.edge_rest)
            {
                self.entries.push(entry.into());
            }
        }
    }

    /// The report of the session so far. `trainee` is who cut (from the station's
    /// configuration, never guessed); `source` what was scored (a journal, a script).
    pub fn report(&self, trainee: Option<String>, source: String) -> LessonReport {
        let m = self.scorer.metrics();
        let plan = self.scorer.plan();
        let spec = &plan.spec;
        LessonReport {
            lesson: spec.name.clone(),
            description: spec.description.clone(),
            scene: spec.scene.clone(),
            trainee,
            source,
            ticks: self.ticks,
            passed: m.passed,
            score: m.score.round(),
            reasons: self.scorer.reasons(&m),
            metrics: MetricsJson::from(&m),
            limits: LimitsJson {
                warning_n: spec.force.warning_n,
                critical_n: spec.force.critical_n,
                time_limit_s: spec.time_limit_s,
                min_completed_percent: 100.0 * spec.pass.min_completed,
                max_rms_deviation_mm: spec.pass.max_rms_deviation_m * 1e3,
                max_rms_depth_error_mm: spec.pass.max_rms_depth_error_m * 1e3,
                max_critical_events: spec.pass.max_critical_events,
                max_no_go_cuts: spec.pass.max_no_go_cuts,
                min_score: spec.pass.min_score,
            },
            events: self
                .events
                .iter()
                .map(|e| EventJson::from_event(e, plan))
                .collect(),
            events_lost: self.scorer.events_lost(),
            timing: TimingJson {
                scoring_us: Quantiles::or_zero(
                    &self.scoring_s.iter().map(|s| s * 1e6).collect::<Vec<_>>(),
                ),
                tick_ms: Quantiles::or_zero(
                    &self.tick_s.iter().map(|s| s * 1e3).collect::<Vec<_>>(),
                ),
                total_s: self.started.elapsed().as_secs_f64(),
            },
        }
    }

    /// Writes `report.json` and `report.html` into `dir` (created if missing).
    pub fn write(&self, report: &LessonReport, dir: &Path) -> anyhow::Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let json = dir.join("report.json");
        std::fs::write(&json, serde_json::to_string_pretty(report)? + "\n")
            .with_context(|| format!("writing {}", json.display()))?;
        let page = dir.join("report.html");
        std::fs::write(&page, html::page(self, report))
            .with_context(|| format!("writing {}", page.display()))?;
        Ok(())
    }
}

fn round(v: f64, digits: i32) -> f64 {
    let k = 10f64.powi(digits);
    (v * k).round() / k
}

/// `report.json` (docs/LESSONS.md, "Reports").
#[derive(Debug, Clone, Serialize)]
pub struct LessonReport {
    /// The lesson's name.
    pub lesson: String,
    /// What it asks.
    pub description: String,
    /// Its scene.
    pub scene: String,
    /// Who cut, when the station's configuration says.
    pub trainee: Option<String>,
    /// What was scored.
    pub source: String,
    /// Ticks scored.
    pub ticks: usize,
    /// Every pass criterion held.
    pub passed: bool,
    /// 0–100.
    pub score: f64,
    /// Why not passed, one sentence a criterion.
    pub reasons: Vec<String>,
    /// The metrics.
    pub metrics: MetricsJson,
    /// The lesson's limits and criteria.
    pub limits: LimitsJson,
    /// Force-limit and no-go events.
    pub events: Vec<EventJson>,
    /// Events the scorer overwrote before they were read (0 unless a session floods it).
    pub events_lost: u64,
    /// What scoring cost, on this machine.
    pub timing: TimingJson,
}

/// What scoring cost: each tick's scoring (µs), the simulation's tick it scored (ms), and
/// the whole run or replay with its scoring (s), on the machine that made the report.
#[derive(Debug, Clone, Serialize)]
pub struct TimingJson {
    pub scoring_us: Quantiles,
    pub tick_ms: Quantiles,
    pub total_s: f64,
}

/// The metrics in the units people read (mm, s, N).
#[derive(Debug, Clone, Serialize)]
pub struct MetricsJson {
    pub time_s: f64,
    pub rms_deviation_mm: f64,
    pub max_deviation_mm: f64,
    pub rms_depth_error_mm: f64,
    pub max_depth_error_mm: f64,
    pub completed_percent: f64,
    pub strokes: u32,
    pub tool_path_mm: f64,
    pub economy: f64,
    pub warning_events: u32,
    pub warning_s: f64,
    pub critical_events: u32,
    pub critical_s: f64,
    pub peak_force_n: f64,
    pub no_go_contacts: u32,
    pub no_go_cuts: u32,
    pub lip_turn_deg: f64,
    pub wounds: u32,
    pub off_band_area_mm2: f64,
}

impl From<&Metrics> for MetricsJson {
    fn from(m: &Metrics) -> Self {
        Self {
            time_s: round(m.time_s, 3),
            rms_deviation_mm: round(m.rms_deviation_m * 1e3, 2),
            max_deviation_mm: round(m.max_deviation_m * 1e3, 2),
            rms_depth_error_mm: round(m.rms_depth_error_m * 1e3, 2),
            max_depth_error_mm: round(m.max_depth_error_m * 1e3, 2),
            completed_percent: round(100.0 * m.completed, 1),
            strokes: m.strokes,
            tool_path_mm: round(m.tool_path_m * 1e3, 1),
            economy: round(m.economy, 3),
            warning_events: m.warning_events,
            warning_s: round(m.warning_s, 3),
            critical_events: m.critical_events,
            critical_s: round(m.critical_s, 3),
            peak_force_n: round(m.peak_force_n, 3),
            no_go_contacts: m.no_go_contacts,
            no_go_cuts: m.no_go_cuts,
            lip_turn_deg: round(m.lip_turn_deg, 1),
            wounds: m.wounds,
            off_band_area_mm2: round(m.off_band_area_m2 * 1e6, 1),
        }
    }
}

/// The lesson's limits.
#[derive(Debug, Clone, Serialize)]
pub struct LimitsJson {
    pub warning_n: f64,
    pub critical_n: f64,
    pub time_limit_s: f64,
    pub min_completed_percent: f64,
    pub max_rms_deviation_mm: f64,
    pub max_rms_depth_error_mm: f64,
    pub max_critical_events: u32,
    pub max_no_go_cuts: u32,
    pub min_score: f64,
}

/// An event.
#[derive(Debug, Clone, Serialize)]
pub struct EventJson {
    /// Simulated time (s).
    pub time_s: f64,
    /// `force-warning`, `force-critical`, `no-go-contact` or `no-go-cut`.
    pub kind: &'static str,
    /// The no-go structure's name, for no-go events.
    pub structure: Option<String>,
    /// The force (N), or the edge's distance from the structure's surface (mm, negative
    /// inside).
    pub value: f64,
}

impl EventJson {
    fn from_event(e: &LessonEvent, plan: &Plan) -> Self {
        let name = |g: u16| Some(plan.spec.no_go[g as usize].name.clone());
        let (kind, structure, value) = match e.kind {
            LessonEventKind::ForceWarning => ("force-warning", None, e.value),
            LessonEventKind::ForceCritical => ("force-critical", None, e.value),
            LessonEventKind::NoGoContact(g) => ("no-go-contact", name(g), e.value * 1e3),
            LessonEventKind::NoGoCut(g) => ("no-go-cut", name(g), e.value * 1e3),
        };
        Self {
            time_s: round(e.time_s, 3),
            kind,
            structure,
            value: round(value, 3),
        }
    }
}

/// The report for people on a terminal.
pub fn summary(r: &LessonReport) -> String {
    let m = &r.metrics;
    let mut s = format!(
        "lesson {} on {}{}: {} — score {:.0}\n",
        r.lesson,
        r.scene,
        r.trainee
            .as_ref()
            .map(|t| format!(", trainee {t}"))
            .unwrap_or_default(),
        if r.passed { "PASS" } else { "FAIL" },
        r.score
    );
    for why in &r.reasons {
        s += &format!("  - {why}\n");
    }
    s += &format!(
        "  path {:.1} mm RMS ({:.1} max), depth error {:.1} mm RMS ({:+.1} worst), \
         completed {:.0} %\n",
        m.rms_deviation_mm,
        m.max_deviation_mm,
        m.rms_depth_error_mm,
        m.max_depth_error_mm,
        m.completed_percent
    );
    s += &format!(
        "  {} strokes in {:.1} s, economy {:.2}, peak force {:.2} N ({} warning, {} critical), \
         no-go {} contacts {} cuts, {} wounds, lip turn {:.0}°, {:.0} mm² cut off the band\n  \
         scoring {:.1} µs a tick (p99 {:.1}) beside the simulation's {:.2} ms (p99 {:.2}); {:.1} s in all",
        m.strokes,
        m.time_s,
        m.economy,
        m.peak_force_n,
        m.warning_events,
        m.critical_events,
        m.no_go_contacts,
        m.no_go_cuts,
        m.wounds,
        m.lip_turn_deg,
        m.off_band_area_mm2,
        r.timing.scoring_us.p50,
        r.timing.scoring_us.p99,
        r.timing.tick_ms.p50,
        r.timing.tick_ms.p99,
        r.timing.total_s
    );
    s
}
