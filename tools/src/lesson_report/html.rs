//! `report.html`: one self-contained page (inline CSS and SVG, no script, nothing fetched):
//! the plan against the cut from above, the depth profile, the force against time with the
//! limits, the metrics table, pass or fail and the events.

use std::fmt::Write as _;

use super::{LessonReport, ScoredSession};

const W: f64 = 640.0;
/// Most points a plot draws (a 10-minute session has 60 000 force samples; the plot is
/// 544 pixels wide): more are merged, a bucket's largest force kept.
const MOST_POINTS: usize = 2000;
const H: f64 = 300.0;
const PAD: f64 = 48.0;

/// Escapes text for HTML.
pub(super) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A plot's frame: data ranges mapped onto the SVG's area.
pub(super) struct Frame {
    x: (f64, f64),
    y: (f64, f64),
    /// x counts something: ticks at whole numbers.
    pub(super) whole_x: bool,
}

impl Frame {
    pub(super) fn new(x: (f64, f64), y: (f64, f64), equal: bool) -> Self {
        let widen = |(lo, hi): (f64, f64)| {
            if hi - lo < 1e-9 {
                (lo - 1.0, hi + 1.0)
            } else {
                let m = 0.05 * (hi - lo);
                (lo - m, hi + m)
            }
        };
        let (mut x, mut y) = (widen(x), widen(y));
        if equal {
            // Grow the narrower range so that both axes have one scale.
            let sx = (x.1 - x.0) / (W - 2.0 * PAD);
            let sy = (y.1 - y.0) / (H - 2.0 * PAD);
            if sx > sy {
                let grow = 0.5 * (sx * (H - 2.0 * PAD) - (y.1 - y.0));
                y = (y.0 - grow, y.1 + grow);
            } else {
                let grow = 0.5 * (sy * (W - 2.0 * PAD) - (x.1 - x.0));
                x = (x.0 - grow, x.1 + grow);
            }
        }
        Self {
            x,
            y,
            whole_x: false,
        }
    }

    pub(super) fn px(&self, x: f64) -> f64 {
        PAD + (x - self.x.0) / (self.x.1 - self.x.0) * (W - 2.0 * PAD)
    }

    pub(super) fn py(&self, y: f64) -> f64 {
        H - PAD - (y - self.y.0) / (self.y.1 - self.y.0) * (H - 2.0 * PAD)
    }

    fn scale(&self) -> f64 {
        (W - 2.0 * PAD) / (self.x.1 - self.x.0)
    }

    /// The axes with their labels and a few ticks, then the plot area clipped for its data
    /// (`id` names the clip; [`Frame::close`] ends it and draws the frame's border over it).
    pub(super) fn axes(&self, svg: &mut String, id: &str, x_label: &str, y_label: &str) {
        let (w, h) = (W - 2.0 * PAD, H - 2.0 * PAD);
        let _ = write!(
            svg,
            r##"<rect x="{PAD}" y="{PAD}" width="{w}" height="{h}" fill="#fbfbfb"/><clipPath id="clip-{id}"><rect x="{PAD}" y="{PAD}" width="{w}" height="{h}"/></clipPath>"##
        );
        let mut label = |x: f64, y: f64, text: String, anchor: &str| {
            let _ = write!(
                svg,
                r##"<text x="{x:.1}" y="{y:.1}" font-size="11" text-anchor="{anchor}">{text}</text>"##
            );
        };
        for k in 0..=4 {
            let f = k as f64 / 4.0;
            let yv = self.y.0 + f * (self.y.1 - self.y.0);
            label(PAD - 4.0, self.py(yv) + 4.0, short(yv), "end");
            if !self.whole_x {
                let xv = self.x.0 + f * (self.x.1 - self.x.0);
                label(self.px(xv), H - PAD + 14.0, short(xv), "middle");
            }
        }
        if self.whole_x {
            // Counts (sessions) are labelled at whole numbers only, at most ten of them.
            let (first, last) = (self.x.0.ceil() as i64, self.x.1.floor() as i64);
            let step = ((last - first) / 10 + 1).max(1);
            for v in (first..=last).step_by(step as usize) {
                label(self.px(v as f64), H - PAD + 14.0, v.to_string(), "middle");
            }
        }
        let _ = write!(
            svg,
            r##"<text x="{:.1}" y="{:.1}" font-size="12" text-anchor="middle">{}</text><text x="12" y="{:.1}" font-size="12" text-anchor="middle" transform="rotate(-90 12 {:.1})">{}</text>"##,
            W / 2.0,
            H - 8.0,
            esc(x_label),
            H / 2.0,
            H / 2.0,
            esc(y_label)
        );
        let _ = write!(svg, r##"<g clip-path="url(#clip-{id})">"##);
    }

    /// Ends the clipped data and draws the frame's border.
    pub(super) fn close(&self, svg: &mut String) {
        let _ = write!(
            svg,
            r##"</g><rect x="{PAD}" y="{PAD}" width="{}" height="{}" fill="none" stroke="#888"/></svg></figure>"##,
            W - 2.0 * PAD,
            H - 2.0 * PAD
        );
    }

    pub(super) fn polyline(&self, svg: &mut String, points: &[(f64, f64)], style: &str) {
        if points.is_empty() {
            return;
        }
        let mut d = String::with_capacity(points.len() * 16);
        for (x, y) in points {
            let _ = write!(d, "{:.1},{:.1} ", self.px(*x), self.py(*y));
        }
        let _ = write!(svg, r#"<polyline fill="none" {style} points="{d}"/>"#);
    }
}

/// `points` in at most `most` buckets, each its last time and largest value.
fn peaks(points: &[(f64, f64)], most: usize) -> Vec<(f64, f64)> {
    let per = points.len().div_ceil(most).max(1);
    points
        .chunks(per)
        .map(|c| {
            (
                c[c.len() - 1].0,
                c.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max),
            )
        })
        .collect()
}

/// A tick label.
fn short(v: f64) -> String {
    if v.abs() >= 100.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

pub(super) fn open_svg(title: &str, id: &str) -> String {
    format!(
        r##"<figure><figcaption>{}</figcaption><svg id="{id}" class="plot" xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}">"##,
        esc(title)
    )
}

/// The plan (its allowed band) and the cut's path from above, with the no-go structures.
fn top_view(session: &ScoredSession) -> String {
    let plan = session.scorer.plan();
    let mut xs: Vec<f64> = Vec::new();
    let mut ys: Vec<f64> = Vec::new();
    for inc in &plan.incisions {
        for s in &inc.samples {
            xs.push(s.at.x * 1e3);
            ys.push(s.at.y * 1e3);
        }
    }
    for e in &session.entries {
        xs.push(e[0] * 1e3);
        ys.push(e[1] * 1e3);
    }
    let range = |v: &[f64]| {
        v.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
                (lo.min(x), hi.max(x))
            })
    };
    let frame = Frame::new(range(&xs), range(&ys), true);
    let mut svg = open_svg(
        "The plan (grey: the allowed band) and the cut (red), from above",
        "top-view",
    );
    frame.axes(&mut svg, "top", "x (mm)", "y (mm)");
    for g in &plan.spec.no_go {
        use scalpel_sim::lesson::NoGoShape;
        match g.shape {
            NoGoShape::Sphere { centre, radius } => {
                let _ = write!(
                    svg,
                    r##"<circle cx="{:.1}" cy="{:.1}" r="{:.1}" fill="#f3c1c1" stroke="#b22"/>"##,
                    frame.px(centre.x * 1e3),
                    frame.py(centre.y * 1e3),
                    radius * 1e3 * frame.scale()
                );
            }
            NoGoShape::Tube { from, to, radius } => {
                let _ = write!(
                    svg,
                    r##"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="#f3c1c1" stroke-width="{:.1}" stroke-linecap="round"/>"##,
                    frame.px(from.x * 1e3),
                    frame.py(from.y * 1e3),
                    frame.px(to.x * 1e3),
                    frame.py(to.y * 1e3),
                    2.0 * radius * 1e3 * frame.scale()
                );
            }
        }
    }
    for inc in &plan.incisions {
        let path: Vec<(f64, f64)> = inc
            .samples
            .iter()
            .map(|s| (s.at.x * 1e3, s.at.y * 1e3))
            .collect();
        let band = format!(
            r##"stroke="#d8d8d8" stroke-width="{:.1}" stroke-linecap="round" stroke-linejoin="round""##,
            2.0 * inc.deviation_m * 1e3 * frame.scale()
        );
        frame.polyline(&mut svg, &path, &band);
        frame.polyline(
            &mut svg,
            &path,
            r##"stroke="#555" stroke-width="1.5" stroke-dasharray="4 3""##,
        );
    }
    let every = session.entries.len().div_ceil(MOST_POINTS).max(1);
    for e in session.entries.iter().step_by(every) {
        let _ = write!(
            svg,
            r##"<circle cx="{:.1}" cy="{:.1}" r="1.6" fill="#c0392b"/>"##,
            frame.px(e[0] * 1e3),
            frame.py(e[1] * 1e3)
        );
    }
    frame.close(&mut svg);
    svg
}

/// The depth the cut reached along each planned incision, against its target and band.
fn depth_profile(session: &ScoredSession) -> String {
    let plan = session.scorer.plan();
    let mut offset = 0.0;
    let mut reached: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut targets = Vec::new();
    let mut deepest: f64 = 0.0;
    for (i, inc) in plan.incisions.iter().enumerate() {
        let depths = session.scorer.depth_reached(i);
        let mut run = Vec::new();
        for (s, &d) in inc.samples.iter().zip(depths) {
            if d.is_finite() {
                run.push(((offset + s.s_m) * 1e3, -d * 1e3));
                deepest = deepest.max(d);
            } else if !run.is_empty() {
                reached.push(std::mem::take(&mut run));
            }
        }
        if !run.is_empty() {
            reached.push(run);
        }
        targets.push((
            offset,
            offset + inc.length_m,
            inc.depth_m,
            inc.depth_tolerance_m,
        ));
        deepest = deepest.max(inc.depth_m + inc.depth_tolerance_m);
        offset += inc.length_m;
    }
    let frame = Frame::new((0.0, offset * 1e3), (-deepest * 1.1e3, 0.0), false);
    let mut svg = open_svg(
        "Depth reached along the plan (red) against the target (dashed) and its tolerance (green)",
        "depth-profile",
    );
    frame.axes(&mut svg, "depth", "along the plan (mm)", "depth (mm)");
    for (a, b, depth, tol) in targets {
        let (top, bottom) = (-(depth - tol) * 1e3, -(depth + tol) * 1e3);
        let _ = write!(
            svg,
            r##"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="#d5f0d5"/>"##,
            frame.px(a * 1e3),
            frame.py(top),
            frame.px(b * 1e3) - frame.px(a * 1e3),
            frame.py(bottom) - frame.py(top)
        );
        frame.polyline(
            &mut svg,
            &[(a * 1e3, -depth * 1e3), (b * 1e3, -depth * 1e3)],
            r##"stroke="#555" stroke-dasharray="4 3""##,
        );
    }
    for run in &reached {
        frame.polyline(&mut svg, run, r##"stroke="#c0392b" stroke-width="2""##);
    }
    frame.close(&mut svg);
    svg
}

/// The force on the device against time, with the warning and critical limits.
fn force_plot(session: &ScoredSession, report: &LessonReport) -> String {
    let t_end = session.force.last().map_or(1.0, |f| f.0);
    let peak = session.force.iter().map(|f| f.1).fold(0.0, f64::max);
    let top = peak.max(report.limits.critical_n) * 1.1;
    let frame = Frame::new((0.0, t_end), (0.0, top), false);
    let mut svg = open_svg(
        "Force on the device against time, with the warning (orange) and critical (red) limits",
        "force-plot",
    );
    frame.axes(&mut svg, "force", "time (s)", "force (N)");
    for (limit, colour) in [
        (report.limits.warning_n, "#e67e22"),
        (report.limits.critical_n, "#c0392b"),
    ] {
        frame.polyline(
            &mut svg,
            &[(0.0, limit), (t_end, limit)],
            &format!(r##"stroke="{colour}" stroke-dasharray="6 3""##),
        );
    }
    frame.polyline(
        &mut svg,
        &peaks(&session.force, MOST_POINTS),
        r##"stroke="#2c3e80" stroke-width="1.5""##,
    );
    frame.close(&mut svg);
    svg
}

/// The whole page.
pub fn page(session: &ScoredSession, report: &LessonReport) -> String {
    let m = &report.metrics;
    let l = &report.limits;
    let verdict = if report.passed { "PASS" } else { "FAIL" };
    let mut s = String::with_capacity(64 * 1024);
    let _ = write!(
        s,
        r##"<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>scalpel report: {lesson}</title>
<style>body{{font-family:sans-serif;margin:24px;color:#222}} table{{border-collapse:collapse}} td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}} td.n{{text-align:right}} .PASS{{color:#1e7d32}} .FAIL{{color:#b71c1c}} figure{{display:inline-block;margin:8px}} figcaption{{font-size:13px;max-width:640px}}</style></head><body>
<h1>{lesson} <span class="{verdict}" id="verdict">{verdict}</span> — score {score:.0}</h1>
<p>{description}</p><p>Scene {scene}; trainee {trainee}; scored from {source} ({ticks} ticks).</p>"##,
        lesson = esc(&report.lesson),
        description = esc(&report.description),
        scene = esc(&report.scene),
        trainee = esc(report.trainee.as_deref().unwrap_or("not named")),
        source = esc(&report.source),
        ticks = report.ticks,
        score = report.score,
    );
    if !report.reasons.is_empty() {
        s += "<ul id=\"reasons\">";
        for why in &report.reasons {
            let _ = write!(s, "<li>{}</li>", esc(why));
        }
        s += "</ul>";
    }
    s += &top_view(session);
    s += &depth_profile(session);
    s += &force_plot(session, report);
    let rows: [(&str, String, String); 16] = [
        (
            "time",
            format!("{:.1} s", m.time_s),
            format!("≤ {:.0} s", l.time_limit_s),
        ),
        (
            "path deviation, RMS",
            format!("{:.2} mm", m.rms_deviation_mm),
            format!("≤ {:.1} mm", l.max_rms_deviation_mm),
        ),
        (
            "path deviation, max",
            format!("{:.2} mm", m.max_deviation_mm),
            String::new(),
        ),
        (
            "depth error, RMS",
            format!("{:.2} mm", m.rms_depth_error_mm),
            format!("≤ {:.1} mm", l.max_rms_depth_error_mm),
        ),
        (
            "depth error, worst",
            format!("{:+.2} mm", m.max_depth_error_mm),
            String::new(),
        ),
        (
            "completed",
            format!("{:.0} %", m.completed_percent),
            format!("≥ {:.0} %", l.min_completed_percent),
        ),
        ("strokes", m.strokes.to_string(), String::new()),
        (
            "economy of motion",
            format!("{:.2} ({:.0} mm of tool path)", m.economy, m.tool_path_mm),
            String::new(),
        ),
        (
            "force over warning",
            format!("{} times, {:.2} s", m.warning_events, m.warning_s),
            format!("{:.1} N", l.warning_n),
        ),
        (
            "force over critical",
            format!("{} times, {:.2} s", m.critical_events, m.critical_s),
            format!(
                "≤ {} times over {:.1} N",
                l.max_critical_events, l.critical_n
            ),
        ),
        (
            "peak force",
            format!("{:.2} N", m.peak_force_n),
            String::new(),
        ),
        (
            "no-go contacts",
            m.no_go_contacts.to_string(),
            String::new(),
        ),
        (
            "no-go structures cut",
            m.no_go_cuts.to_string(),
            format!("≤ {}", l.max_no_go_cuts),
        ),
        (
            "wounds, lip turn",
            format!("{}, {:.0}°", m.wounds, m.lip_turn_deg),
            String::new(),
        ),
        (
            "cut outside the band",
            format!("{:.0} mm²", m.off_band_area_mm2),
            String::new(),
        ),
        (
            "score",
            format!("{:.0}", report.score),
            format!("≥ {:.0}", l.min_score),
        ),
    ];
    s += "<h2>Metrics</h2><table id=\"metrics\"><tr><th>metric</th><th>value</th><th>criterion</th></tr>";
    for (name, value, criterion) in rows {
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
            esc(name),
            esc(&value),
            esc(&criterion)
        );
    }
    s += "</table><h2>Events</h2>";
    if report.events.is_empty() {
        s += "<p>None.</p>";
    } else {
        s += "<table id=\"events\"><tr><th>time (s)</th><th>event</th><th>structure</th><th>value</th></tr>";
        for e in &report.events {
            let _ = write!(
                s,
                "<tr><td class=\"n\">{:.3}</td><td>{}</td><td>{}</td><td class=\"n\">{:.3} {}</td></tr>",
                e.time_s,
                e.kind,
                esc(e.structure.as_deref().unwrap_or("")),
                e.value,
                if e.kind.starts_with("force") {
                    "N"
                } else {
                    "mm"
                }
            );
        }
        s += "</table>";
    }
    s += "<p>Definitions: docs/LESSONS.md.</p></body></html>\n";
    s
}
