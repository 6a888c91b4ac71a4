//! The journal: every input the simulation used, with its tick, so that a session replays
//! bit for bit (`scalpel replay FILE`). Text, one line per tick, numbers as the hex of their
//! f64 bits (exact, and readable with any tool):
//!
//! ```text
//! scalpel-journal 1
//! scene liver
//! config station = "station-1"               (the server's effective configuration, TOML,
//! config [device]                             one line per line; the simulation does not
//! ...                                         read it, a reader of the journal does)
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
use std::io::{BufRead, Write};
use std::path::Path;

use anyhow::{Context, bail};
use nalgebra::{Quaternion, UnitQuaternion};
use scalpel_sim::cut::ToolPose;
use scalpel_sim::math::Vec3;
use scalpel_sim::pipeline::{Simulation, Unobserved};
use scalpel_sim::scene::BuiltScene;

/// Format version written on the first line.
pub const JOURNAL_VERSION: u32 = 1;

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

/// The header lines for a session on `scene` with the server configuration `config` (TOML).
pub fn header(scene: &str, config: &str) -> String {
    let mut s = format!("scalpel-journal {JOURNAL_VERSION}\nscene {scene}\n");
    for line in config.lines() {
        let _ = writeln!(s, "config {line}");
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
    /// The server's configuration (TOML), as journaled.
    pub config: String,
    /// Every tick's input, in order.
    pub ticks: Vec<TickRecord>,
    /// Instructor commands (JSON objects), in the order the server took them.
    pub commands: Vec<serde_json::Value>,
    /// The live run's tick count and final state hash, when it closed the journal.
    pub end: Option<(u64, u64)>,
}

/// Reads a journal; errors name the file and line. A journal whose session was killed reads
/// up to its last complete line.
pub fn read(path: &Path) -> anyhow::Result<Journal> {
    let file = std::fs::File::open(path)
        .with_context(|| format!("cannot read journal {}", path.display()))?;
    let mut lines = std::io::BufReader::new(file).lines().enumerate().peekable();
    let mut next = |what: &str| -> anyhow::Result<(usize, String, bool)> {
        match lines.next() {
            Some((n, Ok(l))) => Ok((n + 1, l, lines.peek().is_none())),
            Some((n, Err(e))) => bail!("{}:{}: {e}", path.display(), n + 1),
            None => bail!("{}: ends before {what}", path.display()),
        }
    };
    let (n, first, _) = next("the header")?;
    if first != format!("scalpel-journal {JOURNAL_VERSION}") {
        bail!(
            "{}:{n}: not a scalpel journal of version {JOURNAL_VERSION} (starts with {first:?})",
            path.display()
        );
    }
    let (n, scene, _) = next("the scene line")?;
    let scene = scene
        .strip_prefix("scene ")
        .with_context(|| format!("{}:{n}: expected 'scene NAME'", path.display()))?
        .to_string();
    let mut journal = Journal {
        scene,
        config: String::new(),
        ticks: Vec::new(),
        commands: Vec::new(),
        end: None,
    };
    let mut stiffness: Option<(u64, f64)> = None;
    loop {
        let (n, line, last) = match next("its end") {
            Ok(l) => l,
            // A session killed before it closed the journal still replays what it has.
            Err(_) => return Ok(journal),
        };
        if let Some(c) = line
            .strip_prefix("config ")
            .or((line == "config").then_some(""))
        {
            journal.config.push_str(c);
            journal.config.push('\n');
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
            let command = serde_json::from_str(json)
                .with_context(|| format!("{}: the command is not JSON", at()))?;
            journal.commands.push(command);
            continue;
        }
        match fields.as_slice() {
            ["stiffness", tick, bits] => {
                let tick: u64 = tick
                    .parse()
                    .with_context(|| format!("{}: bad tick", at()))?;
                let raw = u64::from_str_radix(bits, 16)
                    .with_context(|| format!("{}: bad number {bits:?}", at()))?;
                let k = f64::from_bits(raw);
                if !(k.is_finite() && k > 0.0) {
                    bail!("{}: stiffness factor {k} is not a positive number", at());
                }
                stiffness = Some((tick, k));
            }
            ["tick", tick, rest @ ..] => {
                let tick: u64 = tick
                    .parse()
                    .with_context(|| format!("{}: bad tick", at()))?;
                let expected = journal.ticks.len() as u64 + 1;
                if tick != expected {
                    bail!("{}: tick {tick} where tick {expected} was expected", at());
                }
                let pose = match rest {
                    ["-"] => None,
                    bits if bits.len() == 7 => {
                        let mut v = [0.0; 7];
                        for (slot, b) in v.iter_mut().zip(bits) {
                            let raw = u64::from_str_radix(b, 16)
                                .with_context(|| format!("{}: bad number {b:?}", at()))?;
                            *slot = f64::from_bits(raw);
                        }
                        let q = Quaternion::new(v[3], v[4], v[5], v[6]);
                        Some(ToolPose {
                            tip_m: Vec3::new(v[0], v[1], v[2]),
                            orientation: UnitQuaternion::new_unchecked(q),
                        })
                    }
                    _ => bail!("{}: expected '-' or seven numbers after the tick", at()),
                };
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

/// Plays the journal's inputs through a fresh simulation of `scene`; returns the state hash
/// at the end.
pub fn replay(scene: &BuiltScene, journal: &Journal) -> u64 {
    let mut sim = Simulation::new(scene);
    // As the station does before its threads start (the masses it plans depend on the
    // material then, before any stiffness fault).
    sim.prepare(crate::station::SIM_TICK_S);
    for r in &journal.ticks {
        if let Some(k) = r.stiffness {
            sim.set_stiffness_factor(k);
        }
        sim.set_tool(r.pose);
        sim.tick(crate::station::SIM_TICK_S, &mut Unobserved);
    }
    sim.state_hash()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_killed_session_reads_up_to_its_last_complete_line() {
        let dir = std::env::temp_dir().join(format!("scalpel-journal-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("cut.journal");
        let mut text = header("liver", "station = \"a\"\n\n[device]\n").into_bytes();
        let pose = ToolPose::pointing(Vec3::new(0.01, -0.02, 0.03), Vec3::z());
        write_record(
            &mut text,
            &TickRecord {
                tick: 1,
                pose: None,
                stiffness: None,
            },
        )
        .unwrap();
        write_record(
            &mut text,
            &TickRecord {
                tick: 2,
                pose: Some(pose),
                stiffness: Some(1.5),
            },
        )
        .unwrap();
        text.extend_from_slice(
            command_line(&serde_json::json!({"by": "ann", "seq": 1})).as_bytes(),
        );
        let whole = text.len();
        write_record(
            &mut text,
            &TickRecord {
                tick: 3,
                pose: Some(pose),
                stiffness: None,
            },
        )
        .unwrap();
        // Cut in the middle of the last number, as a kill mid-flush would.
        text.truncate(whole + 40);
        std::fs::write(&path, &text).unwrap();
        let j = read(&path).unwrap();
        assert_eq!(j.ticks.len(), 2);
        assert_eq!(j.ticks[1].pose, Some(pose));
        assert_eq!(j.ticks[1].stiffness, Some(1.5));
        assert_eq!(j.commands, vec![serde_json::json!({"by": "ann", "seq": 1})]);
        assert_eq!(j.config, "station = \"a\"\n\n[device]\n");
        assert_eq!(j.end, None);
        // A bad line that is not the last is an error naming the line.
        let mut text = header("liver", "station = \"a\"\n\n[device]\n").into_bytes();
        text.extend_from_slice(b"tick 1 zz\ntick 2 -\n");
        std::fs::write(&path, &text).unwrap();
        let e = read(&path).unwrap_err().to_string();
        assert!(e.contains("cut.journal:6"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
