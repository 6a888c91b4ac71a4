//! Medians, tails and maxima of measured samples, through one HDR histogram (hdrhistogram)
//! for every report of the tools: three significant digits, the largest value kept exact.

use hdrhistogram::Histogram;
use serde::Serialize;

/// Samples are recorded as integers of this many per unit (a millisecond's sample to the
/// nanosecond, a second's to the microsecond): below three significant digits for every
/// figure the tools report.
const PER_UNIT: f64 = 1e6;

/// Median, 99th percentile and largest of a sample, in the samples' unit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Quantiles {
    /// Samples.
    pub n: usize,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest (exact).
    pub max: f64,
}

impl Quantiles {
    /// Of `samples` (non-negative; a negative one counts as zero); `None` when empty.
    pub fn of(samples: &[f64]) -> Option<Self> {
        if samples.is_empty() {
            return None;
        }
        let mut h = Histogram::<u64>::new(3).expect("three significant digits");
        let mut max = f64::NEG_INFINITY;
        for &v in samples {
            let v = if v.is_finite() { v.max(0.0) } else { 0.0 };
            max = max.max(v);
            // (Auto-resizing: a value past the range grows it.)
            let _ = h.record((v * PER_UNIT).round() as u64);
        }
        let at = |q: f64| h.value_at_quantile(q) as f64 / PER_UNIT;
        Some(Self {
            n: samples.len(),
            p50: at(0.5),
            p99: at(0.99).min(max),
            max,
        })
    }

    /// [`Quantiles::of`], zeros for an empty sample.
    pub fn or_zero(samples: &[f64]) -> Self {
        Self::of(samples).unwrap_or_default()
    }
}

/// The median of `samples` (NaN when empty).
pub fn median(samples: &[f64]) -> f64 {
    Quantiles::of(samples).map_or(f64::NAN, |q| q.p50)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_agree_with_the_sorted_sample_to_three_digits() {
        let samples: Vec<f64> = (1..=1000).map(|k| k as f64 * 0.01).collect();
        let q = Quantiles::of(&samples).unwrap();
        assert_eq!(q.n, 1000);
        assert!((q.p50 - 5.0).abs() <= 5e-3, "{q:?}");
        assert!((q.p99 - 9.9).abs() <= 1e-2, "{q:?}");
        assert_eq!(q.max, 10.0);
        assert!(Quantiles::of(&[]).is_none());
        assert_eq!(Quantiles::or_zero(&[]), Quantiles::default());
        assert!((median(&[3.0, 1.0, 2.0]) - 2.0).abs() < 1e-3);
    }
}
