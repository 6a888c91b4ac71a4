//! Which remote commands are written out one by one (the station's log and the journal) and
//! which are only counted.
//!
//! Every command that changes something, and every refusal while an identity refuses at a
//! human pace, is written out: that is the lab's record of who did what. A client that
//! floods — an observer certificate scripted to send commands, which are all refused, or an
//! instructor past the rate limit — would otherwise write a line per command: fifteen such
//! clients wrote 6 MB of journal in 15 s. Past a burst, an identity's refusals are counted
//! and said once a second as one summary.
//!
//! Sans-IO: time comes in as station ticks (ms).

use std::collections::HashMap;

use crate::faults::TokenBucket;

/// Refusals an identity may have written out in a burst ...
pub const REFUSALS_BURST: f64 = 20.0;
/// ... and per second after it.
pub const REFUSALS_PER_S: f64 = 2.0;
/// Counted refusals are summarised at most this often per identity (station ticks).
pub const SUMMARY_EVERY_TICKS: u64 = 1000;

/// How a command is to be recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Record {
    /// Written out in full.
    Full,
    /// Counted; a later [`CommandAudit::summaries`] says how many.
    Counted,
}

/// Refusals from one identity that were counted, not written out.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Summary {
    /// Who sent them.
    pub by: String,
    /// How many.
    pub refused: u64,
    /// Station ticks of the first and the last of them.
    pub ticks: (u64, u64),
}

#[derive(Debug, Clone)]
struct Sender {
    bucket: TokenBucket,
    counted: u64,
    first_counted: u64,
    last_counted: u64,
    summarised_tick: u64,
}

/// The audit's state: one entry per identity that has sent a refused command (identities
/// are the lab CA's certificate names: a bounded set).
#[derive(Debug, Default)]
pub struct CommandAudit {
    senders: HashMap<String, Sender>,
}

impl CommandAudit {
    /// An audit that has seen nothing.
    pub fn new() -> Self {
        Self::default()
    }

    /// How to record a command from `by` at station tick `now` that was `refused` or not.
    pub fn record(&mut self, by: &str, refused: bool, now: u64) -> Record {
        if !refused {
            return Record::Full;
        }
        if !self.senders.contains_key(by) {
            // Once per identity: a flood's commands find their entry without allocating.
            self.senders.insert(
                by.to_string(),
                Sender {
                    bucket: TokenBucket::full(REFUSALS_PER_S, REFUSALS_BURST, now),
                    counted: 0,
                    first_counted: now,
                    last_counted: now,
                    summarised_tick: now,
                },
            );
        }
        let sender = self.senders.get_mut(by).expect("inserted above");
        if sender.bucket.take(now) {
            return Record::Full;
        }
        if sender.counted == 0 {
            sender.first_counted = now;
        }
        sender.counted += 1;
        sender.last_counted = now;
        Record::Counted
    }

    /// The counted refusals due to be said at station tick `now` (at most one summary per
    /// identity a second; `flush` says them all, at the end of a session).
    pub fn summaries(&mut self, now: u64, flush: bool) -> Vec<Summary> {
        let mut due = Vec::new();
        for (by, s) in &mut self.senders {
            if s.counted > 0
                && (flush || now.saturating_sub(s.summarised_tick) >= SUMMARY_EVERY_TICKS)
            {
                due.push(Summary {
                    by: by.clone(),
                    refused: s.counted,
                    ticks: (s.first_counted, s.last_counted),
                });
                s.counted = 0;
                s.summarised_tick = now;
            }
        }
        due.sort_by(|a, b| a.by.cmp(&b.by));
        due
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn what_changes_something_is_always_written_out() {
        let mut audit = CommandAudit::new();
        for k in 0..10_000 {
            assert_eq!(audit.record("ann", false, k / 100), Record::Full);
        }
        assert!(audit.summaries(1_000_000, true).is_empty());
    }

    #[test]
    fn a_flood_of_refusals_is_counted_past_its_burst_and_said_once_a_second() {
        let mut audit = CommandAudit::new();
        // 1000 refused commands a second for 5 s from one observer; a human pace (one every
        // two seconds) from another.
        let (mut full, mut counted) = (0, 0);
        let mut said = Vec::new();
        for now in 0..5000u64 {
            match audit.record("eve", true, now) {
                Record::Full => full += 1,
                Record::Counted => counted += 1,
            }
            if now % 2000 == 0 {
                assert_eq!(audit.record("obs1", true, now), Record::Full);
            }
            said.extend(audit.summaries(now, false));
        }
        // The burst, then two a second.
        assert!((20..=30).contains(&full), "{full}");
        assert_eq!(full + counted, 5000);
        assert!(said.iter().all(|s| s.by == "eve"));
        // Once a second, none lost.
        assert!((4..=5).contains(&said.len()), "{said:?}");
        let rest = audit.summaries(5000, true);
        let total: u64 = said.iter().chain(&rest).map(|s| s.refused).sum();
        assert_eq!(total, counted);
        for pair in said.windows(2) {
            assert!(pair[1].ticks.0 > pair[0].ticks.1);
        }
        // Quiet again, it writes out refusals one by one after the refill.
        assert_eq!(audit.record("eve", true, 20_000), Record::Full);
    }
}
