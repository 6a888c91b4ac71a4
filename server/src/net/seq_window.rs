//! Instructor sequence numbers, per connection, with a bounded replay window.
//!
//! TLS already stops a network attacker replaying a command (no 0-RTT, AEAD per packet);
//! `seq` guards against a client's own repeats and reorders. It used to be a high-water
//! mark per identity, over all its connections: one command with `seq = u64::MAX` locked
//! that instructor out until the station restarted (issue 45). Now each connection starts
//! afresh, and within one a `seq` is taken when it is above the highest taken so far (by
//! at most [`MAX_JUMP`]) or among the [`WINDOW`] below it and not taken yet — the
//! anti-replay window of IPsec (RFC 4303 §3.4.3).

/// How far below the highest taken `seq` a late one is still taken (if not used).
pub const WINDOW: u64 = 64;

/// How far above the highest taken `seq` the next may jump: a client counts up; a jump of
/// more would let one command use up the rest of the numbering.
pub const MAX_JUMP: u64 = 1 << 32;

/// The sequence numbers one connection has used.
#[derive(Debug, Clone, Default)]
pub struct SeqWindow {
    /// The highest taken, if any.
    highest: Option<u64>,
    /// Bit `k`: `highest - k` was taken.
    taken: u64,
}

impl SeqWindow {
    /// Whether `seq` may be taken now; the reason when it may not. Nothing changes: a
    /// command the station refuses leaves its `seq` usable ([`SeqWindow::take`] after).
    pub fn check(&self, seq: u64) -> Result<(), String> {
        let Some(highest) = self.highest else {
            return Ok(());
        };
        if seq > highest {
            if seq - highest > MAX_JUMP {
                return Err(format!(
                    "seq {seq} jumps more than {MAX_JUMP} above {highest}, the highest this connection used (count up by one)"
                ));
            }
            return Ok(());
        }
        let back = highest - seq;
        if back >= WINDOW {
            return Err(format!(
                "seq {seq} is {back} below {highest}, the highest this connection used: outside the window of {WINDOW} (a replayed or reordered command)"
            ));
        }
        if self.taken & (1 << back) != 0 {
            return Err(format!(
                "seq {seq} was already used on this connection (a replayed command)"
            ));
        }
        Ok(())
    }

    /// Marks `seq` taken (after [`SeqWindow::check`] passed and the station carried it out).
    pub fn take(&mut self, seq: u64) {
        match self.highest {
            None => {
                self.highest = Some(seq);
                self.taken = 1;
            }
            Some(h) if seq > h => {
                let shift = seq - h;
                self.taken = if shift >= WINDOW {
                    0
                } else {
                    self.taken << shift
                } | 1;
                self.highest = Some(seq);
            }
            Some(h) if h - seq < WINDOW => self.taken |= 1 << (h - seq),
            Some(_) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn taken(w: &mut SeqWindow, seq: u64) -> Result<(), String> {
        w.check(seq)?;
        w.take(seq);
        Ok(())
    }

    #[test]
    fn counting_up_is_taken_and_a_repeat_is_not() {
        let mut w = SeqWindow::default();
        for seq in 1..200 {
            taken(&mut w, seq).unwrap();
        }
        let e = taken(&mut w, 150).unwrap_err();
        assert!(e.contains("already used"), "{e}");
        let e = taken(&mut w, 100).unwrap_err();
        assert!(e.contains("outside the window"), "{e}");
    }

    #[test]
    fn late_numbers_inside_the_window_are_taken_once() {
        let mut w = SeqWindow::default();
        taken(&mut w, 1000).unwrap();
        taken(&mut w, 1010).unwrap();
        // Skipped ones may come late, once each.
        taken(&mut w, 1005).unwrap();
        assert!(taken(&mut w, 1005).is_err());
        taken(&mut w, 1000 + WINDOW / 2).unwrap();
        taken(&mut w, 1001).unwrap();
        // Past the window once the highest moves on.
        taken(&mut w, 1010 + WINDOW).unwrap();
        assert!(taken(&mut w, 1009).is_err());
    }

    #[test]
    fn u64_max_first_ends_only_this_connections_numbering() {
        let mut w = SeqWindow::default();
        taken(&mut w, u64::MAX).unwrap();
        assert!(taken(&mut w, u64::MAX).is_err());
        taken(&mut w, u64::MAX - 1).unwrap();
        // A new connection starts afresh.
        let mut next = SeqWindow::default();
        taken(&mut next, 1).unwrap();
    }

    #[test]
    fn a_jump_to_the_top_is_refused_and_counting_goes_on() {
        let mut w = SeqWindow::default();
        taken(&mut w, 7).unwrap();
        let e = taken(&mut w, u64::MAX).unwrap_err();
        assert!(e.contains("jumps"), "{e}");
        taken(&mut w, 8).unwrap();
        taken(&mut w, 8 + MAX_JUMP).unwrap();
    }

    #[test]
    fn a_check_alone_uses_nothing() {
        let mut w = SeqWindow::default();
        taken(&mut w, 5).unwrap();
        w.check(6).unwrap();
        w.check(6).unwrap();
        taken(&mut w, 6).unwrap();
    }
}
