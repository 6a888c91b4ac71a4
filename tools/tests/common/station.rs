//! Real processes for the station tests: the server (`scalpel-server`), the mock device and
//! the viewer (`scalpel`), with their output read line by line as it comes.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// The `scalpel` binary.
pub fn scalpel() -> Command {
    Command::new(env!("CARGO_BIN_EXE_scalpel"))
}

/// The `scalpel-server` binary, built beside `scalpel` by `cargo test --workspace`.
pub fn server_binary() -> PathBuf {
    let path = Path::new(env!("CARGO_BIN_EXE_scalpel")).with_file_name("scalpel-server");
    assert!(
        path.exists(),
        "{} is missing: run the tests with `cargo test --workspace --release` (or first `cargo build [--release] --bin scalpel-server`, in the tests' profile)",
        path.display()
    );
    path
}

/// A station name no other test (or earlier run) uses.
pub fn unique_station(what: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    format!("t-{what}-{}-{nanos}", std::process::id())
}

/// A scratch directory for one test.
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("scalpel-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A running process whose stdout lines arrive on a channel.
pub struct Running {
    /// The process.
    pub child: Child,
    lines: Receiver<String>,
    /// Every line read so far.
    pub seen: Vec<String>,
}

impl Running {
    /// Starts `command` with stdout piped.
    pub fn start(mut command: Command) -> Self {
        let mut child = command
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("the process starts");
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Self {
            child,
            lines: rx,
            seen: Vec::new(),
        }
    }

    /// Reads lines until one satisfies `want` (returned), or `timeout` passes (panics with
    /// everything seen).
    pub fn wait_for(&mut self, timeout: Duration, mut want: impl FnMut(&str) -> bool) -> String {
        let end = Instant::now() + timeout;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    self.seen.push(line.clone());
                    if want(&line) {
                        return line;
                    }
                }
                Err(RecvTimeoutError::Timeout) | Err(RecvTimeoutError::Disconnected) => {
                    panic!(
                        "waited {timeout:?} in vain; output so far:\n{}",
                        self.seen.join("\n")
                    )
                }
            }
        }
    }

    /// One of a server's next status lines (not one already printed) says its haptic loop
    /// runs at (nearly) 1 kHz. One is not enough: a status window is a quarter of a second,
    /// and a 2-vCPU VM has stalled the loop for 20–50 ms inside one (seen in a CI run: 851
    /// Hz in a window, the next ones at 1 kHz). A loop that has stopped never gets there.
    pub fn assert_ticking(&mut self) {
        while let Ok(line) = self.lines.try_recv() {
            self.seen.push(line);
        }
        // `wait_for` fails the test, with the lines seen, if none comes.
        self.wait_for(Duration::from_secs(5), |l| {
            json(l)["haptic"]["rate_hz"]
                .as_f64()
                .is_some_and(|hz| hz > 900.0)
        });
    }

    /// Kills the process with SIGKILL (no clean-up of any kind on its side).
    pub fn kill_9(&mut self) {
        self.child.kill().expect("SIGKILL");
        self.child.wait().unwrap();
    }

    /// Stops the process as a user stops it (SIGINT, Ctrl-C) and waits for it to end.
    pub fn interrupt(self) -> (std::process::ExitStatus, Vec<String>) {
        let sent = Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .status()
            .unwrap();
        assert!(sent.success(), "kill -INT");
        self.finish()
    }

    /// Waits for the process to end and returns the rest of its output.
    pub fn finish(mut self) -> (std::process::ExitStatus, Vec<String>) {
        let status = self.child.wait().unwrap();
        while let Ok(line) = self.lines.recv_timeout(Duration::from_secs(5)) {
            self.seen.push(line);
        }
        (status, std::mem::take(&mut self.seen))
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts a server at `station` with a shared-memory device, JSON status every 0.25 s.
pub fn start_server(station: &str, dir: &Path, duration_s: f64) -> Running {
    start_server_with(station, dir, duration_s, "shared_memory")
}

/// Starts a server at `station` with a device of `kind`, JSON status every 0.25 s.
pub fn start_server_with(station: &str, dir: &Path, duration_s: f64, kind: &str) -> Running {
    let config = dir.join(format!("{station}.toml"));
    std::fs::write(
        &config,
        format!(
            "station = \"{station}\"\n[device]\nkind = \"{kind}\"\n[rates]\nstatus_interval_s = 0.25\n"
        ),
    )
    .unwrap();
    let mut command = Command::new(server_binary());
    command
        .arg(&config)
        .args(["--json", "--duration", &duration_s.to_string()]);
    Running::start(command)
}

/// Writes `dir/observed.toml`, the built-in liver with remote observers (a scene the QUIC
/// endpoint runs for), and returns its path.
pub fn write_observed_scene(dir: &Path) -> PathBuf {
    let scene = dir.join("observed.toml");
    std::fs::write(
        &scene,
        "extends = \"liver\"\n[features]\nobservers = true\n",
    )
    .unwrap();
    scene
}

/// Makes a lab CA and the server's certificate in `dir` with `scalpel certs init`.
pub fn make_lab_ca(dir: &Path) {
    let made = scalpel()
        .args(["certs", "init", "--dir"])
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "scalpel certs init: {}",
        String::from_utf8_lossy(&made.stderr)
    );
}

/// A JSON line as a value (`Null` if it is not JSON).
pub fn json(line: &str) -> serde_json::Value {
    serde_json::from_str(line).unwrap_or(serde_json::Value::Null)
}

/// Runs `tools/tests/python/<script>` with `args` on the interpreter named by
/// SCALPEL_PYTHON (`.ci/run`'s venv; `python3` otherwise) and returns the one JSON object
/// it prints; fails the test with its output if it fails.
pub fn run_python(script: &str, args: &[String]) -> serde_json::Value {
    let python = std::env::var("SCALPEL_PYTHON").unwrap_or_else(|_| "python3".into());
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/python")
        .join(script);
    let out = Command::new(&python)
        .arg(&path)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{script}: {stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    json(stdout.trim())
}
