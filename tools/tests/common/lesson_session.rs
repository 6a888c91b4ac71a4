//! A station's session as a lab runs one: the real server with a trainee and a lesson in
//! its configuration, a real mock device playing a scripted trainee over shared memory,
//! and the session journaled.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use super::station::{self, Running, scalpel, unique_station};

/// Who cuts what.
pub struct Session<'a> {
    /// The station's `trainee`.
    pub trainee: Option<&'a str>,
    /// The station's `lesson`.
    pub lesson: Option<&'a str>,
    /// The mock device's script; `None`: the server runs for 5 s (scene build included) with no device.
    pub script: Option<&'a Path>,
}

/// The mock-device script of a scripted trainee `who` on `lesson`, written into `dir`.
pub fn script(dir: &Path, lesson: &str, who: &str) -> std::path::PathBuf {
    let file = dir.join(format!("{lesson}-{who}.toml"));
    let made = scalpel()
        .args(["lesson", "script", lesson, "--trainee", who, "--out"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    file
}

/// Runs `session` at a station (its files in `dir`), journaled to `journal`.
pub fn run(dir: &Path, session: &Session, journal: &Path) {
    let name = unique_station("lesson");
    let config = dir.join(format!("{name}.toml"));
    let mut text = format!("station = \"{name}\"\n");
    if let Some(t) = session.trainee {
        text += &format!("trainee = \"{t}\"\n");
    }
    if let Some(l) = session.lesson {
        text += &format!("lesson = \"{l}\"\n");
    }
    text += "[device]\nkind = \"shared_memory\"\n[rates]\nstatus_interval_s = 0.25\n";
    std::fs::write(&config, text).unwrap();
    let mut command = Command::new(station::server_binary());
    let duration = if session.script.is_some() { "120" } else { "5" };
    command
        .arg(&config)
        .args(["--json", "--duration", duration, "--journal"])
        .arg(journal);
    let mut server = Running::start(command);
    server.wait_for(Duration::from_secs(60), |l| l.contains("\"haptic\""));
    let Some(script) = session.script else {
        let (status, out) = server.finish();
        assert!(status.success(), "{}", out.join("\n"));
        return;
    };
    let device = scalpel()
        .args(["mock-device", "--station", &name, "--script"])
        .arg(script)
        .output()
        .unwrap();
    assert!(
        device.status.success(),
        "{}",
        String::from_utf8_lossy(&device.stderr)
    );
    let (status, out) = server.interrupt();
    assert!(status.success(), "{}", out.join("\n"));
}
