//! The simulation ticks' wall times as a fixed histogram: kept by the simulation thread
//! without allocating, read as quantiles by the status line and the summary.

use serde::ser::SerializeStruct;

/// Width of a bin (ms).
pub const TICK_BIN_MS: f64 = 0.02;
/// Bins: 0 to 5.1 ms in [`TICK_BIN_MS`] steps; the last one holds every longer tick.
pub const TICK_BINS: usize = 256;

/// How many ticks took how long, since the start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickTimes {
    bins: [u32; TICK_BINS],
    ticks: u64,
}

impl Default for TickTimes {
    fn default() -> Self {
        Self {
            bins: [0; TICK_BINS],
            ticks: 0,
        }
    }
}

impl TickTimes {
    /// Counts a tick of `ms` milliseconds.
    pub fn record(&mut self, ms: f64) {
        // NaN and negatives (a clock read out of order) count in the first bin.
        let bin = ((ms.max(0.0) / TICK_BIN_MS) as usize).min(TICK_BINS - 1);
        self.bins[bin] = self.bins[bin].saturating_add(1);
        self.ticks += 1;
    }

    /// The time that a fraction `q` of the ticks took at most (ms): the upper edge of the
    /// bin where that fraction is reached, so at most [`TICK_BIN_MS`] over the exact
    /// quantile; `None` with no tick, and for a quantile in the last bin (over 5.1 ms:
    /// read the longest tick).
    pub fn quantile_ms(&self, q: f64) -> Option<f64> {
        if self.ticks == 0 {
            return None;
        }
        let wanted = (q.clamp(0.0, 1.0) * self.ticks as f64).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        for (i, &n) in self.bins.iter().enumerate() {
            seen += u64::from(n);
            if seen >= wanted {
                return (i + 1 < TICK_BINS).then(|| (i + 1) as f64 * TICK_BIN_MS);
            }
        }
        None
    }
}

/// As its quantiles (p50, p99, p99.9 in ms; null beyond the histogram's range).
impl serde::Serialize for TickTimes {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut out = s.serialize_struct("TickTimes", 3)?;
        out.serialize_field("p50_ms", &self.quantile_ms(0.5))?;
        out.serialize_field("p99_ms", &self.quantile_ms(0.99))?;
        out.serialize_field("p999_ms", &self.quantile_ms(0.999))?;
        out.end()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_read_to_a_bin() {
        let mut t = TickTimes::default();
        assert_eq!(t.quantile_ms(0.5), None);
        // 990 ticks of 0.31 ms, 9 of 0.95 ms, 1 of 20 ms.
        (0..990).for_each(|_| t.record(0.31));
        (0..9).for_each(|_| t.record(0.95));
        t.record(20.0);
        let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-9;
        assert!(close(t.quantile_ms(0.5), 0.32), "{:?}", t.quantile_ms(0.5));
        assert!(close(t.quantile_ms(0.99), 0.32));
        assert!(close(t.quantile_ms(0.999), 0.96));
        // The longest is beyond the histogram.
        assert_eq!(t.quantile_ms(1.0), None);
        // NaN and negative times count, in the first bin.
        t.record(f64::NAN);
        t.record(-1.0);
        assert_eq!(t.bins[0], 2);
        let json = serde_json::to_value(t).unwrap();
        assert!(json["p999_ms"].as_f64().is_some(), "{json}");
    }
}
