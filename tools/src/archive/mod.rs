//! The lab's archive (docs/LESSONS.md, "The lab's archive"): trainees, lessons, sessions and
//! scores in SQLite (the default: one file beside the lab's journals, nothing to install) or
//! PostgreSQL (a lab or a group of labs on a server), chosen by the URL at run time through
//! sqlx's Any driver, with one schema (tools/migrations), one set of queries and versioned
//! migrations for both. The journals stay the source of truth: every row comes from one,
//! and `scalpel archive rebuild` empties the archive and reads them again.

mod ingest;

use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use sqlx::any::{AnyPoolOptions, AnyRow, install_default_drivers};
use sqlx::{AnyPool, Row};

use crate::lesson_report::MetricsJson;

pub use ingest::{Ingested, ingest_dir};

/// The archive's schema, embedded (tools/migrations, applied in order, each once).
static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("./migrations");

/// The archive file `scalpel report --lab DIR` uses when no `--db` is given.
pub const DEFAULT_FILE: &str = "lab.sqlite";

/// An open archive, migrated to this build's schema.
pub struct Archive {
    pool: AnyPool,
    /// Where it is, for messages (a PostgreSQL URL without its password).
    pub shown: String,
}

/// One scored session as the lab summary reads it.
#[derive(Debug, Clone)]
pub struct ScoredRow {
    pub session: String,
    pub journal: String,
    pub station: String,
    pub trainee: Option<String>,
    pub started_unix_s: Option<i64>,
    pub lesson: String,
    pub min_score: f64,
    pub score: f64,
    pub passed: bool,
    pub figures: Figures,
    pub reasons: String,
}

/// The figures of a score the archive keeps in columns of `scores`, in their order (the
/// whole report is in its `report` column).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Figures {
    pub time_s: f64,
    pub rms_deviation_mm: f64,
    pub rms_depth_error_mm: f64,
    pub completed_percent: f64,
    pub economy: f64,
    pub peak_force_n: f64,
    pub critical_events: i64,
    pub no_go_cuts: i64,
    pub off_band_area_mm2: f64,
}

impl Figures {
    fn of(m: &MetricsJson) -> Self {
        Self {
            time_s: m.time_s,
            rms_deviation_mm: m.rms_deviation_mm,
            rms_depth_error_mm: m.rms_depth_error_mm,
            completed_percent: m.completed_percent,
            economy: m.economy,
            peak_force_n: m.peak_force_n,
            critical_events: i64::from(m.critical_events),
            no_go_cuts: i64::from(m.no_go_cuts),
            off_band_area_mm2: m.off_band_area_mm2,
        }
    }

    /// The figures in a row's columns from `at` on.
    fn read(r: &AnyRow, at: usize) -> Result<Self, sqlx::Error> {
        Ok(Self {
            time_s: r.try_get(at)?,
            rms_deviation_mm: r.try_get(at + 1)?,
            rms_depth_error_mm: r.try_get(at + 2)?,
            completed_percent: r.try_get(at + 3)?,
            economy: r.try_get(at + 4)?,
            peak_force_n: r.try_get(at + 5)?,
            critical_events: r.try_get(at + 6)?,
            no_go_cuts: r.try_get(at + 7)?,
            off_band_area_mm2: r.try_get(at + 8)?,
        })
    }
}

/// A session's rows, as [`Archive::put`] writes them in one transaction.
pub struct SessionRecord<'a> {
    pub id: &'a str,
    pub journal: &'a str,
    pub station: &'a str,
    pub scene: &'a str,
    pub trainee: Option<&'a str>,
    pub started_unix_s: Option<i64>,
    pub ticks: i64,
    pub archived_unix_s: i64,
    pub scored: Option<ScoreRecord<'a>>,
}

/// The lesson a session was scored on and its score.
pub struct ScoreRecord<'a> {
    pub lesson_id: &'a str,
    pub lesson_name: &'a str,
    pub description: &'a str,
    pub scene: &'a str,
    pub min_score: f64,
    pub lesson_text: &'a str,
    pub report: &'a crate::lesson_report::LessonReport,
    pub report_json: &'a str,
}

/// The URL for `--db VALUE`: a `sqlite:`, `postgres:` or `postgresql:` URL as given, or a
/// file path for SQLite (created when missing).
pub fn url_for(db: &str) -> String {
    let is_url = ["sqlite:", "postgres:", "postgresql:"]
        .iter()
        .any(|p| db.starts_with(p));
    if is_url {
        db.to_string()
    } else {
        format!("sqlite://{db}?mode=rwc")
    }
}

/// `url` as messages show it: a SQLite file by its path, a server's URL without its password.
fn shown(url: &str) -> String {
    match url.strip_prefix("sqlite://") {
        Some(file) => file.trim_end_matches("?mode=rwc").to_string(),
        None => without_password(url),
    }
}

/// `url` with its password replaced by `***`.
fn without_password(url: &str) -> String {
    match (url.find("://"), url.rfind('@')) {
        (Some(s), Some(at)) if at > s => match url[s + 3..at].find(':') {
            Some(c) => format!("{}:***{}", &url[..s + 3 + c], &url[at..]),
            None => url.to_string(),
        },
        _ => url.to_string(),
    }
}

impl Archive {
    /// Opens (creating a SQLite file if missing) and migrates the archive at `url`.
    pub async fn open(url: &str) -> anyhow::Result<Self> {
        install_default_drivers();
        let shown = shown(url);
        let pool = AnyPoolOptions::new()
            .max_connections(2)
            .connect(url)
            .await
            .with_context(|| format!("cannot open the lab's archive {shown}"))?;
        MIGRATOR
            .run(&pool)
            .await
            .with_context(|| format!("cannot bring the archive {shown} to this build's schema"))?;
        Ok(Self { pool, shown })
    }

    /// Opens the archive for the lab in `dir`: `db` (a URL or a SQLite file) or
    /// `dir/lab.sqlite`.
    pub async fn for_lab(dir: &Path, db: Option<&str>) -> anyhow::Result<Self> {
        let url = match db {
            Some(db) => url_for(db),
            None => url_for(&dir.join(DEFAULT_FILE).display().to_string()),
        };
        Self::open(&url).await
    }

    /// Whether the session `id` is archived.
    pub async fn has(&self, id: &str) -> anyhow::Result<bool> {
        let row = sqlx::query("SELECT COUNT(*) FROM sessions WHERE id = $1")
            .bind(id)
            .fetch_one(&self.pool)
            .await
            .with_context(|| format!("reading {}", self.shown))?;
        Ok(row.try_get::<i64, _>(0)? > 0)
    }

    /// Archives a session (its trainee and lesson when new), all or nothing.
    pub async fn put(&self, r: &SessionRecord<'_>) -> anyhow::Result<()> {
        let mut tx = self.pool.begin().await?;
        if let Some(t) = r.trainee {
            sqlx::query("INSERT INTO trainees (name) VALUES ($1) ON CONFLICT (name) DO NOTHING")
                .bind(t)
                .execute(&mut *tx)
                .await?;
        }
        if let Some(s) = &r.scored {
            sqlx::query(
                "INSERT INTO lessons (id, name, description, scene, min_score, text) \
                 VALUES ($1, $2, $3, $4, $5, $6) ON CONFLICT (id) DO NOTHING",
            )
            .bind(s.lesson_id)
            .bind(s.lesson_name)
            .bind(s.description)
            .bind(s.scene)
            .bind(s.min_score)
            .bind(s.lesson_text)
            .execute(&mut *tx)
            .await?;
        }
        sqlx::query(
            "INSERT INTO sessions (id, journal, station, scene, trainee, lesson, started_unix_s, \
             ticks, archived_unix_s) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9)",
        )
        .bind(r.id)
        .bind(r.journal)
        .bind(r.station)
        .bind(r.scene)
        .bind(r.trainee)
        .bind(r.scored.as_ref().map(|s| s.lesson_id))
        .bind(r.started_unix_s)
        .bind(r.ticks)
        .bind(r.archived_unix_s)
        .execute(&mut *tx)
        .await?;
        if let Some(s) = &r.scored {
            let f = Figures::of(&s.report.metrics);
            sqlx::query(
                "INSERT INTO scores (session, score, passed, time_s, rms_deviation_mm, \
                 rms_depth_error_mm, completed_percent, economy, peak_force_n, critical_events, \
                 no_go_cuts, off_band_area_mm2, reasons, report) \
                 VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14)",
            )
            .bind(r.id)
            .bind(s.report.score)
            .bind(i64::from(s.report.passed))
            .bind(f.time_s)
            .bind(f.rms_deviation_mm)
            .bind(f.rms_depth_error_mm)
            .bind(f.completed_percent)
            .bind(f.economy)
            .bind(f.peak_force_n)
            .bind(f.critical_events)
            .bind(f.no_go_cuts)
            .bind(f.off_band_area_mm2)
            .bind(s.report.reasons.join("\n"))
            .bind(s.report_json)
            .execute(&mut *tx)
            .await?;
        }
        tx.commit().await?;
        Ok(())
    }

    /// Empties the archive (its schema stays), for a rebuild from the journals.
    pub async fn clear(&self) -> anyhow::Result<()> {
        let mut tx = self.pool.begin().await?;
        for delete in [
            "DELETE FROM scores",
            "DELETE FROM sessions",
            "DELETE FROM lessons",
            "DELETE FROM trainees",
        ] {
            sqlx::query(delete).execute(&mut *tx).await?;
        }
        tx.commit().await?;
        Ok(())
    }

    /// Sessions archived (scored or not).
    pub async fn session_count(&self) -> anyhow::Result<i64> {
        let row = sqlx::query("SELECT COUNT(*) FROM sessions")
            .fetch_one(&self.pool)
            .await?;
        Ok(row.try_get(0)?)
    }

    /// Every scored session, by trainee (unnamed last), then start, then journal.
    pub async fn scored(&self) -> anyhow::Result<Vec<ScoredRow>> {
        let rows = sqlx::query(
            "SELECT s.id, s.journal, s.station, s.trainee, s.started_unix_s, l.name, \
             l.min_score, c.score, c.passed, c.time_s, c.rms_deviation_mm, \
             c.rms_depth_error_mm, c.completed_percent, c.economy, c.peak_force_n, \
             c.critical_events, c.no_go_cuts, c.off_band_area_mm2, c.reasons \
             FROM sessions s JOIN scores c ON c.session = s.id JOIN lessons l ON l.id = s.lesson",
        )
        .fetch_all(&self.pool)
        .await
        .with_context(|| format!("reading {}", self.shown))?;
        // Sorted here: SQLite and PostgreSQL put NULLs at opposite ends.
        let mut out = rows
            .iter()
            .map(|r| -> Result<ScoredRow, sqlx::Error> {
                Ok(ScoredRow {
                    session: r.try_get(0)?,
                    journal: r.try_get(1)?,
                    station: r.try_get(2)?,
                    trainee: r.try_get(3)?,
                    started_unix_s: r.try_get(4)?,
                    lesson: r.try_get(5)?,
                    min_score: r.try_get(6)?,
                    score: r.try_get(7)?,
                    passed: r.try_get::<i64, _>(8)? != 0,
                    figures: Figures::read(r, 9)?,
                    reasons: r.try_get(18)?,
                })
            })
            .collect::<Result<Vec<_>, _>>()
            .with_context(|| format!("reading {}", self.shown))?;
        out.sort_by(|a, b| {
            let key = |r: &ScoredRow| {
                (
                    r.trainee.is_none(),
                    r.trainee.clone(),
                    r.started_unix_s.is_none(),
                    r.started_unix_s,
                    r.journal.clone(),
                )
            };
            key(a).cmp(&key(b))
        });
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_password_is_not_shown() {
        assert_eq!(
            without_password("postgres://lab:s3cret@db.example:5432/scalpel"),
            "postgres://lab:***@db.example:5432/scalpel"
        );
        assert_eq!(
            without_password("postgres://lab@db/scalpel"),
            "postgres://lab@db/scalpel"
        );
        assert_eq!(
            url_for("/labs/a/lab.sqlite"),
            "sqlite:///labs/a/lab.sqlite?mode=rwc"
        );
        assert_eq!(url_for("postgres://x/y"), "postgres://x/y");
    }
}
