//! Lessons and their scores (issue 43), with real processes: the scripted trainees on every
//! built-in lesson score in the order a teacher expects, and a station's session, run with
//! a real mock device over shared memory and journaled, is scored from its journal with the
//! trainee the station names.

mod common;

use std::collections::HashMap;
use std::process::Command;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use common::station::{self, json, scalpel};
use common::{browser, lesson_session};

/// The tests of this file run simulations; on two cores, one at a time.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// `scalpel lesson try LESSON --trainee WHO --json`, its report.
fn try_lesson(lesson: &str, who: &str) -> serde_json::Value {
    let out = station::scratch(&format!("lesson-{lesson}-{who}"));
    let run = scalpel()
        .args(["lesson", "try", lesson, "--trainee", who, "--json", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{lesson} {who}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    for id in ["top-view", "depth-profile", "force-plot", "metrics"] {
        assert!(
            page.contains(&format!("id=\"{id}\"")),
            "{lesson} {who}: no {id}"
        );
    }
    serde_json::from_slice(&run.stdout).unwrap()
}

fn reasons(report: &serde_json::Value) -> String {
    report["reasons"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r.as_str().unwrap())
        .collect::<Vec<_>>()
        .join("; ")
}

/// `try_lesson` on every pair of `lessons` and `trainees`, two processes at a time (the
/// machine's two cores; each run is one simulation thread and none is timed), keyed by
/// (lesson, trainee).
fn try_all(
    lessons: &[&'static str],
    trainees: &[&'static str],
) -> HashMap<(&'static str, &'static str), serde_json::Value> {
    let jobs: Vec<_> = lessons
        .iter()
        .flat_map(|l| trainees.iter().map(move |t| (*l, *t)))
        .collect();
    let next = AtomicUsize::new(0);
    let done = Mutex::new(HashMap::new());
    std::thread::scope(|scope| {
        for _ in 0..2 {
            scope.spawn(|| {
                while let Some(&(lesson, who)) = jobs.get(next.fetch_add(1, Ordering::Relaxed)) {
                    let report = try_lesson(lesson, who);
                    done.lock().unwrap().insert((lesson, who), report);
                }
            });
        }
    });
    done.into_inner().unwrap()
}

#[test]
fn scripted_trainees_score_in_order_on_every_built_in_lesson() {
    let _one = one_at_a_time();
    // The shoulder's hesitant trainee is the regression test of a node slaved to a point
    // the cut set loose (its solver diverged at the lift; docs/CUTTING-DECISIONS.md).
    let lessons = ["liver-straight", "shoulder-curved", "cerebroma-margin"];
    let reports = try_all(&lessons, &["careful", "careless", "hesitant"]);
    for lesson in lessons {
        let careful = &reports[&(lesson, "careful")];
        let careless = &reports[&(lesson, "careless")];
        assert!(
            careful["passed"].as_bool().unwrap(),
            "{lesson}: the careful trainee fails: {}",
            reasons(careful)
        );
        assert!(
            !careless["passed"].as_bool().unwrap(),
            "{lesson}: careless passes"
        );
        // The careless trainee fails for what it did: too deep, into the structure, not
        // finished.
        let why = reasons(careless);
        for cause in ["depth off by", "cut into", "completed"] {
            assert!(
                why.contains(cause),
                "{lesson}: careless fails without {cause:?}: {why}"
            );
        }
        assert_eq!(careful["metrics"]["no_go_cuts"], 0, "{lesson}");
        assert!(careful["metrics"]["completed_percent"].as_f64().unwrap() >= 95.0);
        let (good, bad) = (
            careful["score"].as_f64().unwrap(),
            careless["score"].as_f64().unwrap(),
        );
        assert!(
            good >= 90.0 && bad < 60.0,
            "{lesson}: careful {good}, careless {bad}"
        );
        let h = &reports[&(lesson, "hesitant")];
        let score = h["score"].as_f64().unwrap();
        assert!(
            bad < score && score < good,
            "{lesson}: hesitant {score} not between careless {bad} and careful {good}"
        );
        // Two strokes, slower: more time and more tool path for the same cut.
        assert_eq!(h["metrics"]["strokes"], 2, "{lesson}");
        assert!(
            h["metrics"]["economy"].as_f64() > careful["metrics"]["economy"].as_f64()
                && h["metrics"]["time_s"].as_f64() > careful["metrics"]["time_s"].as_f64(),
            "{lesson}"
        );
    }
}

#[test]
fn a_station_session_is_scored_from_its_journal_with_its_trainee() {
    let _one = one_at_a_time();
    let dir = station::scratch("lesson-station");
    let script = lesson_session::script(&dir, "liver-straight", "careful");
    let journal = dir.join("session.journal");
    lesson_session::run(
        &dir,
        &lesson_session::Session {
            trainee: Some("Ann Example"),
            lesson: Some("liver-straight"),
            script: Some(&script),
        },
        &journal,
    );
    let report_dir = dir.join("report");
    let scored = scalpel()
        .arg("report")
        .arg(&journal)
        .args(["--json", "--out"])
        .arg(&report_dir)
        .output()
        .unwrap();
    assert!(
        scored.status.success(),
        "{}",
        String::from_utf8_lossy(&scored.stderr)
    );
    let report = json(&String::from_utf8_lossy(&scored.stdout).replace('\n', " "));
    assert_eq!(report["lesson"], "liver-straight");
    assert_eq!(report["trainee"], "Ann Example");
    assert!(
        report["passed"].as_bool().unwrap(),
        "the careful trainee at a station: {}",
        reasons(&report)
    );
    assert!(report["metrics"]["completed_percent"].as_f64().unwrap() >= 95.0);
    assert!(report_dir.join("report.html").exists());
    // Scored on another lesson's organ: refused with both scenes named.
    let wrong = scalpel()
        .arg("report")
        .arg(&journal)
        .args(["--lesson", "cerebroma-margin", "--out"])
        .arg(dir.join("wrong"))
        .output()
        .unwrap();
    let message = String::from_utf8_lossy(&wrong.stderr);
    assert!(
        !wrong.status.success()
            && message.contains("the session ran scene \"liver\"")
            && message.contains("\"cerebroma\""),
        "{message}"
    );
}

#[test]
fn a_bad_lesson_file_is_refused_with_its_place() {
    let dir = station::scratch("lesson-bad");
    let file = dir.join("bad.toml");
    std::fs::write(
        &file,
        "name = \"x\"\nscene = \"liver\"\n[[incision]]\npoints_mm = [[-30.0, 0.0, 25.0], [30.0, 0.0, 25.0]]\ndepth_mm = 10.0\ndeviaton_mm = 2.0\n",
    )
    .unwrap();
    let run = scalpel()
        .args(["lesson", "show"])
        .arg(&file)
        .output()
        .unwrap();
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && message.contains("bad.toml") && message.contains("deviaton_mm"),
        "{message}"
    );
    // A station refuses a lesson for another organ before it starts.
    let config = dir.join("server.toml");
    std::fs::write(&config, "scene = \"liver\"\nlesson = \"shoulder-curved\"\n").unwrap();
    let run = Command::new(station::server_binary())
        .arg(&config)
        .arg("--check")
        .output()
        .unwrap();
    let message = format!(
        "{}{}",
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        !run.status.success() && message.contains("lesson") && message.contains("shoulder"),
        "{message}"
    );
}

/// The report as a browser shows it: Debian's Chromium, headless, loads report.html (no
/// error on its console, nothing fetched) and draws its three plots: each plot's frame
/// (#fbfbfb) holds pixels of its data colour.
#[test]
#[ignore = "needs Debian's chromium; .ci/run installs it and runs this"]
fn chromium_draws_every_plot_of_a_report() {
    let _one = one_at_a_time();
    let careless = try_lesson("liver-straight", "careless");
    assert!(!careless["passed"].as_bool().unwrap());
    let out = station::scratch("lesson-liver-straight-careless");
    let shot = browser::screenshot(
        &out.join("report.html"),
        &out.join("report.png"),
        1400,
        1600,
    );
    let boxes = shot.plot_frames();
    assert_eq!(
        boxes.len(),
        3,
        "plot frames found: {boxes:?} ({} × {})",
        shot.w,
        shot.h
    );
    // Each plot's own data colour (its frames close in page order: the plan from above,
    // the depth profile, then the force): the cut's red (#c0392b) in the first two, the
    // force trace's blue (#2c3e80) in the third (its limits are dashed orange and red).
    let red = (0xc0, 0x39, 0x2b);
    let blue = (0x2c, 0x3e, 0x80);
    for (k, (b, colour)) in boxes.iter().zip([red, red, blue]).enumerate() {
        let drawn = shot.count_near(*b, colour);
        assert!(drawn > 50, "plot {k} {b:?}: {drawn} pixels of {colour:?}");
    }
}
