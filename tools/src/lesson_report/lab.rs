//! The lab summary (`scalpel report --lab DIR`): every scored session in the lab's archive,
//! per trainee and lesson in the order they were cut — the learning curve — written as
//! `lab.csv` (one row a session), `lab.json` and a self-contained `lab.html` (a curve per
//! trainee, a table per trainee). docs/LESSONS.md, "The lab summary".

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use serde::Serialize;

use super::html::{Frame, esc, open_svg};
use crate::archive::{Figures, ScoredRow};

/// `lab.json`.
#[derive(Debug, Clone, Serialize)]
pub struct LabSummary {
    /// The archive read (a PostgreSQL URL without its password).
    pub archive: String,
    /// Sessions in the archive, scored or not.
    pub sessions: i64,
    /// Scored sessions.
    pub scored: usize,
    /// Journals archived by this run.
    pub added: usize,
    /// Journals refused by this run, with why.
    pub refused: Vec<Refused>,
    /// One a trainee, by name; sessions whose station named no trainee last.
    pub trainees: Vec<TraineeCurve>,
}

/// A journal not archived.
#[derive(Debug, Clone, Serialize)]
pub struct Refused {
    pub journal: String,
    pub error: String,
}

/// A trainee's sessions.
#[derive(Debug, Clone, Serialize)]
pub struct TraineeCurve {
    /// As the station's configuration names them; `None` when it named nobody.
    pub trainee: Option<String>,
    pub sessions: usize,
    pub passed: usize,
    pub best_score: f64,
    /// The last score minus the first, over all their sessions.
    pub change: f64,
    /// One a lesson, in the order the trainee first cut it.
    pub lessons: Vec<LessonCurve>,
}

/// A trainee's attempts at one lesson.
#[derive(Debug, Clone, Serialize)]
pub struct LessonCurve {
    pub lesson: String,
    /// The lesson's passing score.
    pub min_score: f64,
    pub attempts: Vec<Attempt>,
}

/// One session.
#[derive(Debug, Clone, Serialize)]
pub struct Attempt {
    /// 1, 2, ... for this trainee on this lesson.
    pub attempt: usize,
    /// The trainee's session number over all lessons (the curve's x).
    pub session: usize,
    /// When it began (UTC), when the journal says.
    pub started: Option<String>,
    pub station: String,
    pub score: f64,
    pub passed: bool,
    #[serde(flatten)]
    pub figures: Figures,
    pub reasons: Vec<String>,
    pub journal: String,
    /// The session's id in the archive (its journal's SHA-256).
    pub id: String,
}

/// Unix seconds as `2026-12-07 13:04 UTC`.
fn utc(unix_s: i64) -> Option<String> {
    let t = time::OffsetDateTime::from_unix_timestamp(unix_s).ok()?;
    Some(format!(
        "{}-{:02}-{:02} {:02}:{:02} UTC",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute()
    ))
}

/// The curves from the archive's rows (sorted by trainee, then start).
pub fn curves(rows: &[ScoredRow]) -> Vec<TraineeCurve> {
    let mut out: Vec<TraineeCurve> = Vec::new();
    for r in rows {
        if out.last().is_none_or(|c| c.trainee != r.trainee) {
            out.push(TraineeCurve {
                trainee: r.trainee.clone(),
                sessions: 0,
                passed: 0,
                best_score: 0.0,
                change: 0.0,
                lessons: Vec::new(),
            });
        }
        let c = out.last_mut().expect("pushed above");
        c.sessions += 1;
        c.passed += usize::from(r.passed);
        c.best_score = c.best_score.max(r.score);
        let at = match c.lessons.iter().position(|l| l.lesson == r.lesson) {
            Some(k) => k,
            None => {
                c.lessons.push(LessonCurve {
                    lesson: r.lesson.clone(),
                    min_score: r.min_score,
                    attempts: Vec::new(),
                });
                c.lessons.len() - 1
            }
        };
        let lesson = &mut c.lessons[at];
        lesson.attempts.push(Attempt {
            attempt: lesson.attempts.len() + 1,
            session: c.sessions,
            started: r.started_unix_s.and_then(utc),
            station: r.station.clone(),
            score: r.score,
            passed: r.passed,
            figures: r.figures,
            reasons: r
                .reasons
                .lines()
                .filter(|l| !l.is_empty())
                .map(str::to_string)
                .collect(),
            journal: r.journal.clone(),
            id: r.session.clone(),
        });
    }
    for c in &mut out {
        let mut all: Vec<&Attempt> = c.lessons.iter().flat_map(|l| &l.attempts).collect();
        all.sort_by_key(|a| a.session);
        if let (Some(first), Some(last)) = (all.first(), all.last()) {
            c.change = last.score - first.score;
        }
    }
    out
}

/// A CSV field, quoted when it must be (RFC 4180).
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// `lab.csv`: one row a scored session.
pub fn csv(summary: &LabSummary) -> String {
    let mut s = String::from(
        "trainee,lesson,attempt,session,started,station,score,passed,time_s,rms_deviation_mm,\
         rms_depth_error_mm,completed_percent,economy,peak_force_n,critical_events,no_go_cuts,\
         off_band_area_mm2,journal\n",
    );
    for c in &summary.trainees {
        for l in &c.lessons {
            for a in &l.attempts {
                let f = &a.figures;
                let _ = writeln!(
                    s,
                    "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                    field(c.trainee.as_deref().unwrap_or("")),
                    field(&l.lesson),
                    a.attempt,
                    a.session,
                    field(a.started.as_deref().unwrap_or("")),
                    field(&a.station),
                    a.score,
                    a.passed,
                    f.time_s,
                    f.rms_deviation_mm,
                    f.rms_depth_error_mm,
                    f.completed_percent,
                    f.economy,
                    f.peak_force_n,
                    f.critical_events,
                    f.no_go_cuts,
                    f.off_band_area_mm2,
                    field(&a.journal)
                );
            }
        }
    }
    s
}

/// Colours of a trainee's lessons, in order.
const COLOURS: [&str; 6] = [
    "#2c3e80", "#c0392b", "#1e7d32", "#8e44ad", "#d35400", "#16a085",
];
const COLOUR_NAMES: [&str; 6] = ["blue", "red", "green", "purple", "orange", "teal"];

/// A trainee's learning curve: score against their session number, a line a lesson, each
/// lesson's passing score dashed in its colour, passed sessions filled.
fn curve_plot(c: &TraineeCurve, k: usize) -> String {
    let mut frame = Frame::new((1.0, c.sessions.max(2) as f64), (0.0, 100.0), false);
    frame.whole_x = true;
    let who = c
        .trainee
        .as_deref()
        .unwrap_or("sessions with no trainee named");
    let legend: Vec<String> = c
        .lessons
        .iter()
        .enumerate()
        .map(|(i, l)| format!("{} {}", l.lesson, COLOUR_NAMES[i % COLOURS.len()]))
        .collect();
    let mut svg = open_svg(
        &format!(
            "{who}: score by session — {} (dashed: the lesson's pass mark; filled: passed)",
            legend.join(", ")
        ),
        &format!("curve-{k}"),
    );
    frame.axes(&mut svg, &format!("curve{k}"), "session", "score");
    for (i, l) in c.lessons.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        frame.polyline(
            &mut svg,
            &[(1.0, l.min_score), (c.sessions.max(2) as f64, l.min_score)],
            &format!(r##"stroke="{colour}" stroke-dasharray="5 4" stroke-opacity="0.6""##),
        );
        let points: Vec<(f64, f64)> = l
            .attempts
            .iter()
            .map(|a| (a.session as f64, a.score))
            .collect();
        frame.polyline(
            &mut svg,
            &points,
            &format!(r##"stroke="{colour}" stroke-width="2""##),
        );
        for a in &l.attempts {
            let _ = write!(
                svg,
                r##"<circle cx="{:.1}" cy="{:.1}" r="4" stroke="{colour}" stroke-width="2" fill="{}"><title>{} attempt {}: {:.0}</title></circle>"##,
                frame.px(a.session as f64),
                frame.py(a.score),
                if a.passed { colour } else { "#ffffff" },
                esc(&l.lesson),
                a.attempt,
                a.score
            );
        }
    }
    frame.close(&mut svg);
    svg
}

/// `lab.html`.
pub fn page(summary: &LabSummary) -> String {
    let mut s = String::with_capacity(64 * 1024);
    let _ = write!(
        s,
        r##"<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>scalpel lab summary</title>
<style>body{{font-family:sans-serif;margin:24px;color:#222}} table{{border-collapse:collapse;margin:8px 0}} td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}} td.n{{text-align:right}} .PASS{{color:#1e7d32}} .FAIL{{color:#b71c1c}} figure{{display:inline-block;margin:8px}} figcaption{{font-size:13px;max-width:640px}}</style></head><body>
<h1>Lab summary</h1><p>{} scored sessions of {} in the archive {}.</p>"##,
        summary.scored,
        summary.sessions,
        esc(&summary.archive)
    );
    s += "<table id=\"trainees\"><tr><th>trainee</th><th>sessions</th><th>passed</th><th>best</th><th>last − first</th></tr>";
    for c in &summary.trainees {
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{:.0}</td><td class=\"n\">{:+.0}</td></tr>",
            esc(c.trainee.as_deref().unwrap_or("(not named)")),
            c.sessions,
            c.passed,
            c.best_score,
            c.change
        );
    }
    s += "</table>";
    for (k, c) in summary.trainees.iter().enumerate() {
        let _ = write!(
            s,
            "<h2>{}</h2>",
            esc(c.trainee.as_deref().unwrap_or("(not named)"))
        );
        s += &curve_plot(c, k);
        s += "<table><tr><th>lesson</th><th>attempt</th><th>started</th><th>station</th><th>score</th><th></th><th>why not passed</th></tr>";
        for l in &c.lessons {
            for a in &l.attempts {
                let verdict = if a.passed { "PASS" } else { "FAIL" };
                let _ = write!(
                    s,
                    "<tr><td>{}</td><td class=\"n\">{}</td><td>{}</td><td>{}</td><td class=\"n\">{:.0}</td><td class=\"{verdict}\">{verdict}</td><td>{}</td></tr>",
                    esc(&l.lesson),
                    a.attempt,
                    esc(a.started.as_deref().unwrap_or("")),
                    esc(&a.station),
                    a.score,
                    esc(&a.reasons.join("; "))
                );
            }
        }
        s += "</table>";
    }
    if !summary.refused.is_empty() {
        s += "<h2>Journals not archived</h2><ul id=\"refused\">";
        for r in &summary.refused {
            let _ = write!(s, "<li>{}: {}</li>", esc(&r.journal), esc(&r.error));
        }
        s += "</ul>";
    }
    s += "<p>Definitions: docs/LESSONS.md.</p></body></html>\n";
    s
}

/// Writes `lab.csv`, `lab.json` and `lab.html` into `dir` (created if missing).
pub fn write(summary: &LabSummary, dir: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (name, text) in [
        ("lab.csv", csv(summary)),
        ("lab.json", serde_json::to_string_pretty(summary)? + "\n"),
        ("lab.html", page(summary)),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(trainee: Option<&str>, lesson: &str, started: i64, score: f64) -> ScoredRow {
        ScoredRow {
            session: format!("{trainee:?}{started}"),
            journal: format!("s{started}.journal"),
            station: "station-1".into(),
            trainee: trainee.map(str::to_string),
            started_unix_s: Some(started),
            lesson: lesson.into(),
            min_score: 70.0,
            score,
            passed: score >= 70.0,
            figures: Figures {
                time_s: 20.0,
                rms_deviation_mm: 1.0,
                rms_depth_error_mm: 1.0,
                completed_percent: 100.0,
                economy: 1.2,
                peak_force_n: 2.0,
                critical_events: 0,
                no_go_cuts: 0,
                off_band_area_mm2: 0.0,
            },
            reasons: "first\nsecond".into(),
        }
    }

    #[test]
    fn curves_count_attempts_per_lesson_and_sessions_per_trainee() {
        let rows = [
            row(Some("Ann"), "liver-straight", 100, 20.0),
            row(Some("Ann"), "shoulder-curved", 200, 60.0),
            row(Some("Ann"), "liver-straight", 300, 90.0),
            row(Some("Bo, Jr."), "liver-straight", 150, 75.0),
            row(None, "liver-straight", 50, 10.0),
        ];
        let c = curves(&rows);
        assert_eq!(c.len(), 3);
        assert_eq!(c[0].trainee.as_deref(), Some("Ann"));
        assert_eq!((c[0].sessions, c[0].passed), (3, 1));
        assert_eq!(c[0].change, 70.0);
        assert_eq!(c[0].lessons[0].attempts[1].attempt, 2);
        assert_eq!(c[0].lessons[0].attempts[1].session, 3);
        assert_eq!(c[0].lessons[0].attempts[1].reasons, ["first", "second"]);
        assert_eq!(c[2].trainee, None);
        let summary = LabSummary {
            archive: "x".into(),
            sessions: 5,
            scored: 5,
            added: 5,
            refused: Vec::new(),
            trainees: c,
        };
        let text = csv(&summary);
        assert_eq!(text.lines().count(), 6);
        assert!(text.contains("\n\"Bo, Jr.\",liver-straight,1,1,"), "{text}");
        assert_eq!(utc(0).as_deref(), Some("1970-01-01 00:00 UTC"));
    }
}
