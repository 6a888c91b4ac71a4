//! The journal: every input the simulation used, with its tick, so that a session replays
//! bit for bit (`scalpel replay FILE`). Text, one line per tick, numbers as the hex of their
//! f64 bits (exact, and readable with any tool):
//!
//! ```text
//! scalpel-journal 2
//! scene liver
//! started 1796660370                         (when the session began, Unix seconds)
//! config station = "station-1"               (the server's effective configuration, TOML,
//! config [device]                             one line per line; the simulation does not
//! ...                                         read it, a reader of the journal does)
//! lesson name = "Straight incision"          (the lesson's TOML as the station read it,
//! ...                                         when it ran one: a report scores the lesson
//!                                             the trainee had, not today's file)
//! tick 1 -                                   (no tool)
//! tick 2 <tip x y z> <orientation w i j k>   (seven f64 bit patterns in hex)
//! command {"station_tick":2,"sim_tick":1,"by":"ann","seq":1,"action":...,"outcome":...}
//! stiffness 3 4000000000000000               (factor from tick 3 on, an instructor's fault)
//! tick 3 ...
//! end 5000 9f0c2a41d3b87e65                  (ticks, state hash at the end of the run)
//! ```
//!
//! The simulation thread hands each tick's record to a writer thread through an SPSC ring,
//! so the file's I/O never blocks a tick. Instructor commands come from the main thread
//! (JSON: who sent what, when, and what became of it); the faults' effects on the
//! simulation are in the records themselves — the poses as the simulation got them
//! (delayed, noisy, dropped) and the stiffness lines — so a replay needs nothing else.

use std::fmt::Write as _;
use std::io::{BufRead, Read, Write};
use std::path::Path;

use anyhow::{Context, bail};
use nalgebra::{Quaternion, UnitQuaternion};
use scalpel_sim::cut::ToolPose;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{NoClock, Simulation, StageClock, TickReport};
use scalpel_sim::scene::BuiltScene;

/// Format version written on the first line. Version 1 (no `started`, no `lesson` lines)
/// still reads.
pub const JOURNAL_VERSION: u32 = 2;

/// One tick's input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickRecord {
    /// Simulation tick (from 1).
    pub tick: u64,
    /// The tool pose the tick used.
    pub pose: Option<ToolPose>,
    /// A new tissue stiffness factor (an instructor's fault), set before the tick.
    pub stiffness: Option<f64>,
}

impl TickRecord {
    /// Gives `sim` this tick's inputs (the stiffness change, then the pose), as the station's
    /// simulation thread does before it ticks and as a replay does: the one path both take,
    /// so that a replay is the live run by construction.
    pub fn apply_to(&self, sim: &mut Simulation) {
        if let Some(k) = self.stiffness {
            sim.handle_stiffness_factor(k);
        }
        sim.handle_tool_pose(self.pose);
    }
}

/// The header lines for a session on `scene` begun at `started_unix_s`, with the server
/// configuration `config` (TOML) and the text of the lesson it runs (TOML, empty for none).
pub fn header(scene: &str, started_unix_s: u64, config: &str, lesson: &str) -> String {
    let mut s =
        format!("scalpel-journal {JOURNAL_VERSION}\nscene {scene}\nstarted {started_unix_s}\n");
    for line in config.lines() {
        let _ = writeln!(s, "config {line}");
    }
    for line in lesson.lines() {
        let _ = writeln!(s, "lesson {line}");
    }
    s
}

/// One tick's line (after its stiffness line, if the factor changed).
pub fn write_record(out: &mut impl Write, r: &TickRecord) -> std::io::Result<()> {
    let mut line = String::with_capacity(200);
    if let Some(k) = r.stiffness {
        let _ = writeln!(line, "stiffness {} {:016x}", r.tick, k.to_bits());
    }
    let _ = write!(line, "tick {}", r.tick);
    match r.pose {
        None => line.push_str(" -"),
        Some(p) => {
            let q = p.orientation.quaternion();
            for x in [p.tip_m.x, p.tip_m.y, p.tip_m.z, q.w, q.i, q.j, q.k] {
                let _ = write!(line, " {:016x}", x.to_bits());
            }
        }
    }
    line.push('\n');
    out.write_all(line.as_bytes())
}

/// An instructor command's line: `record` is a JSON object (no newlines in it).
pub fn command_line(record: &serde_json::Value) -> String {
    format!("command {record}\n")
}

/// The closing line.
pub fn footer(ticks: u64, state_hash: u64) -> String {
    format!("end {ticks} {state_hash:016x}\n")
}

/// A journal read back.
#[derive(Debug, Clone, PartialEq)]
pub struct Journal {
    /// The scene the session ran.
    pub scene: String,
    /// When the session began (Unix seconds; `None` in a version 1 journal).
    pub started_unix_s: Option<u64>,
    /// The server's configuration (TOML), as journaled.
    pub config: String,
    /// The lesson the station ran (TOML, as it read it; empty for none or version 1).
    pub lesson: String,
    /// Every tick's input, in order.
    pub ticks: Vec<TickRecord>,
    /// Instructor commands (JSON objects), in the order the server took them.
    pub commands: Vec<serde_json::Value>,
    /// The live run's tick count and final state hash, when it closed the journal.
    pub end: Option<(u64, u64)>,
}

impl Journal {
    /// The station's `[limits]` as journaled (the defaults for a journal from before they
    /// existed, or with none): `scalpel replay` admits the scene within the same memory.
    pub fn limits(&self) -> crate::config::LimitsConfig {
        self.config
            .parse::<toml::Table>()
            .ok()
            .and_then(|t| t.get("limits").cloned())
            .and_then(|l| l.try_into().ok())
            .unwrap_or_default()
    }
}

impl Journal {
    /// A top-level string key of the journaled configuration (`trainee`, `lesson`), when
    /// set and not empty.
    pub fn config_string(&self, key: &str) -> Option<String> {
        self.config
            .parse::<toml::Table>()
            .ok()?
            .get(key)?
            .as_str()
            .filter(|s| !s.is_empty())
            .map(str::to_string)
    }
}

/// The longest line a journal may have (bytes).
const MAX_LINE_BYTES: u64 = 1 << 20;

/// Reads a journal; errors name the file and line. A journal whose session was killed reads
/// up to its last complete line.
pub fn read(path: &Path) -> anyhow::Result<Journal> {
    let journal = read_lines(path)?;
    // The simulation does not read the configuration, so only its form is checked: the
    // checks of the configuration itself change between versions, and an older journal
    // must still replay.
    if !journal.config.is_empty() {
        journal
            .config
            .parse::<toml::Table>()
            .with_context(|| format!("{}: its config lines are not TOML", path.display()))?;
    }
    Ok(journal)
}

fn read_lines(path: &Path) -> anyhow::Result<Journal> {
    // A file or a pipe (`scalpel replay <(zstd -dc s.journal.zst)`); not a device, whose
    // bytes never end.
    let meta = std::fs::metadata(path)
        .with_context(|| format!("cannot read journal {}", path.display()))?;
    {
        use std::os::unix::fs::FileTypeExt;
        let kind = meta.file_type();
        if !(kind.is_file() || kind.is_fifo()) {
            bail!(
                "cannot read journal {}: not a file or a pipe",
                path.display()
            );
        }
    }
    let file = std::fs::File::open(path)
        .with_context(|| format!("cannot read journal {}", path.display()))?;
    let mut reader = std::io::BufReader::new(file);
    let mut number = 0;
    // Each line read with a cap: a journal's longest lines (config, command) are far
    // shorter, and a file of garbage must not be read into memory whole. `None` at the end
    // of the file, and for a last line a kill cut inside a character.
    let mut next = || -> anyhow::Result<Option<(usize, String, bool)>> {
        let mut bytes = Vec::new();
        number += 1;
        let n = (&mut reader)
            .take(MAX_LINE_BYTES + 1)
            .read_until(b'\n', &mut bytes)
            .with_context(|| format!("{}:{number}", path.display()))?;
        if n == 0 {
            return Ok(None);
        }
        if n as u64 > MAX_LINE_BYTES {
            bail!(
                "{}:{number}: a line over {MAX_LINE_BYTES} bytes: not a journal",
                path.display()
            );
        }
        let last = reader
            .fill_buf()
            .with_context(|| format!("{}:{number}", path.display()))?
            .is_empty();
        let mut line = match String::from_utf8(bytes) {
            Ok(line) => line,
            Err(_) if last => return Ok(None),
            Err(e) => bail!("{}:{number}: not UTF-8 text: {e}", path.display()),
        };
        if line.ends_with('\n') {
            line.pop();
            if line.ends_with('\r') {
                line.pop();
            }
        }
        Ok(Some((number, line, last)))
    };
    let ends_before = |what: &str| anyhow::anyhow!("{}: ends before {what}", path.display());
    let (n, first, _) = next()?.ok_or_else(|| ends_before("the header"))?;
    if !(1..=JOURNAL_VERSION).any(|v| first == format!("scalpel-journal {v}")) {
        bail!(
            "{}:{n}: not a scalpel journal of version 1 to {JOURNAL_VERSION} (starts with \
             {first:?})",
            path.display()
        );
    }
    let (n, scene, _) = next()?.ok_or_else(|| ends_before("the scene line"))?;
    let scene = scene
        .strip_prefix("scene ")
        .with_context(|| format!("{}:{n}: expected 'scene NAME'", path.display()))?
        .to_string();
    let mut journal = Journal {
        scene,
        started_unix_s: None,
        config: String::new(),
        lesson: String::new(),
        ticks: Vec::new(),
        commands: Vec::new(),
        end: None,
    };
    let mut stiffness: Option<(u64, f64)> = None;
    loop {
        let Some((n, line, last)) = next()? else {
            // A session killed before it closed the journal still replays what it has.
            return Ok(journal);
        };
        if let Some(c) = line
            .strip_prefix("config ")
            .or((line == "config").then_some(""))
        {
            journal.config.push_str(c);
            journal.config.push('\n');
            continue;
        }
        if let Some(c) = line
            .strip_prefix("lesson ")
            .or((line == "lesson").then_some(""))
        {
            journal.lesson.push_str(c);
            journal.lesson.push('\n');
            continue;
        }
        if let Some(t) = line.strip_prefix("started ") {
            journal.started_unix_s = Some(t.parse().with_context(|| {
                format!("{}:{n}: 'started' wants Unix seconds", path.display())
            })?);
            continue;
        }
        // ... even when the kill cut its last line short.
        let fields: Vec<&str> = line.split_whitespace().collect();
        let complete = line.starts_with("end ")
            || line.ends_with(" -")
            || (line.starts_with("command ") && line.ends_with('}'))
            || (matches!(fields.len(), 3 | 9) && fields.last().is_some_and(|b| b.len() == 16));
        if last && !complete {
            return Ok(journal);
        }
        let at = || format!("{}:{n}", path.display());
        if let Some(json) = line.strip_prefix("command ") {
            let command: serde_json::Value = serde_json::from_str(json)
                .with_context(|| format!("{}: the command is not JSON", at()))?;
            // A record of what an instructor asked for, as asked (a refused command's
            // non-finite numbers are written as null): its form only.
            if !command.is_object() {
                bail!("{}: the command is not a JSON object", at());
            }
            journal.commands.push(command);
            continue;
        }
        match fields.as_slice() {
            ["stiffness", tick, bits] => stiffness = Some(stiffness_of(tick, bits, &at)?),
            ["tick", tick, rest @ ..] => {
                let tick: u64 = tick
                    .parse()
                    .with_context(|| format!("{}: bad tick", at()))?;
                let expected = journal.ticks.len() as u64 + 1;
                if tick != expected {
                    bail!("{}: tick {tick} where tick {expected} was expected", at());
                }
                let pose = pose_of(rest, tick, &at)?;
                let stiffness = match stiffness.take() {
                    Some((t, k)) if t == tick => Some(k),
                    Some((t, _)) => {
                        bail!("{}: a stiffness line for tick {t} before tick {tick}", at())
                    }
                    None => None,
                };
                journal.ticks.push(TickRecord {
                    tick,
                    pose,
                    stiffness,
                });
            }
            ["end", ticks, hash] => {
                let ticks: u64 = ticks
                    .parse()
                    .with_context(|| format!("{}: bad count", at()))?;
                let hash =
                    u64::from_str_radix(hash, 16).with_context(|| format!("{}: bad hash", at()))?;
                journal.end = Some((ticks, hash));
                return Ok(journal);
            }
            _ => bail!(
                "{}: expected a 'tick', 'stiffness', 'command' or 'end' line",
                at()
            ),
        }
    }
}

/// A stiffness line's tick and factor (within the faults' range).
fn stiffness_of(tick: &str, bits: &str, at: &dyn Fn() -> String) -> anyhow::Result<(u64, f64)> {
    let tick: u64 = tick
        .parse()
        .with_context(|| format!("{}: bad tick", at()))?;
    let raw =
        u64::from_str_radix(bits, 16).with_context(|| format!("{}: bad number {bits:?}", at()))?;
    let k = f64::from_bits(raw);
    let (lo, hi) = (
        f64::from(crate::faults::MIN_STIFFNESS),
        f64::from(crate::faults::MAX_STIFFNESS),
    );
    if !(lo..=hi).contains(&k) {
        bail!(
            "{}: stiffness factor {k:e} is outside {lo:.1}–{hi:.0} (the faults' range)",
            at()
        );
    }
    Ok((tick, k))
}

/// A tick line's pose: `-` (no tool) or seven numbers (tip, quaternion), sound.
fn pose_of(rest: &[&str], tick: u64, at: &dyn Fn() -> String) -> anyhow::Result<Option<ToolPose>> {
    match rest {
        ["-"] => Ok(None),
        bits if bits.len() == 7 => {
            let mut v = [0.0; 7];
            for (slot, b) in v.iter_mut().zip(bits) {
                let raw = u64::from_str_radix(b, 16)
                    .with_context(|| format!("{}: bad number {b:?}", at()))?;
                *slot = f64::from_bits(raw);
            }
            let q = Quaternion::new(v[3], v[4], v[5], v[6]);
            let pose = ToolPose {
                tip_m: Vec3::new(v[0], v[1], v[2]),
                orientation: UnitQuaternion::new_unchecked(q),
            };
            // What the station journals is what its simulation took.
            if !pose.is_sound() {
                bail!(
                    "{}: tick {tick}: the pose is not a finite tip and a unit quaternion",
                    at()
                );
            }
            Ok(Some(pose))
        }
        _ => bail!("{}: expected '-' or seven numbers after the tick", at()),
    }
}

/// Plays the journal's inputs through a fresh simulation of `scene`; returns the state hash
/// at the end.
pub fn replay(scene: &BuiltScene, journal: &Journal) -> u64 {
    replay_with(scene, journal, &mut NoClock, |_, _, _| {})
}

/// [`replay`], timing the stages on `clock` and handing each tick's report (with the
/// journal's index of the tick, and the simulation after it) to `on_tick`.
pub fn replay_with(
    scene: &BuiltScene,
    journal: &Journal,
    clock: &mut dyn StageClock,
    mut on_tick: impl FnMut(usize, &TickReport, &Simulation),
) -> u64 {
    let mut sim = Simulation::new(scene);
    // As the station does before its threads start (the masses it plans depend on the
    // material then, before any stiffness fault).
    sim.prepare(crate::station::SIM_TICK_S);
    for (k, r) in journal.ticks.iter().enumerate() {
        r.apply_to(&mut sim);
        let report = sim.tick(crate::station::SIM_TICK_S, clock);
        on_tick(k, &report, &sim);
    }
    sim.state_hash()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Appends one tick's lines, as the station's writer does.
    fn record(text: &mut Vec<u8>, tick: u64, pose: Option<ToolPose>, stiffness: Option<f64>) {
        write_record(
            text,
            &TickRecord {
                tick,
                pose,
                stiffness,
            },
        )
        .unwrap();
    }

    #[test]
    fn a_killed_session_reads_up_to_its_last_complete_line() {
        let dir = std::env::temp_dir().join(format!("scalpel-journal-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("cut.journal");
        let lesson = "name = \"x\"\nscene = \"liver\"\n";
        let mut text = header(
            "liver",
            1_796_660_370,
            "station = \"a\"\n\n[device]\n",
            lesson,
        )
        .into_bytes();
        let pose = ToolPose::pointing(Vec3::new(0.01, -0.02, 0.03), Vec3::z());
        record(&mut text, 1, None, None);
        record(&mut text, 2, Some(pose), Some(1.5));
        text.extend_from_slice(
            command_line(&serde_json::json!({"by": "ann", "seq": 1})).as_bytes(),
        );
        let whole = text.len();
        record(&mut text, 3, Some(pose), None);
        // Cut in the middle of the last number, as a kill mid-flush would.
        text.truncate(whole + 40);
        std::fs::write(&path, &text).unwrap();
        let j = read(&path).unwrap();
        assert_eq!(j.ticks.len(), 2);
        assert_eq!(j.ticks[1].pose, Some(pose));
        assert_eq!(j.ticks[1].stiffness, Some(1.5));
        assert_eq!(j.commands, vec![serde_json::json!({"by": "ann", "seq": 1})]);
        assert_eq!(j.config, "station = \"a\"\n\n[device]\n");
        assert_eq!(j.lesson, lesson);
        assert_eq!(j.started_unix_s, Some(1_796_660_370));
        assert_eq!(j.end, None);
        // A bad line that is not the last is an error naming the line.
        let mut text = header("liver", 0, "station = \"a\"\n\n[device]\n", "").into_bytes();
        text.extend_from_slice(b"tick 1 zz\ntick 2 -\n");
        std::fs::write(&path, &text).unwrap();
        let e = read(&path).unwrap_err().to_string();
        assert!(e.contains("cut.journal:7"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn what_a_live_server_writes_replays() {
        let dir = std::env::temp_dir().join(format!("scalpel-journal-live-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("live.journal");
        let mut text =
            header("liver", 0, "station = \"a\"\n[rates]\nframe_hz = 0.5\n", "").into_bytes();
        // A refused command with a NaN, as the station writes it (serde_json: null), and a
        // last line a kill cut inside a two-byte character.
        text.extend_from_slice(
            command_line(&serde_json::json!({"by": "ann", "action": {"sigma_mm": f32::NAN}}))
                .as_bytes(),
        );
        record(&mut text, 1, None, None);
        text.extend_from_slice("command {\"by\":\"Zo\u{eb}\"}".as_bytes());
        text.truncate(text.len() - 3);
        assert!(std::str::from_utf8(&text).is_err());
        std::fs::write(&path, &text).unwrap();
        let j = read(&path).unwrap();
        assert_eq!(j.ticks.len(), 1);
        assert_eq!(j.commands.len(), 1);
        // Through a pipe, as `scalpel replay <(zstd -dc …)` gives it.
        let fifo = dir.join("pipe");
        assert!(
            std::process::Command::new("mkfifo")
                .arg(&fifo)
                .status()
                .unwrap()
                .success()
        );
        let writer = {
            let (fifo, text) = (fifo.clone(), text.clone());
            std::thread::spawn(move || std::fs::write(fifo, text).unwrap())
        };
        assert_eq!(read(&fifo).unwrap().ticks.len(), 1);
        writer.join().unwrap();
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_journal_the_server_could_not_have_written_is_refused_with_its_line() {
        let dir = std::env::temp_dir().join(format!("scalpel-journal-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bad.journal");
        let good = header("liver", 0, "station = \"a\"\n", "");
        let one = |hex: u64| format!("{hex:016x}");
        let tip = [0.01f64, 0.0, 0.0].map(|c| one(c.to_bits())).join(" ");
        let refused = |body: &str| -> String {
            std::fs::write(&path, format!("{good}{body}tick 9 -\n")).unwrap();
            format!("{:#}", read(&path).unwrap_err())
        };
        // A NaN and an unnormalised orientation (replay panicked on the first).
        for q in [
            [f64::NAN, 0.0, 0.0, 1.0],
            [2.0, 0.0, 0.0, 0.0],
            [f64::INFINITY, 0.0, 0.0, 0.0],
        ] {
            let q = q.map(|c| one(c.to_bits())).join(" ");
            let e = refused(&format!("tick 1 {tip} {q}\n"));
            assert!(
                e.contains("bad.journal:5") && e.contains("unit quaternion"),
                "{e}"
            );
        }
        let e = refused(&format!(
            "stiffness 1 {}\ntick 1 -\n",
            one(1.0e308f64.to_bits())
        ));
        assert!(e.contains("bad.journal:5") && e.contains("0.1–10"), "{e}");
        let e = refused("command [1, 2]\n");
        assert!(
            e.contains("bad.journal:5") && e.contains("not a JSON object"),
            "{e}"
        );
        // Config lines that are not TOML (their values are not checked: the checks change
        // between versions, and the simulation does not read them).
        std::fs::write(
            &path,
            "scalpel-journal 1\nscene liver\nconfig [rates]\nconfig haptic_hz = = 1\ntick 1 -\n",
        )
        .unwrap();
        let e = format!("{:#}", read(&path).unwrap_err());
        assert!(e.contains("config lines are not TOML"), "{e}");
        // Not a file, and a line no journal has.
        let e = format!("{:#}", read(Path::new("/dev/zero")).unwrap_err());
        assert!(e.contains("not a file or a pipe"), "{e}");
        std::fs::write(&path, format!("{good}{}\n", "x".repeat(2 << 20))).unwrap();
        let e = format!("{:#}", read(&path).unwrap_err());
        assert!(e.contains("bad.journal:5") && e.contains("over"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
