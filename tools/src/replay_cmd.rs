//! `scalpel replay FILE [--json] [--slowest N]`: plays a station journal through a fresh
//! simulation and compares the final state hash with the live run's, bit for bit; with
//! `--slowest`, the N ticks whose work took longest, stage by stage. Instructor commands in
//! the journal are listed with who sent them; their effects on the simulation (the poses it
//! got, the stiffness changes) are in the tick records, so the replay reproduces them.

use std::path::Path;

use anyhow::{Context, bail};
use scalpel_server::scene_budget::SceneBudget;
use scalpel_server::station::stages_text;
use scalpel_server::{journal, scene_file};
use scalpel_sim::pipeline::{
    NoClock, SIMULATION_TICK_S as SIM_TICK_S, StageClock, StageTimes, TickReport,
};

use crate::cutrun::WallClock;

/// Replays `file`.
pub fn run(file: &Path, json: bool, slowest: Option<usize>) -> anyhow::Result<()> {
    let recorded = journal::read(file)?;
    // The memory budget the station had (a replay runs at its own pace: no tick budget).
    let (scene, _) = scene_file::load_station_scene_within(
        &recorded.scene,
        &SceneBudget::memory_only(&recorded.limits()),
    )
    .with_context(|| format!("{}: the scene it names", file.display()))?;
    let mut timing = Timing::new(slowest.unwrap_or(0));
    // Unless asked, no clock: a plain replay reads none.
    let (mut wall, mut no_clock) = (WallClock::default(), NoClock);
    let clock: &mut dyn StageClock = if slowest.is_some() {
        &mut wall
    } else {
        &mut no_clock
    };
    let hash = journal::replay_with(&scene, &recorded, clock, |k, report, _| {
        timing.add(k, report);
    });
    if let Some((ticks, _)) = recorded.end
        && ticks != recorded.ticks.len() as u64
    {
        bail!(
            "{}: the journal closes with {ticks} ticks but holds {}",
            file.display(),
            recorded.ticks.len()
        );
    }
    let live = recorded.end.map(|(_, h)| h);
    let identical = live.is_some_and(|h| h == hash);
    if json {
        println!(
            "{}",
            serde_json::json!({
                "scene": recorded.scene,
                "config": recorded.config,
                "ticks": recorded.ticks.len(),
                "commands": recorded.commands,
                "stiffness_changes": recorded.ticks.iter().filter(|t| t.stiffness.is_some()).count(),
                "state_hash": format!("{hash:016x}"),
                "live_state_hash": live.map(|h| format!("{h:016x}")),
                "identical": identical,
                "slowest": slowest.map(|_| timing.json()),
            })
        );
    } else {
        for c in &recorded.commands {
            println!("{}", command_text(c));
        }
        println!(
            "replayed {} ticks of {}: state hash {hash:016x}",
            recorded.ticks.len(),
            recorded.scene
        );
        match live {
            Some(h) if identical => println!("identical to the live run ({h:016x})"),
            Some(h) => println!("DIFFERENT from the live run ({h:016x})"),
            None => println!("the journal was not closed (no live hash to compare)"),
        }
        if slowest.is_some() {
            timing.print();
        }
    }
    if live.is_some() && !identical {
        bail!("the replay's state differs from the live run's");
    }
    Ok(())
}

/// The replay's slowest ticks: the simulation's own work for each input, with nothing
/// else on the machine's cores that the station has (its haptic thread, its re-cut worker,
/// its writers). A re-cut runs inline here, in the tick that lands it.
struct Timing {
    keep: usize,
    /// (journal index, the tick's stage times), slowest first.
    slowest: Vec<(usize, StageTimes)>,
    over_budget: usize,
}

impl Timing {
    fn new(keep: usize) -> Self {
        Self {
            keep,
            slowest: Vec::with_capacity(keep + 1),
            over_budget: 0,
        }
    }

    fn add(&mut self, k: usize, report: &TickReport) {
        let total = report.stages.total();
        self.over_budget += usize::from(total > SIM_TICK_S);
        let at = self.slowest.partition_point(|e| e.1.total() >= total);
        if at < self.keep {
            self.slowest.insert(at, (k, report.stages));
            self.slowest.truncate(self.keep);
        }
    }

    fn print(&self) {
        println!(
            "ticks over {} ms of work: {}; the slowest (re-cuts run inline in a replay):",
            SIM_TICK_S * 1e3,
            self.over_budget
        );
        for (k, stages) in &self.slowest {
            println!(
                "  tick {}: {:.3} ms ({})",
                k + 1,
                stages.total() * 1e3,
                stages_text(&stages.ms_by_stage())
            );
        }
    }

    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "ticks_over_budget": self.over_budget,
            "ticks": self.slowest.iter().map(|(k, stages)| serde_json::json!({
                "tick": k + 1,
                "ms": stages.total() * 1e3,
                "stages_ms": stages
                    .ms_by_stage()
                    .into_iter()
                    .filter(|(_, ms)| *ms > 0.0)
                    .map(|(name, ms)| (name.to_string(), serde_json::json!(ms)))
                    .collect::<serde_json::Map<String, serde_json::Value>>(),
            })).collect::<Vec<_>>(),
        })
    }
}

/// A journaled command as `scalpel replay` lists it.
fn command_text(c: &serde_json::Value) -> String {
    match c.get("refused_unrecorded") {
        // A flood the station counted rather than journaled one by one.
        Some(n) => format!(
            "{n} more commands by {} refused from station tick {} to {} (counted, not journaled one by one)",
            c["by"], c["first_station_tick"], c["last_station_tick"]
        ),
        None => format!(
            "command at station tick {} (simulation tick {}) by {}: {} -> {}",
            c["station_tick"], c["sim_tick"], c["by"], c["action"], c["outcome"]
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_and_counted_refusals_are_listed() {
        let command = serde_json::json!({
            "station_tick": 3935, "sim_tick": 3932, "by": "ann", "seq": 7,
            "action": "List", "outcome": "Listed",
        });
        assert_eq!(
            command_text(&command),
            r#"command at station tick 3935 (simulation tick 3932) by "ann": "List" -> "Listed""#
        );
        let counted = serde_json::json!({
            "station_tick": 5000, "sim_tick": 4990, "by": "obs2", "refused_unrecorded": 80,
            "first_station_tick": 4012, "last_station_tick": 4870,
        });
        assert_eq!(
            command_text(&counted),
            r#"80 more commands by "obs2" refused from station tick 4012 to 4870 (counted, not journaled one by one)"#
        );
    }
}
