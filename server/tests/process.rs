//! The real server process, as a user runs it: the embedded default for a few seconds, and
//! a bad configuration file.

use std::process::Command;

fn server() -> Command {
    Command::new(env!("CARGO_BIN_EXE_scalpel-server"))
}

#[test]
fn the_embedded_default_runs_the_demo_cut_and_replays_bit_for_bit() {
    let dir = std::env::temp_dir().join(format!("scalpel-journal-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let journal = dir.join("session.journal");
    let out = server()
        .args(["--duration", "4", "--json", "--journal"])
        .arg(&journal)
        .output()
        .expect("the server starts");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON object per line"))
        .collect();
    let (summary, reports) = lines.split_last().expect("a summary");
    let status: Vec<&serde_json::Value> = reports
        .iter()
        .filter(|l| l.get("haptic").is_some())
        .collect();
    assert!(status.len() >= 2, "a status line a second: {stdout}");
    for line in &status {
        let force = line["haptic"]["force_n"].as_f64().unwrap();
        assert!(force.is_finite() && (0.0..=3.3).contains(&force), "{line}");
    }
    // The haptic loop ran and the simulation followed it; the blade reached the tissue
    // (the demo cut enters at about 1 s) and cut.
    assert!(
        summary["haptic_ticks"].as_u64().unwrap() > 1000,
        "{summary}"
    );
    assert!(
        summary["sim"]["ticks"].as_u64().unwrap() > 1000,
        "{summary}"
    );
    assert!(
        summary["sim"]["cut_length_mm"].as_f64().unwrap() > 0.0,
        "{summary}"
    );
    // The liver's mass floor gives it one sub-step per tick, and the cut keeps it.
    assert_eq!(summary["sim"]["most_substeps"], 1, "{summary}");
    // The device felt the cut (the largest force of the status samples: one may fall in a
    // watchdog fade while a slow build re-meshes).
    let felt = status
        .iter()
        .map(|l| l["haptic"]["force_n"].as_f64().unwrap())
        .fold(0.0, f64::max);
    assert!(felt > 0.5, "{stdout}");

    // The journal replays to the live run's final state, bit for bit.
    assert_eq!(summary["journal_dropped"].as_u64(), Some(0), "{summary}");
    let recorded = scalpel_server::journal::read(&journal).unwrap();
    let live = summary["state_hash"].as_u64().unwrap();
    assert_eq!(recorded.end, Some((recorded.ticks.len() as u64, live)));
    assert!(recorded.ticks.iter().any(|t| t.pose.is_some()));
    let scene = scalpel_server::scene_file::load_scene(&recorded.scene).unwrap();
    assert_eq!(scalpel_server::journal::replay(&scene, &recorded), live);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_bad_configuration_is_refused_with_its_key() {
    let dir = std::env::temp_dir().join(format!("scalpel-server-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("bad.toml");
    std::fs::write(&file, "[output]\nrate_limit_n_per_ms = -1\n").unwrap();
    let out = server().arg(&file).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("bad.toml") && stderr.contains("output.rate_limit_n_per_ms"),
        "{stderr}"
    );
    std::fs::write(&file, "[outptu]\n").unwrap();
    let out = server().arg(&file).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("outptu"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}
