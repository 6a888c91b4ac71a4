//! What a station admits of a scene: its memory and its tick, as estimated before the scene
//! is built (`scalpel_sim::scene::footprint`), against the configuration's `[limits]`.
//!
//! Issue 45: `target_points = 3900000` (inside the documented limit of 4 000 000) took 17.8 GB,
//! locked, of a 24 GB host for 265 s and never ticked. The estimate comes from the surface
//! alone, in milliseconds, so a scene over the budget is refused before anything big is
//! allocated, with what to change.

use scalpel_sim::scene::footprint::{Footprint, MEMORY_PER_POINT_BYTES};

use crate::config::LimitsConfig;

/// The host's memory when /proc/meminfo cannot be read (bytes): a small lab machine's.
const HOST_MEMORY_FALLBACK_BYTES: u64 = 8 << 30;

/// The budget.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneBudget {
    /// Most memory (bytes).
    pub memory_bytes: u64,
    /// Where the memory budget comes from: `None` for `limits.memory_mb`, the host's
    /// memory for the default (half of it).
    pub host_memory_bytes: Option<u64>,
    /// Most wall time per simulated time of a whole-body tick; `None`: not checked (a
    /// replay runs at its own pace).
    pub max_slowdown: Option<f64>,
}

/// The host's memory (MemTotal, bytes).
pub fn host_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

impl SceneBudget {
    /// The station's budget from its configuration.
    pub fn station(limits: &LimitsConfig) -> Self {
        Self {
            max_slowdown: Some(limits.max_slowdown),
            ..Self::memory_only(limits)
        }
    }

    /// Only the memory part (what `scalpel replay` applies).
    pub fn memory_only(limits: &LimitsConfig) -> Self {
        if limits.memory_mb > 0.0 {
            return Self {
                memory_bytes: (limits.memory_mb * (1u64 << 20) as f64) as u64,
                host_memory_bytes: None,
                max_slowdown: None,
            };
        }
        let host = host_memory_bytes().unwrap_or(HOST_MEMORY_FALLBACK_BYTES);
        Self {
            memory_bytes: host / 2,
            host_memory_bytes: Some(host),
            max_slowdown: None,
        }
    }

    /// The budget in words, for messages and `--check`.
    pub fn describe(&self) -> String {
        let memory = match self.host_memory_bytes {
            Some(host) => format!(
                "{:.0} MB (half of the host's {:.0} MB; limits.memory_mb sets it)",
                mb(self.memory_bytes),
                mb(host)
            ),
            None => format!("{:.0} MB (limits.memory_mb)", mb(self.memory_bytes)),
        };
        match self.max_slowdown {
            Some(s) => {
                format!("memory {memory}, tick at most {s}× real time (limits.max_slowdown)")
            }
            None => format!("memory {memory}"),
        }
    }

    /// Refuses `footprint` of `scene` when it is over the budget, saying what to change.
    pub fn check(&self, scene: &str, f: &Footprint) -> Result<(), String> {
        if f.memory_bytes > self.memory_bytes {
            let fitting = (self
                .memory_bytes
                .saturating_sub(f.memory_bytes - f.points as u64 * MEMORY_PER_POINT_BYTES)
                / MEMORY_PER_POINT_BYTES) as usize;
            return Err(format!(
                "scene {scene} would take about {:.0} MB ({} points, {} triangles), over this station's {}: sample fewer points ([sampling] target_points or spacing_mm; about {} would fit) or raise limits.memory_mb",
                f.memory_mb(),
                f.points,
                f.triangles,
                self.describe_memory(),
                fitting
            ));
        }
        if let (Some(most), Some(slowdown), Some(tick)) = (self.max_slowdown, f.slowdown(), f.tick)
            && slowdown > most
        {
            return Err(format!(
                "scene {scene}'s whole-body tick would take about {:.1} ms for each 1 ms it simulates ({} points × {} sub-steps), over limits.max_slowdown = {most}: the tissue would trail the hand {:.0} times over; sample fewer points ([sampling] real_time_points, target_points or spacing_mm) or raise limits.max_slowdown",
                tick.wall_s * 1e3,
                f.points,
                tick.substeps,
                slowdown
            ));
        }
        Ok(())
    }

    fn describe_memory(&self) -> String {
        match self.host_memory_bytes {
            Some(host) => format!(
                "limit of {:.0} MB (half of the host's {:.0} MB)",
                mb(self.memory_bytes),
                mb(host)
            ),
            None => format!(
                "limit of {:.0} MB (limits.memory_mb)",
                mb(self.memory_bytes)
            ),
        }
    }
}

fn mb(bytes: u64) -> f64 {
    bytes as f64 / (1u64 << 20) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use scalpel_sim::scene::footprint::TickEstimate;

    fn footprint(points: usize, memory_mb: u64, wall_ms: f64) -> Footprint {
        Footprint {
            points,
            triangles: 508,
            spacing_m: 1e-3,
            memory_bytes: memory_mb << 20,
            tick: Some(TickEstimate {
                substeps: 4,
                wall_s: wall_ms * 1e-3,
            }),
        }
    }

    #[test]
    fn a_scene_over_the_memory_or_the_tick_is_refused_with_what_to_change() {
        let budget = SceneBudget::station(&LimitsConfig {
            memory_mb: 1024.0,
            max_slowdown: 10.0,
        });
        budget.check("ok", &footprint(2000, 100, 3.0)).unwrap();
        let e = budget
            .check("big", &footprint(3_900_000, 23_000, 1900.0))
            .unwrap_err();
        assert!(
            e.contains("about 23000 MB")
                && e.contains("limit of 1024 MB (limits.memory_mb)")
                && e.contains("target_points"),
            "{e}"
        );
        let e = budget
            .check("slow", &footprint(300_000, 900, 150.0))
            .unwrap_err();
        assert!(
            e.contains("150.0 ms") && e.contains("limits.max_slowdown = 10"),
            "{e}"
        );
        // A replay checks the memory only.
        SceneBudget::memory_only(&LimitsConfig {
            memory_mb: 1024.0,
            max_slowdown: 10.0,
        })
        .check("slow", &footprint(300_000, 900, 150.0))
        .unwrap();
    }

    #[test]
    fn the_default_is_half_of_the_host() {
        let b = SceneBudget::station(&LimitsConfig::default());
        let host = b.host_memory_bytes.unwrap();
        assert_eq!(b.memory_bytes, host / 2);
        assert!(
            b.describe().contains("half of the host's"),
            "{}",
            b.describe()
        );
    }
}
