//! The lab's archive and learning curves (issue 43), with real processes: station sessions
//! run with a real mock device and journaled go into the archive (SQLite by default, a real
//! PostgreSQL server when CI starts one), `scalpel report --lab` reads each trainee's curve
//! back, a second run archives nothing twice, and `scalpel archive rebuild` gives the same
//! curves from the journals alone.

mod common;

use std::path::{Path, PathBuf};

use common::browser;
use common::lesson_session::{self, Session};
use common::station::{self, scalpel};

/// The tests of this file run stations; on two cores, one at a time.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// A lab's journals in a scratch folder of its own (`name`): Ann's careless then careful
/// attempt at the straight liver cut, Bo's free session at a second station, a broken
/// journal and one still running. The sessions are real stations with a real mock device;
/// they are recorded once per build of the two binaries and this test (a minute) and
/// copied from there, so CI's PostgreSQL and Chromium steps archive what the plain run
/// recorded.
fn lab(name: &str) -> PathBuf {
    let cache = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("lab-{:016x}", build_stamp()));
    if !cache.exists() {
        let part = cache.with_extension(format!("part-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&part);
        record_lab(&part.join("journals"));
        // Another process may have finished first: theirs is the same build's.
        if let Err(e) = std::fs::rename(&part, &cache) {
            let _ = std::fs::remove_dir_all(&part);
            assert!(cache.join("journals").exists(), "caching the lab: {e}");
        }
        forget_older_labs(&cache);
    }
    let journals = station::scratch(name).join("journals");
    let _ = std::fs::remove_dir_all(&journals);
    common::copy_tree(&cache.join("journals"), &journals);
    journals
}

/// Removes the labs earlier builds recorded beside `cache` (6 MB each; one a build would
/// pile up locally). Another build's recording in progress (`.part-*`) is left alone.
fn forget_older_labs(cache: &Path) {
    let Ok(entries) = std::fs::read_dir(cache.parent().unwrap()) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with("lab-") && !name.contains(".part-") && entry.path() != cache {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// What identifies this build of `scalpel`, `scalpel-server` and this test (what records
/// the lab): their sizes and times.
fn build_stamp() -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for bin in [
        PathBuf::from(env!("CARGO_BIN_EXE_scalpel")),
        station::server_binary(),
        std::env::current_exe().unwrap(),
    ] {
        let meta = std::fs::metadata(&bin).unwrap();
        (meta.len(), meta.modified().unwrap()).hash(&mut h);
    }
    h.finish()
}

/// Records the lab's journals into `journals` (see [`lab`]); the scripts and the stations'
/// configurations go beside it.
fn record_lab(journals: &Path) {
    let dir = journals.parent().unwrap().to_path_buf();
    std::fs::create_dir_all(journals.join("station-2")).unwrap();
    for (k, who) in ["careless", "careful"].iter().enumerate() {
        let script = lesson_session::script(&dir, "liver-straight", who);
        lesson_session::run(
            &dir,
            &Session {
                trainee: Some("Ann Example"),
                lesson: Some("liver-straight"),
                script: Some(&script),
            },
            &journals.join(format!("ann-{k}.journal")),
        );
        // Sessions a second apart at least: the curve's order is the journals' start.
        std::thread::sleep(std::time::Duration::from_millis(1100));
    }
    lesson_session::run(
        &dir,
        &Session {
            trainee: Some("Bo"),
            lesson: None,
            script: None,
        },
        &journals.join("station-2/free.journal"),
    );
    std::fs::write(journals.join("broken.journal"), "not a journal\n").unwrap();
    let whole = std::fs::read_to_string(journals.join("ann-1.journal")).unwrap();
    let open = &whole[..whole.trim_end().rfind('\n').unwrap() + 1];
    assert!(whole[open.len()..].starts_with("end "));
    std::fs::write(journals.join("running.journal"), open).unwrap();
}

/// `scalpel ARGS --json`, its JSON.
fn run_json(args: &[&str], dir: &Path, db: Option<&str>) -> serde_json::Value {
    let mut command = scalpel();
    command.args(args).arg(dir).arg("--json");
    if let Some(db) = db {
        command.args(["--db", db]);
    }
    let out = command
        .arg("--out")
        .arg(dir.join("../summary"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Each trainee's (name, lesson, attempt, score, passed) in order.
fn curve(summary: &serde_json::Value) -> Vec<(String, String, u64, f64, bool)> {
    let mut out = Vec::new();
    for t in summary["trainees"].as_array().unwrap() {
        for l in t["lessons"].as_array().unwrap() {
            for a in l["attempts"].as_array().unwrap() {
                out.push((
                    t["trainee"].as_str().unwrap_or("").to_string(),
                    l["lesson"].as_str().unwrap().to_string(),
                    a["attempt"].as_u64().unwrap(),
                    a["score"].as_f64().unwrap(),
                    a["passed"].as_bool().unwrap(),
                ));
            }
        }
    }
    out
}

/// The archive at `db` (default: the lab's SQLite file) after a first summary, a second
/// one, and a rebuild.
fn check_archive(journals: &Path, db: Option<&str>) -> Vec<(String, String, u64, f64, bool)> {
    let first = run_json(&["report", "--lab"], journals, db);
    // Refused, each with why: not a journal, and a session still running.
    let refused: Vec<(&str, &str)> = first["refused"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| (r["journal"].as_str().unwrap(), r["error"].as_str().unwrap()))
        .collect();
    assert_eq!(refused.len(), 2, "{first}");
    assert!(
        refused[0].0.ends_with("broken.journal") && refused[0].1.contains("not a scalpel journal"),
        "{first}"
    );
    assert!(
        refused[1].0.ends_with("running.journal") && refused[1].1.contains("still running"),
        "{first}"
    );
    assert_eq!(first["sessions"], 3, "{first}");
    assert_eq!(first["scored"], 2, "{first}");
    let ann = curve(&first);
    assert_eq!(ann.len(), 2, "{ann:?}");
    assert!(
        ann.iter()
            .all(|a| a.0 == "Ann Example" && a.1 == "liver-straight")
    );
    assert_eq!((ann[0].2, ann[1].2), (1, 2));
    assert!(
        !ann[0].4 && ann[1].4 && ann[1].3 > ann[0].3,
        "careless then careful: {ann:?}"
    );
    let first_attempt = &first["trainees"][0]["lessons"][0]["attempts"][0];
    assert!(
        !first_attempt["reasons"].as_array().unwrap().is_empty()
            && first_attempt["started"].as_str().unwrap().ends_with("UTC"),
        "{first_attempt}"
    );
    // Nothing is archived twice.
    let again = run_json(&["report", "--lab"], journals, db);
    assert_eq!(again["added"], 0, "{again}");
    assert_eq!(curve(&again), ann);
    // The journals are the source of truth.
    let rebuilt = run_json(&["archive", "rebuild"], journals, db);
    assert_eq!(rebuilt["added"], 3, "{rebuilt}");
    assert_eq!(rebuilt["sessions"], 3, "{rebuilt}");
    assert_eq!(curve(&rebuilt), ann);
    ann
}

#[test]
fn a_lab_archive_keeps_each_trainees_learning_curve() {
    let _one = one_at_a_time();
    let journals = lab("lab-sqlite");
    check_archive(&journals, None);
    assert!(journals.join("lab.sqlite").exists());
    let summary = journals.join("../summary");
    let csv = std::fs::read_to_string(summary.join("lab.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 3, "{csv}");
    assert!(rows[0].starts_with("trainee,lesson,attempt,session,started,station,score,passed"));
    assert!(
        rows[1].starts_with("Ann Example,liver-straight,1,1,"),
        "{csv}"
    );
    assert!(
        rows[2].starts_with("Ann Example,liver-straight,2,2,"),
        "{csv}"
    );
    let page = std::fs::read_to_string(summary.join("lab.html")).unwrap();
    assert!(page.contains("id=\"curve-0\"") && page.contains("Ann Example"));
}

/// The same archive on a real PostgreSQL server: .ci/run starts one and names it in
/// SCALPEL_TEST_POSTGRES (a database this test may empty).
#[test]
#[ignore = "needs a PostgreSQL server: .ci/run starts one and sets SCALPEL_TEST_POSTGRES"]
fn postgres_archive_gives_the_same_curves_as_sqlite() {
    let _one = one_at_a_time();
    let url = std::env::var("SCALPEL_TEST_POSTGRES")
        .expect("SCALPEL_TEST_POSTGRES names the PostgreSQL database to test on");
    let journals = lab("lab-postgres");
    // Whatever an earlier run left: a rebuild starts the archive over.
    run_json(&["archive", "rebuild"], &journals, Some(&url));
    let on_postgres = check_archive(&journals, Some(&url));
    let on_sqlite = check_archive(&journals, None);
    assert_eq!(on_postgres, on_sqlite);
    // A password never reaches the output.
    let out = run_json(&["report", "--lab"], &journals, Some(&url));
    let password = url
        .split_once("://")
        .and_then(|(_, rest)| rest.split_once('@'))
        .and_then(|(user, _)| user.split_once(':'))
        .map(|(_, p)| p.to_string())
        .unwrap_or_default();
    assert!(
        password.is_empty() || !out.to_string().contains(&password),
        "{out}"
    );
}

/// The lab summary as a browser shows it: Chromium loads lab.html clean and draws the
/// learning curve (its frame holds the lesson's blue).
#[test]
#[ignore = "needs Debian's chromium; .ci/run installs it and runs this"]
fn chromium_draws_the_lab_learning_curves() {
    let _one = one_at_a_time();
    let journals = lab("lab-chromium");
    run_json(&["report", "--lab"], &journals, None);
    let summary = journals.join("../summary");
    let shot = browser::screenshot(
        &summary.join("lab.html"),
        &summary.join("lab.png"),
        1200,
        1000,
    );
    let frames = shot.plot_frames();
    assert_eq!(frames.len(), 1, "{frames:?}");
    let blue = (0x2c, 0x3e, 0x80);
    let drawn = shot.count_near(frames[0], blue);
    assert!(drawn > 100, "{drawn} pixels of the curve's blue");
}
