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
    // The liver's mass floor gives it one sub-step per tick; where the blade strains the
    // strain-stiffening liver (β = 10) the step follows its tangent, one sub-step more.
    assert!(
        summary["sim"]["most_substeps"].as_u64().unwrap() <= 2,
        "{summary}"
    );
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

#[test]
fn a_station_whose_stdout_is_closed_runs_on() {
    // The reader is gone before the server writes its first line (a `| head` that has
    // what it wants, a log pipe whose reader exited): the station still runs its whole
    // session and says once on stderr why its status lines stopped.
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let dir = std::env::temp_dir().join(format!("scalpel-closed-out-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let journal = dir.join("session.journal");
    // A station of its own: the embedded default's test runs beside this one.
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!("station = \"closed-out-{}\"\n", std::process::id()),
    )
    .unwrap();
    let out = server()
        .arg(&config)
        .args(["--duration", "4", "--journal"])
        .arg(&journal)
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {stderr}", out.status);
    assert_eq!(stderr.matches("stdout closed").count(), 1, "{stderr}");
    // It ran the session to the end: the journal has its closing state hash.
    let recorded = scalpel_server::journal::read(&journal).unwrap();
    assert!(
        recorded.ticks.len() > 1000,
        "{} ticks",
        recorded.ticks.len()
    );
    assert!(recorded.end.is_some());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn with_a_haptic_cpu_the_simulation_and_its_worker_run_on_the_other_cpus() {
    let allowed = scalpel_server::realtime::allowed_cpus();
    let Some(&haptic_cpu) = allowed.last().filter(|_| allowed.len() >= 2) else {
        eprintln!("skipped: one CPU ({allowed:?}), nothing to keep the haptic CPU apart from");
        return;
    };
    let dir = std::env::temp_dir().join(format!("scalpel-pinned-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!(
            "station = \"pinned-{}\"\n[realtime]\nhaptic_cpu = {haptic_cpu}\n",
            std::process::id()
        ),
    )
    .unwrap();
    let mut child = server()
        .arg(&config)
        .args(["--duration", "20"])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Once the station says what runs, its threads are placed.
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut runs = String::new();
    while !runs.contains("runs:") {
        runs.clear();
        let n = std::io::BufRead::read_line(&mut stdout, &mut runs).unwrap();
        assert!(n > 0, "the server ended before saying what runs");
    }
    let cpus_of = |thread: &str| -> String {
        let tasks = std::path::PathBuf::from(format!("/proc/{}/task", child.id()));
        for task in std::fs::read_dir(&tasks).unwrap().flatten() {
            let comm = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
            if comm.trim() == thread {
                let status = std::fs::read_to_string(task.path().join("status")).unwrap();
                return status
                    .lines()
                    .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))
                    .unwrap()
                    .trim()
                    .to_string();
            }
        }
        panic!("no thread named {thread}");
    };
    let haptic = cpus_of("haptic");
    let simulation = cpus_of("simulation");
    // The simulation's worker (realtime.sim_threads = 2 by default).
    let worker = cpus_of("sim-worker-1");
    let _ = child.kill();
    let _ = child.wait();
    std::fs::remove_dir_all(&dir).ok();
    assert_eq!(haptic, haptic_cpu.to_string(), "{runs}");
    let others: Vec<usize> = allowed
        .iter()
        .copied()
        .filter(|&c| c != haptic_cpu)
        .collect();
    assert_eq!(parse_cpu_list(&simulation), others, "{runs}");
    // On the other CPUs when there are two of them; else anywhere (below the haptic
    // thread's priority), as one CPU would leave it nothing to do beside the simulation.
    let worker_cpus = if others.len() >= 2 { &others } else { &allowed };
    assert_eq!(&parse_cpu_list(&worker), worker_cpus, "{runs}");
    assert!(
        runs.contains(&format!("simulation on 2 threads (CPUs {others:?})")),
        "{runs}"
    );
}

/// A kernel CPU list ("0-2,5") as CPU numbers.
fn parse_cpu_list(list: &str) -> Vec<usize> {
    list.split(',')
        .flat_map(|part| match part.split_once('-') {
            Some((a, b)) => (a.parse().unwrap()..=b.parse().unwrap()).collect::<Vec<usize>>(),
            None => vec![part.parse().unwrap()],
        })
        .collect()
}

#[test]
fn a_scene_with_cutting_off_is_cut_and_the_station_says_so() {
    let dir = std::env::temp_dir().join(format!("scalpel-nocut-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("nocut.toml"),
        "extends = \"liver\"\n[features]\ncutting = false\n",
    )
    .unwrap();
    let config = dir.join("server.toml");
    std::fs::write(
        &config,
        format!(
            "station = \"nocut-{}\"\nscene = \"{}\"\n",
            std::process::id(),
            dir.join("nocut.toml").display()
        ),
    )
    .unwrap();
    let out = server()
        .arg(&config)
        // The liver settles on its tray under gravity before its first tick (about 1 s).
        .args(["--duration", "3"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("has features.cutting off; a station always cuts"),
        "{stdout}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
