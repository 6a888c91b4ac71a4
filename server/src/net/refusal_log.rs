//! Refused connections in the station's log: each said in full while they come at a human
//! pace, then — a flood — counted and summed up once a second by reason, so an attacker
//! cannot fill the log (the same rule as instructors' refused commands, command_audit.rs).
//! Sans-IO: time comes in as milliseconds since the endpoint started.

use std::collections::{BTreeMap, HashSet};
use std::net::IpAddr;

use super::admission::{Budgets, Refusal};
use crate::faults::TokenBucket;

/// Refusals said in full in a burst ...
pub const FULL_BURST: f64 = 10.0;
/// ... and per second after it.
pub const FULL_PER_S: f64 = 1.0;
/// Counted refusals are summed up at most this often (ms).
pub const SUMMARY_EVERY_MS: u64 = 1000;
/// Addresses remembered for a summary (a flood from more is said as "at least").
const MOST_ADDRESSES: usize = 1024;

/// The log's state.
#[derive(Debug)]
pub struct RefusalLog {
    budgets: Budgets,
    bucket: TokenBucket,
    counted: BTreeMap<Refusal, u64>,
    addresses: HashSet<IpAddr>,
    first_ms: u64,
    summarised_ms: u64,
    /// Retries sent since the last summary (said only with refusals: a Retry is routine).
    retries: u64,
}

impl RefusalLog {
    /// An empty log at `now_ms`.
    pub fn new(budgets: Budgets, now_ms: u64) -> Self {
        Self {
            budgets,
            bucket: TokenBucket::full(FULL_PER_S, FULL_BURST, now_ms),
            counted: BTreeMap::new(),
            addresses: HashSet::new(),
            first_ms: now_ms,
            summarised_ms: now_ms,
            retries: 0,
        }
    }

    /// A Retry was sent (counted for the next summary).
    pub fn retried(&mut self) {
        self.retries += 1;
    }

    /// `ip` was refused for `why` (with `detail`, e.g. TLS's error) at `now_ms`: the line
    /// to log, or `None` when it is counted for the next summary.
    pub fn refused(
        &mut self,
        now_ms: u64,
        ip: IpAddr,
        why: Refusal,
        detail: Option<&str>,
    ) -> Option<String> {
        if self.counted.is_empty() && self.bucket.take(now_ms) {
            return Some(format!(
                "network: refused {ip}: {}{}",
                why.describe(&self.budgets),
                detail.map_or(String::new(), |d| format!(": {d}"))
            ));
        }
        if self.counted.is_empty() {
            self.first_ms = now_ms;
        }
        *self.counted.entry(why).or_default() += 1;
        if self.addresses.len() < MOST_ADDRESSES {
            self.addresses.insert(ip);
        }
        None
    }

    /// The summary of what was counted, once [`SUMMARY_EVERY_MS`] has passed since the last
    /// (or at once with `last`, when the endpoint stops).
    pub fn summary(&mut self, now_ms: u64, last: bool) -> Option<String> {
        if self.counted.is_empty()
            || (!last && now_ms < self.summarised_ms.saturating_add(SUMMARY_EVERY_MS))
        {
            return None;
        }
        self.summarised_ms = now_ms;
        let total: u64 = self.counted.values().sum();
        let reasons: Vec<String> = self
            .counted
            .iter()
            .map(|(why, n)| format!("{n} {}", why.name()))
            .collect();
        let addresses = self.addresses.len();
        let line = format!(
            "network: {total} more connection attempts refused in {:.1} s ({}) from {}{addresses} address{}; {} Retry sent (a flood: counted, not said one by one)",
            now_ms.saturating_sub(self.first_ms) as f64 * 1e-3,
            reasons.join(", "),
            if addresses == MOST_ADDRESSES {
                "at least "
            } else {
                ""
            },
            if addresses == 1 { "" } else { "es" },
            self.retries,
        );
        self.counted.clear();
        self.addresses.clear();
        self.retries = 0;
        Some(line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn budgets() -> Budgets {
        Budgets {
            handshakes: 16,
            handshakes_per_address: 4,
            connections: 48,
            connections_per_address: 16,
        }
    }

    #[test]
    fn a_few_refusals_are_said_in_full_and_a_flood_is_summed_up() {
        let mut log = RefusalLog::new(budgets(), 0);
        let ip = IpAddr::from([127, 0, 0, 2]);
        let line = log
            .refused(5, ip, Refusal::Tls, Some("no client certificate"))
            .unwrap();
        assert_eq!(
            line,
            "network: refused 127.0.0.2: TLS handshake failed: no client certificate"
        );
        let mut said = 1;
        for k in 0..1000u64 {
            let ip = IpAddr::from([127, 0, 0, 2 + (k % 3) as u8]);
            said += usize::from(log.refused(10 + k, ip, Refusal::Handshakes, None).is_some());
        }
        assert_eq!(said, FULL_BURST as usize);
        assert_eq!(
            log.summary(500, false),
            None,
            "not before a second has passed"
        );
        let summary = log.summary(1010, false).unwrap();
        assert!(
            summary.starts_with("network: 991 more connection attempts refused")
                && summary.contains("991 handshake budget")
                && summary.contains("from 3 addresses"),
            "{summary}"
        );
        assert_eq!(log.summary(5000, true), None, "nothing left to say");
    }

    #[test]
    fn while_a_flood_is_counted_nothing_is_said_in_full() {
        let mut log = RefusalLog::new(budgets(), 0);
        let ip = IpAddr::from([10, 0, 0, 1]);
        for _ in 0..FULL_BURST as usize {
            assert!(log.refused(0, ip, Refusal::Timeout, None).is_some());
        }
        assert!(log.refused(0, ip, Refusal::Timeout, None).is_none());
        // Tokens come back, but the flood is still being counted: no line between.
        assert!(log.refused(3000, ip, Refusal::Timeout, None).is_none());
        log.retried();
        let s = log.summary(3000, false).unwrap();
        assert!(
            s.contains("2 handshake timed out") && s.contains("1 Retry"),
            "{s}"
        );
        assert!(log.refused(3001, ip, Refusal::Timeout, None).is_some());
    }
}
