//! Journals into the archive: each session's journal is read, replayed and scored on the
//! lesson it journaled (as `scalpel report` does), and archived once, keyed by the journal's
//! SHA-256.

use std::path::{Path, PathBuf};

use anyhow::Context;
use sha2::{Digest, Sha256};

use super::{Archive, ScoreRecord, SessionRecord};
use crate::lesson_cmd::score_journal;

/// What became of one journal.
#[derive(Debug, Clone)]
pub enum Ingested {
    /// Archived now; `scored` when the session ran a lesson.
    Added { scored: bool },
    /// Already in the archive.
    Known,
    /// Not archived, and why (the others are).
    Refused(String),
}

/// Every `*.journal` file under `dir` (its subfolders too), in name order.
fn journals_under(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut found = Vec::new();
    let mut folders = vec![dir.to_path_buf()];
    while let Some(folder) = folders.pop() {
        let entries = std::fs::read_dir(&folder)
            .with_context(|| format!("cannot read the lab folder {}", folder.display()))?;
        for entry in entries {
            let path = entry?.path();
            if path.is_dir() {
                folders.push(path);
            } else if path.extension().is_some_and(|e| e == "journal") {
                found.push(path);
            }
        }
    }
    found.sort();
    Ok(found)
}

/// The hex SHA-256 of a file.
fn sha256_of(path: &Path) -> anyhow::Result<String> {
    let mut file =
        std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut hash = Sha256::new();
    std::io::copy(&mut file, &mut hash).with_context(|| format!("reading {}", path.display()))?;
    Ok(format!("{:x}", hash.finalize()))
}

/// How long a journal with no closing line must have been left alone before it is taken
/// for a killed station's (and archived) rather than a session still running.
const UNFINISHED_WAIT: std::time::Duration = std::time::Duration::from_secs(3600);

/// Whether `path` was written to within `wait` of now.
fn changed_within(path: &Path, wait: std::time::Duration) -> anyhow::Result<bool> {
    let modified = std::fs::metadata(path)
        .and_then(|m| m.modified())
        .with_context(|| format!("reading {}", path.display()))?;
    Ok(modified.elapsed().is_ok_and(|age| age < wait))
}

fn unix_now() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs() as i64)
}

/// Archives every journal under `dir` not archived yet; `progress` hears of each.
pub async fn ingest_dir(
    archive: &Archive,
    dir: &Path,
    mut progress: impl FnMut(&Path, &Ingested),
) -> anyhow::Result<Vec<(PathBuf, Ingested)>> {
    let mut done = Vec::new();
    for path in journals_under(dir)? {
        let outcome = match ingest_one(archive, &path).await {
            Ok(o) => o,
            Err(e) => Ingested::Refused(format!("{e:#}")),
        };
        progress(&path, &outcome);
        done.push((path, outcome));
    }
    Ok(done)
}

async fn ingest_one(archive: &Archive, path: &Path) -> anyhow::Result<Ingested> {
    let id = sha256_of(path)?;
    if archive.has(&id).await? {
        return Ok(Ingested::Known);
    }
    let recorded = scalpel_server::journal::read(path)?;
    if recorded.end.is_none() && changed_within(path, UNFINISHED_WAIT)? {
        // Archived now, it would be archived again when it is finished (another SHA-256).
        anyhow::bail!(
            "{}: no closing line and written to in the last hour: a session still running \
             (a killed station's journal is archived once it has not changed for an hour)",
            path.display()
        );
    }
    let runs_lesson = !recorded.lesson.is_empty() || recorded.config_string("lesson").is_some();
    let shown = path.display().to_string();
    let station = recorded.config_string("station").unwrap_or_default();
    let trainee = recorded.config_string("trainee");
    let mut record = SessionRecord {
        id: &id,
        journal: &shown,
        station: &station,
        scene: &recorded.scene,
        trainee: trainee.as_deref(),
        started_unix_s: recorded.started_unix_s.map(|s| s as i64),
        ticks: recorded.ticks.len() as i64,
        archived_unix_s: unix_now(),
        scored: None,
    };
    if !runs_lesson {
        archive.put(&record).await?;
        return Ok(Ingested::Added { scored: false });
    }
    let session = score_journal(path, &recorded, None)?;
    let report = session.report(trainee.clone(), format!("journal {shown}"));
    let report_json = serde_json::to_string(&report)?;
    let spec = &session.scorer.plan().spec;
    // The lesson's text as the station journaled it (a version 1 journal: the file now).
    let text = match recorded.lesson.is_empty() {
        false => recorded.lesson.clone(),
        true => scalpel_server::scene_file::lesson_text(
            &recorded.config_string("lesson").unwrap_or_default(),
        )?,
    };
    let lesson_id = format!("{:x}", Sha256::digest(text.as_bytes()));
    record.scored = Some(ScoreRecord {
        lesson_id: &lesson_id,
        lesson_name: &spec.name,
        description: &spec.description,
        scene: &recorded.scene,
        min_score: spec.pass.min_score,
        lesson_text: &text,
        report: &report,
        report_json: &report_json,
    });
    archive.put(&record).await?;
    Ok(Ingested::Added { scored: true })
}
