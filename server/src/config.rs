//! The server's configuration file (TOML; every key in docs/SERVER.md; unknown keys are
//! rejected). With no file the embedded default runs: the built-in liver and an in-process
//! scripted device performing the demo cut.

use std::path::{Path, PathBuf};

use scalpel_sim::scene::file::MAX_DEVICE_FORCE_N;
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A rejected configuration: which file and what is wrong.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// Not readable.
    #[error("{file}: cannot read: {reason}")]
    Read {
        /// The file.
        file: PathBuf,
        /// Why (said in the message, not chained as a source: it would be said twice).
        reason: std::io::Error,
    },
    /// Not valid TOML, or a key that does not exist or has the wrong type.
    #[error("{file}: {message}")]
    Parse {
        /// The file.
        file: PathBuf,
        /// The parser's message (with line and column).
        message: String,
    },
    /// A value out of range.
    #[error("{file}: {key} = {value}: {expected}")]
    Range {
        /// The file.
        file: PathBuf,
        /// The key.
        key: &'static str,
        /// The value given.
        value: String,
        /// What is accepted.
        expected: String,
    },
}

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServerConfig {
    /// Station name (names the shared-memory services of this station).
    pub station: String,
    /// A built-in scene name or a scene file (docs/SCENES.md).
    pub scene: String,
    /// Who trains at the station: reports name them (empty: not named; never guessed).
    pub trainee: String,
    /// The lesson the station's sessions are scored on: a built-in lesson or a lesson file
    /// (docs/LESSONS.md) for the station's scene; empty: none.
    pub lesson: String,
    /// The haptic device.
    pub device: DeviceConfig,
    /// Loop rates.
    pub rates: RateConfig,
    /// Real-time scheduling of the haptic thread.
    pub realtime: RealtimeConfig,
    /// The output stage.
    pub output: OutputConfig,
    /// The QUIC endpoint for remote observers and instructors.
    pub network: NetworkConfig,
    /// What the station admits: the scene's memory and tick.
    pub limits: LimitsConfig,
}

/// What the station admits (docs/SERVER.md, "Admitting a scene").
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LimitsConfig {
    /// Most memory the scene may take, as estimated before it is built (MB); 0: half of the
    /// host's memory.
    pub memory_mb: f64,
    /// Most a whole-body tick may take, as estimated before the scene is built, in units of
    /// the 1 ms it simulates: a scene over it would leave the tissue that many times behind
    /// the hand.
    pub max_slowdown: f64,
}

impl Default for LimitsConfig {
    fn default() -> Self {
        Self {
            memory_mb: 0.0,
            max_slowdown: 10.0,
        }
    }
}

/// The QUIC endpoint.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetworkConfig {
    /// Address and port to listen on (e.g. `0.0.0.0:4433`); empty: no endpoint. It runs
    /// only for a scene with the `observers` feature.
    pub listen: String,
    /// Folder of the lab's certificates (`scalpel certs init`): `ca.pem`, `server.pem`,
    /// `server.key`.
    pub certs: String,
    /// Frames per second to an observer, at most.
    pub frame_hz: f64,
    /// Connections at once.
    pub max_connections: u32,
    /// Connections at once from one address.
    pub max_per_address: u32,
    /// TLS handshakes in flight at once (a client whose address a QUIC Retry validated,
    /// not yet through its handshake): a separate, small budget, so that handshakes never
    /// finished cannot take the connections' places.
    pub max_handshakes: u32,
    /// TLS handshakes in flight from one address.
    pub max_handshakes_per_address: u32,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        Self {
            listen: String::new(),
            certs: String::new(),
            frame_hz: 30.0,
            max_connections: 48,
            max_per_address: 16,
            max_handshakes: 16,
            max_handshakes_per_address: 4,
        }
    }
}

/// The haptic device.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviceConfig {
    /// `scripted`: an in-process device playing a cut script at the haptic rate;
    /// `shared_memory`: another process (the mock device, a device driver) on the
    /// station's iceoryx2 device services (docs/PROTOCOL.md).
    pub kind: DeviceKind,
    /// Cut script for `scripted` (TOML, `scalpel cut --script` format); empty: the scene's
    /// demo cut.
    pub script: String,
    /// `scripted`: start the script again when it ends.
    pub loop_script: bool,
}

/// Device kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceKind {
    /// In-process scripted device.
    Scripted,
    /// A device process over shared memory.
    SharedMemory,
}

/// Loop rates.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RateConfig {
    /// Haptic loop rate (Hz).
    pub haptic_hz: f64,
    /// Status line interval (s).
    pub status_interval_s: f64,
    /// Render frames per second over shared memory (0: none).
    pub frame_hz: f64,
}

/// Real-time scheduling.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RealtimeConfig {
    /// SCHED_FIFO priority for the haptic thread (1–99); 0 keeps the normal scheduler.
    pub fifo_priority: i32,
    /// SCHED_FIFO priority for the simulation thread (below the haptic thread's); 0 keeps
    /// the normal scheduler.
    pub sim_fifo_priority: i32,
    /// Lock the process's memory (mlockall) so the haptic loop never waits on a page fault.
    pub lock_memory: bool,
    /// A CPU for the haptic thread alone (-1: none): the thread is pinned to it and the
    /// network threads to the other CPUs, so QUIC to many observers (bursts of system calls
    /// and packet processing) does not share its CPU. Off by default: stations on one
    /// machine must each get their own.
    pub haptic_cpu: i32,
    /// Threads for the simulation, its own included (1 or 2): with 2 its force evaluation's
    /// two parts run in parallel on a worker it waits on (never the haptic thread: that
    /// one runs above both). At most the CPUs the process may use.
    pub sim_threads: u32,
    /// Nice value of the simulation's threads under normal scheduling (−20 to 19; 0: the
    /// process's): above local viewers and the station's other threads, below none that
    /// is real time. Refused (no CAP_SYS_NICE or RLIMIT_NICE) with a warning.
    pub sim_nice: i32,
}

/// Output stage limits.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Largest force sent (N); 0 uses the scene's `force.max_force_n`.
    pub max_force_n: f64,
    /// Largest change of the force per millisecond (N).
    pub rate_limit_n_per_ms: f64,
    /// No device sample for this long fades the force out (ms).
    pub device_timeout_ms: f64,
    /// No simulation update for this long fades the force out (ms).
    pub sim_timeout_ms: f64,
    /// Length of the fade out (ms).
    pub fade_out_ms: f64,
    /// Length of the fade back in (ms).
    pub fade_in_ms: f64,
    /// Hannaford–Ryu passivity observer and controller.
    pub passivity: bool,
    /// Time constant over which the passivity observer forgets absorbed energy (ms);
    /// 0 = never (the classic observer).
    pub passivity_memory_ms: f64,
    /// The stiffest local model rendered (N/m): the device's stable stiffness at the
    /// loop's rate; each eigenvalue of the model's K is bounded by it.
    pub max_stiffness_n_per_m: f64,
}

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            station: "station-1".into(),
            scene: "liver".into(),
            trainee: String::new(),
            lesson: String::new(),
            device: DeviceConfig::default(),
            rates: RateConfig::default(),
            realtime: RealtimeConfig::default(),
            output: OutputConfig::default(),
            network: NetworkConfig::default(),
            limits: LimitsConfig::default(),
        }
    }
}

impl Default for DeviceConfig {
    fn default() -> Self {
        Self {
            kind: DeviceKind::Scripted,
            script: String::new(),
            loop_script: true,
        }
    }
}

impl Default for RateConfig {
    fn default() -> Self {
        Self {
            haptic_hz: 1000.0,
            status_interval_s: 1.0,
            frame_hz: 60.0,
        }
    }
}

impl Default for RealtimeConfig {
    fn default() -> Self {
        Self {
            fifo_priority: 80,
            sim_fifo_priority: 0,
            lock_memory: true,
            haptic_cpu: -1,
            sim_threads: 2,
            sim_nice: -10,
        }
    }
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            max_force_n: 0.0,
            rate_limit_n_per_ms: 0.5,
            device_timeout_ms: 5.0,
            sim_timeout_ms: 100.0,
            fade_out_ms: 5.0,
            fade_in_ms: 50.0,
            passivity: true,
            passivity_memory_ms: 1000.0,
            max_stiffness_n_per_m: 1000.0,
        }
    }
}

/// A range check: the key, its value, whether it is in range, and what is accepted.
type Range<'a> = dyn Fn(&'static str, f64, bool, &'static str) -> Result<(), ConfigError> + 'a;

impl ServerConfig {
    /// The configuration as TOML (what the journal records).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_else(|e| format!("# not serialisable: {e}\n"))
    }

    /// Reads and checks a configuration file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = crate::input_file::read_text_capped(path, crate::input_file::TOML_MAX_BYTES)
            .map_err(|reason| ConfigError::Read {
                file: path.to_owned(),
                reason,
            })?;
        Self::from_toml(&text, path)
    }

    /// Parses and checks `text` (named `file` in errors).
    pub fn from_toml(text: &str, file: &Path) -> Result<Self, ConfigError> {
        let config: Self = toml::from_str(text).map_err(|e| ConfigError::Parse {
            file: file.to_owned(),
            message: e.to_string(),
        })?;
        config.check(file)?;
        Ok(config)
    }

    fn check(&self, file: &Path) -> Result<(), ConfigError> {
        let range = |key: &'static str, value: f64, ok: bool, expected: &'static str| {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(ConfigError::Range {
                    file: file.to_owned(),
                    key,
                    value: scalpel_sim::scene::file::readable_number(value),
                    expected: expected.to_string(),
                })
            }
        };
        self.check_rates(&range)?;
        self.check_realtime(&range)?;
        self.check_output(file, &range)?;
        self.check_limits(&range)?;
        self.check_network(file, &range)?;
        self.check_device(file)?;
        self.check_lesson(file)
    }

    /// `trainee` and `lesson`: a name a report can print, a lesson for this scene.
    fn check_lesson(&self, file: &Path) -> Result<(), ConfigError> {
        let error = |key: &'static str, value: &str, expected: String| ConfigError::Range {
            file: file.to_owned(),
            key,
            value: format!("{value:?}"),
            expected,
        };
        if self.trainee.chars().count() > 64 || self.trainee.chars().any(char::is_control) {
            return Err(error(
                "trainee",
                &self.trainee,
                "at most 64 characters, none of them a control character".into(),
            ));
        }
        if self.lesson.is_empty() {
            return Ok(());
        }
        let spec = crate::scene_file::load_lesson(&self.lesson)
            .map_err(|e| error("lesson", &self.lesson, format!("{e:#}")))?;
        if !crate::scene_file::same_scene(&spec.scene, &self.scene) {
            return Err(error(
                "lesson",
                &self.lesson,
                format!(
                    "a lesson for this station's scene ({:?}); it is for {:?}",
                    self.scene, spec.scene
                ),
            ));
        }
        Ok(())
    }

    /// `[rates]`.
    fn check_rates(&self, range: &Range<'_>) -> Result<(), ConfigError> {
        let r = &self.rates;
        range(
            "rates.haptic_hz",
            r.haptic_hz,
            (100.0..=10_000.0).contains(&r.haptic_hz),
            "between 100 and 10000 Hz",
        )?;
        range(
            "rates.status_interval_s",
            r.status_interval_s,
            (0.05..=3600.0).contains(&r.status_interval_s),
            "between 0.05 and 3600 s",
        )?;
        range(
            "rates.frame_hz",
            r.frame_hz,
            r.frame_hz == 0.0 || (1.0..=500.0).contains(&r.frame_hz),
            "0 (no frames) or 1 to 500 Hz",
        )?;
        Ok(())
    }

    /// `[realtime]`.
    fn check_realtime(&self, range: &Range<'_>) -> Result<(), ConfigError> {
        let p = self.realtime.fifo_priority;
        range(
            "realtime.fifo_priority",
            f64::from(p),
            (0..=99).contains(&p),
            "0 (normal scheduling) or 1–99",
        )?;
        let q = self.realtime.sim_fifo_priority;
        range(
            "realtime.sim_fifo_priority",
            f64::from(q),
            // A real-time simulation above a normally scheduled haptic thread would
            // preempt it.
            (0..=99).contains(&q) && (q == 0 || (p > 0 && q < p)),
            "0 (normal scheduling) or 1–99, below a realtime.fifo_priority that is not 0",
        )?;
        let c = self.realtime.haptic_cpu;
        range(
            "realtime.haptic_cpu",
            f64::from(c),
            (-1..=1023).contains(&c),
            "-1 (none) or a CPU number",
        )?;
        let t = self.realtime.sim_threads;
        range(
            "realtime.sim_threads",
            f64::from(t),
            // The force evaluation is split into two fixed parts (the same bits on one
            // thread or two); more threads would have nothing to take.
            (1..=2).contains(&t),
            "1 (the simulation thread alone) or 2 (with a worker)",
        )?;
        let n = self.realtime.sim_nice;
        range(
            "realtime.sim_nice",
            f64::from(n),
            (-20..=19).contains(&n),
            "-20 to 19 (0: the process's)",
        )?;
        Ok(())
    }

    /// `[output]`.
    fn check_output(&self, file: &Path, range: &Range<'_>) -> Result<(), ConfigError> {
        let o = &self.output;
        range(
            "output.max_force_n",
            o.max_force_n,
            (0.0..=MAX_DEVICE_FORCE_N).contains(&o.max_force_n),
            "between 0 (the scene's limit) and 50 N",
        )?;
        range(
            "output.rate_limit_n_per_ms",
            o.rate_limit_n_per_ms,
            o.rate_limit_n_per_ms > 0.0 && o.rate_limit_n_per_ms <= 50.0,
            "above 0 and at most 50 N/ms",
        )?;
        range(
            "output.max_stiffness_n_per_m",
            o.max_stiffness_n_per_m,
            (0.0..=20_000.0).contains(&o.max_stiffness_n_per_m),
            "between 0 (no local model: the force holds between simulation ticks) and 20000 N/m",
        )?;
        // A timeout shorter than two of the loop's periods would fade the force in and out
        // between samples.
        let period_ms = 1e3 / self.rates.haptic_hz;
        if !(o.device_timeout_ms >= 2.0 * period_ms && o.device_timeout_ms <= 10_000.0) {
            return Err(ConfigError::Range {
                file: file.to_owned(),
                key: "output.device_timeout_ms",
                value: scalpel_sim::scene::file::readable_number(o.device_timeout_ms),
                expected: format!(
                    "at least two haptic periods ({:.3} ms at rates.haptic_hz = {}) and at most 10000 ms",
                    2.0 * period_ms,
                    self.rates.haptic_hz
                ),
            });
        }
        range(
            "output.sim_timeout_ms",
            o.sim_timeout_ms,
            (2.0..=10_000.0).contains(&o.sim_timeout_ms),
            "at least 2 ms (two simulation ticks) and at most 10000 ms",
        )?;
        range(
            "output.fade_out_ms",
            o.fade_out_ms,
            o.fade_out_ms > 0.0 && o.fade_out_ms <= 1000.0,
            "above 0 and at most 1000 ms",
        )?;
        range(
            "output.fade_in_ms",
            o.fade_in_ms,
            o.fade_in_ms > 0.0 && o.fade_in_ms <= 10_000.0,
            "above 0 and at most 10000 ms",
        )?;
        // Shorter than a few periods would forget what the tissue absorbed within a tick
        // and let the controller damp ordinary elastic contact.
        range(
            "output.passivity_memory_ms",
            o.passivity_memory_ms,
            o.passivity_memory_ms == 0.0 || (10.0..=3_600_000.0).contains(&o.passivity_memory_ms),
            "0 (never forget) or 10 ms to one hour",
        )?;
        Ok(())
    }

    /// `[limits]`.
    fn check_limits(&self, range: &Range<'_>) -> Result<(), ConfigError> {
        let l = &self.limits;
        range(
            "limits.memory_mb",
            l.memory_mb,
            l.memory_mb == 0.0 || (64.0..=16.0 * 1024.0 * 1024.0).contains(&l.memory_mb),
            "0 (half of the host's memory) or 64 MB to 16 TB",
        )?;
        range(
            "limits.max_slowdown",
            l.max_slowdown,
            (1.0..=1000.0).contains(&l.max_slowdown),
            "between 1 (real time) and 1000",
        )?;
        Ok(())
    }

    /// `[network]`.
    fn check_network(&self, file: &Path, range: &Range<'_>) -> Result<(), ConfigError> {
        let n = &self.network;
        range(
            "network.frame_hz",
            n.frame_hz,
            n.frame_hz > 0.0 && n.frame_hz <= 120.0,
            "above 0 and at most 120 Hz",
        )?;
        range(
            "network.max_connections",
            f64::from(n.max_connections),
            (1..=1024).contains(&n.max_connections),
            "1 to 1024",
        )?;
        range(
            "network.max_per_address",
            f64::from(n.max_per_address),
            (1..=1024).contains(&n.max_per_address),
            "1 to 1024",
        )?;
        range(
            "network.max_handshakes",
            f64::from(n.max_handshakes),
            (1..=256).contains(&n.max_handshakes),
            "1 to 256",
        )?;
        range(
            "network.max_handshakes_per_address",
            f64::from(n.max_handshakes_per_address),
            (1..=n.max_handshakes.max(1)).contains(&n.max_handshakes_per_address),
            "1 to network.max_handshakes",
        )?;
        if !n.listen.is_empty() {
            if n.listen.parse::<std::net::SocketAddr>().is_err() {
                return Err(ConfigError::Range {
                    file: file.to_owned(),
                    key: "network.listen",
                    value: n.listen.clone(),
                    expected: "an address and port, like 127.0.0.1:4433 or [::]:4433".into(),
                });
            }
            if n.certs.is_empty() {
                return Err(ConfigError::Range {
                    file: file.to_owned(),
                    key: "network.certs",
                    value: String::new(),
                    expected: "the lab's certificate folder (scalpel certs init --dir DIR)".into(),
                });
            }
        }
        if scalpel_proto::shm::check_station(&self.station).is_err() {
            return Err(ConfigError::Range {
                file: file.to_owned(),
                key: "station",
                value: self.station.clone(),
                expected: "1 to 48 letters, digits, '-' and '_' (it names shared-memory services)"
                    .into(),
            });
        }
        // The journal names the scene on a line of its own.
        if self.scene.is_empty() || self.scene.chars().any(char::is_control) {
            return Err(ConfigError::Range {
                file: file.to_owned(),
                key: "scene",
                value: format!("{:?}", self.scene),
                expected:
                    "a built-in scene name or a scene file's path, without control characters"
                        .into(),
            });
        }
        Ok(())
    }

    /// `[device]`.
    fn check_device(&self, file: &Path) -> Result<(), ConfigError> {
        if self.device.kind == DeviceKind::SharedMemory && !self.device.script.is_empty() {
            return Err(ConfigError::Range {
                file: file.to_owned(),
                key: "device.script",
                value: format!("{:?}", self.device.script),
                expected:
                    "empty with kind = \"shared_memory\" (the device process plays its own script)"
                        .into(),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn docs_example_is_complete_and_shows_the_defaults() {
        let doc = include_str!("../../docs/SERVER.md");
        let start = doc.find("```toml\n").expect("an example") + 8;
        let end = start + doc[start..].find("```").unwrap();
        let text = &doc[start..end];
        let parsed = ServerConfig::from_toml(text, Path::new("docs/SERVER.md")).unwrap();
        assert_eq!(parsed, ServerConfig::default());
        // Every key of the example is documented in the table.
        for line in text.lines() {
            if let Some((key, _)) = line.split_once('=') {
                let key = key.trim();
                assert!(
                    doc.contains(&format!("| `{key}` |")),
                    "{key} is not in the table"
                );
            }
        }
    }

    #[test]
    fn the_configuration_round_trips_through_toml() {
        let mut config = ServerConfig::default();
        config.device.kind = DeviceKind::SharedMemory;
        config.rates.frame_hz = 30.0;
        let text = config.to_toml();
        assert_eq!(
            ServerConfig::from_toml(&text, Path::new("x")).unwrap(),
            config
        );
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named() {
        let e =
            ServerConfig::from_toml("[rates]\nhaptic_hz = 1000\ntypo = 1\n", Path::new("s.toml"))
                .unwrap_err()
                .to_string();
        assert!(e.contains("s.toml") && e.contains("typo"), "{e}");
        let e = ServerConfig::from_toml("[rates]\nhaptic_hz = 5\n", Path::new("s.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("rates.haptic_hz = 5"), "{e}");
        let e = ServerConfig::from_toml("station = \"a/b\"\n", Path::new("s.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("station"), "{e}");
        // Each `[output]` value refused names its key.
        let refused = |key: &str, bad: &[&str]| {
            for value in bad {
                let text = format!("[output]\n{key} = {value}\n");
                let e = ServerConfig::from_toml(&text, Path::new("s.toml"))
                    .unwrap_err()
                    .to_string();
                assert!(e.contains(&format!("output.{key}")), "{e}");
            }
        };
        // A memory of a few ticks would let the controller damp ordinary contact.
        refused("passivity_memory_ms", &["1", "-5", "nan"]);
        for good in ["0", "10", "1000.0"] {
            let text = format!("[output]\npassivity_memory_ms = {good}\n");
            assert!(ServerConfig::from_toml(&text, Path::new("s.toml")).is_ok());
        }
        refused("max_stiffness_n_per_m", &["-1", "30000", "nan"]);
    }

    #[test]
    fn settings_that_make_no_sense_together_are_refused() {
        let refused = |text: &str| {
            ServerConfig::from_toml(text, Path::new("s.toml"))
                .unwrap_err()
                .to_string()
        };
        let e = refused("[rates]\nframe_hz = 1e-9\n");
        assert!(e.contains("rates.frame_hz"), "{e}");
        // A real-time simulation above a normally scheduled haptic thread.
        let e = refused("[realtime]\nfifo_priority = 0\nsim_fifo_priority = 10\n");
        assert!(e.contains("realtime.sim_fifo_priority"), "{e}");
        for threads in ["0", "3"] {
            let e = refused(&format!("[realtime]\nsim_threads = {threads}\n"));
            assert!(e.contains("realtime.sim_threads"), "{e}");
        }
        // The journal names the scene on one line.
        let e = refused("scene = \"a\\nb.toml\"\n");
        assert!(e.contains("scene") && e.contains("control"), "{e}");
        let e = refused("[device]\nkind = \"shared_memory\"\nscript = \"x.toml\"\n");
        assert!(e.contains("device.script"), "{e}");
        // The timeout's bound, with the rate it comes from.
        let e = refused("[rates]\nhaptic_hz = 333.3\n");
        assert!(e.contains("6.001 ms at rates.haptic_hz = 333.3"), "{e}");
        // The reason said once.
        let e = format!(
            "{:#}",
            anyhow::Error::from(ServerConfig::load(Path::new("/nonexistent/s.toml")).unwrap_err())
        );
        assert_eq!(e.matches("No such file").count(), 1, "{e}");
        let e = ServerConfig::load(Path::new("/dev/zero"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a regular file"), "{e}");
    }
}
