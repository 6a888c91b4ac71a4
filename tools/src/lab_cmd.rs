//! `scalpel report --lab DIR` and `scalpel archive rebuild DIR`: the lab's journals into its
//! archive, and the learning curves read back from it (docs/LESSONS.md, "The lab's
//! archive" and "The lab summary").

use std::path::Path;

use crate::archive::{Archive, Ingested, ingest_dir};
use crate::lesson_report::lab::{self, LabSummary, Refused};

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?)
}

/// Says what became of a journal (on stderr: stdout may be JSON).
fn say(path: &Path, outcome: &Ingested) {
    match outcome {
        Ingested::Added { scored: true } => eprintln!("archived and scored {}", path.display()),
        Ingested::Added { scored: false } => {
            eprintln!("archived {} (it ran no lesson)", path.display())
        }
        Ingested::Known => {}
        Ingested::Refused(why) => eprintln!("not archived: {why}"),
    }
}

/// Archives the journals under `dir` that are new, then reads every scored session back.
async fn summarise(archive: &Archive, dir: &Path) -> anyhow::Result<LabSummary> {
    let done = ingest_dir(archive, dir, say).await?;
    let refused = done
        .iter()
        .filter_map(|(p, o)| match o {
            Ingested::Refused(why) => Some(Refused {
                journal: p.display().to_string(),
                error: why.clone(),
            }),
            _ => None,
        })
        .collect();
    let rows = archive.scored().await?;
    Ok(LabSummary {
        archive: archive.shown.clone(),
        sessions: archive.session_count().await?,
        scored: rows.len(),
        added: done
            .iter()
            .filter(|(_, o)| matches!(o, Ingested::Added { .. }))
            .count(),
        refused,
        trainees: lab::curves(&rows),
    })
}

fn print(summary: &LabSummary, out: &Path, json: bool) -> anyhow::Result<()> {
    lab::write(summary, out)?;
    if json {
        println!("{}", serde_json::to_string_pretty(summary)?);
        return Ok(());
    }
    println!(
        "{} scored sessions of {} in {} ({} archived now, {} refused)",
        summary.scored,
        summary.sessions,
        summary.archive,
        summary.added,
        summary.refused.len()
    );
    for c in &summary.trainees {
        println!(
            "  {:<24} {:>3} sessions, {:>3} passed, best {:>3.0}, last − first {:+.0}",
            c.trainee.as_deref().unwrap_or("(not named)"),
            c.sessions,
            c.passed,
            c.best_score,
            c.change
        );
    }
    println!("summary: {}", out.join("lab.html").display());
    Ok(())
}

/// `scalpel report --lab DIR [--db URL] --out OUT`.
pub fn report(dir: &Path, db: Option<&str>, out: &Path, json: bool) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        let archive = Archive::for_lab(dir, db).await?;
        let summary = summarise(&archive, dir).await?;
        print(&summary, out, json)
    })
}

/// `scalpel archive rebuild DIR [--db URL] --out OUT`: empties the archive, archives every
/// journal under `dir` again, and writes the summary.
pub fn rebuild(dir: &Path, db: Option<&str>, out: &Path, json: bool) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        let archive = Archive::for_lab(dir, db).await?;
        archive.clear().await?;
        let summary = summarise(&archive, dir).await?;
        print(&summary, out, json)
    })
}
