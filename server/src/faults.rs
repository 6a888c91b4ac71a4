//! Instructor faults (docs/PROTOCOL.md, "Faults"): the book the main thread keeps — who
//! scheduled what, per-identity rate limits — and the fixed-size table
//! it hands the real-time threads through triple buffers. Each thread evaluates the table on
//! its own tick of the station clock (ms since the start), so a fault starts and ends on the
//! tick it was scheduled for, with no lock and no allocation on the real-time path.
//!
//! Sans-IO: time comes in as station ticks, so the book's rules are unit-tested here.

use std::collections::HashMap;

use scalpel_proto::wire::{
    Action, Command, Fault, FaultSpec, MAX_FAULT_MS, Outcome, ScheduledFault, Start,
};

/// Faults booked at once (scheduled or active).
pub const MAX_FAULTS: usize = 16;
/// Commands per second one identity may send, on average ...
pub const COMMANDS_PER_S: f64 = 10.0;
/// ... and in a burst.
pub const COMMAND_BURST: f64 = 20.0;
/// A ramped stiffness change is applied to the solver in steps of this much (relative):
/// each step re-derives the solver's constants, so every tick would be too many.
pub const STIFFNESS_STEP: f64 = 0.02;

/// The stiffness factor in effect stays within these, however many faults ask for one.
pub const MIN_STIFFNESS: f32 = 0.1;
/// See [`MIN_STIFFNESS`].
pub const MAX_STIFFNESS: f32 = 10.0;

/// A fault as the real-time threads see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultSlot {
    /// Its id.
    pub id: u64,
    /// What it does.
    pub fault: Fault,
    /// First station tick it is in effect.
    pub start_tick: u64,
    /// First station tick it is no longer in effect (`u64::MAX`: until cleared).
    pub end_tick: u64,
}

impl FaultSlot {
    fn active(&self, tick: u64) -> bool {
        (self.start_tick..self.end_tick).contains(&tick)
    }

    /// Ramp of a stiffness change, 0–1: in over `ramp_ms` from the start, out over `ramp_ms`
    /// from the end, down from where the ramp in had got to — continuous, and never rising
    /// again once ended (cleared halfway through a 60 s ramp in, the old `min(rise, fall)`
    /// climbed on for 30 s after the clear).
    fn ramp(&self, tick: u64, ramp_ms: u32) -> f64 {
        if tick < self.start_tick {
            return 0.0;
        }
        let ramp = f64::from(ramp_ms.max(1));
        let rise = |t: u64| ((t - self.start_tick) as f64 / ramp).min(1.0);
        if tick < self.end_tick {
            return rise(tick);
        }
        let end = self.end_tick.max(self.start_tick);
        let fall = ((end as f64 + ramp - tick as f64) / ramp).clamp(0.0, 1.0);
        rise(end) * fall
    }

    /// The last tick it has any effect on (a stiffness change ramps out after its end).
    fn expires_tick(&self) -> u64 {
        match self.fault {
            Fault::TissueStiffness { ramp_ms, .. } => {
                self.end_tick.saturating_add(u64::from(ramp_ms.max(1)))
            }
            _ => self.end_tick,
        }
    }
}

/// Every booked fault, for the real-time threads (`Copy`: it goes through triple buffers).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FaultTable {
    /// The faults; empty slots are `None`.
    pub slots: [Option<FaultSlot>; MAX_FAULTS],
}

/// What the faults do to the haptic thread on one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HapticEffects {
    /// Device samples are dropped.
    pub dropout: bool,
    /// Device samples are held back this long (s).
    pub latency_s: f64,
    /// Gaussian noise on the device position, per axis (m).
    pub noise_sigma_m: f64,
    /// Added to the requested force, along it (N).
    pub spike_n: f64,
    /// The force is capped here (N; infinite: no cap but the device's).
    pub cap_n: f64,
}

/// What the faults do to the simulation thread on one tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimEffects {
    /// No simulation tick.
    pub stall: bool,
    /// Wall time per simulated time (1: real time).
    pub slowdown: f64,
    /// Factor on the tissue's stiffness.
    pub stiffness: f64,
    /// No render frames.
    pub renderer_freeze: bool,
}

impl FaultTable {
    fn active(&self, tick: u64) -> impl Iterator<Item = &FaultSlot> {
        self.slots.iter().flatten().filter(move |s| s.active(tick))
    }

    /// The haptic thread's effects at station tick `tick`. Several faults of a kind combine
    /// as the worst of them (the spikes add up).
    pub fn haptic(&self, tick: u64) -> HapticEffects {
        let mut e = HapticEffects {
            dropout: false,
            latency_s: 0.0,
            noise_sigma_m: 0.0,
            spike_n: 0.0,
            cap_n: f64::INFINITY,
        };
        for s in self.active(tick) {
            match s.fault {
                Fault::DeviceDropout => e.dropout = true,
                Fault::DeviceLatency { ms } => e.latency_s = e.latency_s.max(f64::from(ms) * 1e-3),
                Fault::PoseNoise { sigma_mm } => {
                    e.noise_sigma_m = e.noise_sigma_m.max(f64::from(sigma_mm) * 1e-3);
                }
                Fault::ForceSpike { newtons } => e.spike_n += f64::from(newtons),
                Fault::ForceSaturation { max_n } => e.cap_n = e.cap_n.min(f64::from(max_n)),
                _ => {}
            }
        }
        e
    }

    /// The simulation thread's effects at station tick `tick`.
    pub fn sim(&self, tick: u64) -> SimEffects {
        let mut e = SimEffects {
            stall: false,
            slowdown: 1.0,
            stiffness: 1.0,
            renderer_freeze: false,
        };
        for s in self.slots.iter().flatten() {
            if let Fault::TissueStiffness { factor, ramp_ms } = s.fault {
                // Several at once multiply, within the range one may ask for (clamped
                // below): stacked faults must not make the solver's step vanish.
                let w = s.ramp(tick, ramp_ms);
                e.stiffness *= 1.0 + (f64::from(factor) - 1.0) * w;
                continue;
            }
            if !s.active(tick) {
                continue;
            }
            match s.fault {
                Fault::SimStall => e.stall = true,
                Fault::SimSlowdown { factor } => e.slowdown = e.slowdown.max(f64::from(factor)),
                Fault::RendererFreeze => e.renderer_freeze = true,
                _ => {}
            }
        }
        e.stiffness = e
            .stiffness
            .clamp(f64::from(MIN_STIFFNESS), f64::from(MAX_STIFFNESS));
        e
    }

    /// Observers get no frames or metrics at station tick `tick`.
    pub fn stream_lost(&self, tick: u64) -> bool {
        self.active(tick)
            .any(|s| matches!(s.fault, Fault::ObserverStreamLoss))
    }
}

/// The stiffness factor to give the simulation, which runs with `current`, when the faults
/// ask for `target` now and asked for `previous` a tick ago: the target once it is a step
/// away, or once the ramp has settled (exact at the end of a ramp); `None`: keep `current`.
pub fn stiffness_to_apply(current: f64, target: f64, previous: f64) -> Option<f64> {
    let settled = target == previous;
    let step = ((target / current) - 1.0).abs() >= STIFFNESS_STEP;
    (target != current && (settled || step)).then_some(target)
}

/// A fault in the book.
#[derive(Debug, Clone)]
struct Booked {
    slot: FaultSlot,
    spec: FaultSpec,
    by: String,
    applied: bool,
    /// Cleared before it started.
    cancelled: bool,
}

/// One identity's command state (its sequence numbers are its connections': `net::seq_window`).
#[derive(Debug, Clone)]
struct Client {
    bucket: TokenBucket,
}

/// A token bucket on the station clock: `burst` tokens, refilled at `per_s` a second; the
/// command rate limit here and the refusal audit (command_audit.rs) each keep one per
/// identity.
#[derive(Debug, Clone, Copy)]
pub struct TokenBucket {
    tokens: f64,
    refilled_tick: u64,
    per_s: f64,
    burst: f64,
}

impl TokenBucket {
    /// A full bucket at station tick `now`.
    pub fn full(per_s: f64, burst: f64, now: u64) -> Self {
        Self {
            tokens: burst,
            refilled_tick: now,
            per_s,
            burst,
        }
    }

    /// Takes a token at station tick `now`, after the refill since the last call; `false`
    /// when there is none.
    pub fn take(&mut self, now: u64) -> bool {
        let elapsed_s = now.saturating_sub(self.refilled_tick) as f64 * 1e-3;
        self.tokens = (self.tokens + elapsed_s * self.per_s).min(self.burst);
        self.refilled_tick = now;
        let took = self.tokens >= 1.0;
        if took {
            self.tokens -= 1.0;
        }
        took
    }
}

/// Something the station reports about a fault.
#[derive(Debug, Clone, PartialEq)]
pub enum Transition {
    /// It took effect.
    Applied(String),
    /// It ended (its time was up or it was cleared).
    Ended(String),
}

/// The main thread's record of faults and of who asked for them.
#[derive(Debug, Default)]
pub struct FaultBook {
    next_id: u64,
    booked: Vec<Booked>,
    clients: HashMap<String, Client>,
}

/// How a fault reads in events and logs.
fn describe(b: &Booked) -> String {
    let until = if b.slot.end_tick == u64::MAX {
        "until cleared".to_string()
    } else {
        format!("until tick {}", b.slot.end_tick)
    };
    format!(
        "fault {} {} {:?} by {} ({until})",
        b.slot.id,
        b.spec.fault.kind(),
        b.spec.fault,
        b.by
    )
}

impl FaultBook {
    /// An empty book.
    pub fn new() -> Self {
        Self {
            next_id: 1,
            ..Self::default()
        }
    }

    /// Carries out `command` from the instructor `by` at station tick `now`. Returns the
    /// outcome, and the list for `List`. A command is refused when the identity is over its
    /// rate, or when its parameters are out of range. (Its `seq` was checked by its
    /// connection, `net::seq_window`.)
    pub fn command(
        &mut self,
        by: &str,
        command: &Command,
        now: u64,
    ) -> (Outcome, Option<Vec<ScheduledFault>>) {
        let rejected = |reason: String| (Outcome::Rejected { reason }, None);
        let client = self.clients.entry(by.to_string()).or_insert(Client {
            bucket: TokenBucket::full(COMMANDS_PER_S, COMMAND_BURST, now),
        });
        // Every command costs a token, refused ones too (a flood is a flood).
        if !client.bucket.take(now) {
            return rejected(format!(
                "rate limit: at most {COMMANDS_PER_S} commands a second (bursts of {COMMAND_BURST}) per identity"
            ));
        }
        let result = match &command.action {
            Action::Schedule(spec) => self.schedule(by, spec, now),
            Action::Clear { id } => self.clear(*id, now),
            Action::List => Ok((Outcome::Listed, Some(self.list(now)))),
        };
        result.unwrap_or_else(rejected)
    }

    fn schedule(
        &mut self,
        by: &str,
        spec: &FaultSpec,
        now: u64,
    ) -> Result<(Outcome, Option<Vec<ScheduledFault>>), String> {
        spec.fault.check()?;
        let start = match spec.start {
            Start::Now => now,
            Start::AtTick(t) if t < now => {
                return Err(format!(
                    "tick {t} has passed (the station is at tick {now})"
                ));
            }
            Start::AtTick(t) if t - now > MAX_FAULT_MS => {
                return Err(format!(
                    "tick {t} is more than an hour ahead (the station is at tick {now})"
                ));
            }
            Start::AtTick(t) => t,
        };
        if u64::from(spec.duration_ms) > MAX_FAULT_MS {
            return Err(format!(
                "duration_ms {} is over an hour ({MAX_FAULT_MS})",
                spec.duration_ms
            ));
        }
        if self.booked.len() >= MAX_FAULTS {
            // Ended but still acting: a stiffness change ramping out. (A fault whose effect
            // is over waits for the next `advance` to leave the book: at most 10 ms.)
            let ramping: Vec<u64> = self
                .booked
                .iter()
                .filter(|b| !b.cancelled && b.slot.end_tick <= now && now < b.slot.expires_tick())
                .map(|b| b.slot.expires_tick() - now)
                .collect();
            let ramping = match ramping.iter().min() {
                Some(soonest) => format!(
                    " ({} of them stiffness changes ramping out, the first free in {soonest} ms)",
                    ramping.len()
                ),
                None => String::new(),
            };
            return Err(format!(
                "{MAX_FAULTS} faults are booked already{ramping}: clear some first"
            ));
        }
        let id = self.next_id;
        self.next_id += 1;
        let end_tick = match spec.duration_ms {
            0 => u64::MAX,
            d => start + u64::from(d),
        };
        self.booked.push(Booked {
            slot: FaultSlot {
                id,
                fault: spec.fault,
                start_tick: start,
                end_tick,
            },
            spec: spec.clone(),
            by: by.to_string(),
            applied: false,
            cancelled: false,
        });
        Ok((Outcome::Scheduled { id }, None))
    }

    fn clear(
        &mut self,
        id: Option<u64>,
        now: u64,
    ) -> Result<(Outcome, Option<Vec<ScheduledFault>>), String> {
        let mut count = 0;
        for b in &mut self.booked {
            if id.is_none_or(|id| b.slot.id == id) && b.slot.end_tick > now && !b.cancelled {
                if b.slot.start_tick > now {
                    // Never starts.
                    b.cancelled = true;
                    b.slot.end_tick = b.slot.start_tick;
                } else {
                    // Ends now: the next `advance` reports it (a stiffness change ramps
                    // out).
                    b.slot.end_tick = now;
                }
                count += 1;
            }
        }
        if count == 0
            && let Some(id) = id
        {
            return Err(format!("no fault {id} is scheduled or active"));
        }
        Ok((Outcome::Cleared { count }, None))
    }

    /// The booked faults at station tick `now`, each with the start the station gave it and,
    /// once its end is known (cleared, or its time up), the duration it had: a cleared
    /// "until cleared" fault is not listed as such. `active`: it acts now — a stiffness
    /// change ramping out after its end included (it still holds its place in the book).
    pub fn list(&self, now: u64) -> Vec<ScheduledFault> {
        self.booked
            .iter()
            .map(|b| {
                let mut spec = b.spec.clone();
                spec.start = Start::AtTick(b.slot.start_tick);
                if b.slot.end_tick <= now && !b.cancelled {
                    // At least 1: 0 means "until cleared" (a fault cleared on its first tick).
                    spec.duration_ms = u32::try_from(b.slot.end_tick - b.slot.start_tick)
                        .unwrap_or(u32::MAX)
                        .max(1);
                }
                ScheduledFault {
                    id: b.slot.id,
                    spec,
                    by: b.by.clone(),
                    active: (b.slot.start_tick..b.slot.expires_tick()).contains(&now)
                        && !b.cancelled,
                }
            })
            .collect()
    }

    /// Moves the book to station tick `now`: reports the faults that took effect or ended
    /// since the last call, and drops those that have no effect left.
    pub fn advance(&mut self, now: u64) -> Vec<Transition> {
        let mut out = Vec::new();
        self.booked.retain_mut(|b| {
            if b.cancelled {
                out.push(Transition::Ended(format!(
                    "{} cleared before it started",
                    describe(b)
                )));
                return false;
            }
            if !b.applied && b.slot.active(now) {
                b.applied = true;
                out.push(Transition::Applied(describe(b)));
            }
            if now >= b.slot.end_tick {
                if !b.applied {
                    // Too short for the book to see it active: it still happened.
                    out.push(Transition::Applied(describe(b)));
                    b.applied = true;
                }
                if now >= b.slot.expires_tick() {
                    out.push(Transition::Ended(format!("{} ended", describe(b))));
                    return false;
                }
            }
            true
        });
        out
    }

    /// The table for the real-time threads.
    pub fn table(&self) -> FaultTable {
        let mut table = FaultTable::default();
        for (slot, b) in table.slots.iter_mut().zip(&self.booked) {
            *slot = Some(b.slot);
        }
        table
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn schedule(seq: u64, fault: Fault, start: Start, duration_ms: u32) -> Command {
        Command {
            seq,
            action: Action::Schedule(FaultSpec {
                fault,
                start,
                duration_ms,
            }),
        }
    }

    #[test]
    fn a_fault_is_in_effect_from_its_start_tick_to_its_end() {
        let mut book = FaultBook::new();
        let (o, _) = book.command(
            "ann",
            &schedule(
                1,
                Fault::DeviceLatency { ms: 20.0 },
                Start::AtTick(1500),
                250,
            ),
            1000,
        );
        assert_eq!(o, Outcome::Scheduled { id: 1 });
        let t = book.table();
        assert_eq!(t.haptic(1499).latency_s, 0.0);
        assert_eq!(t.haptic(1500).latency_s, 0.02);
        assert_eq!(t.haptic(1749).latency_s, 0.02);
        assert_eq!(t.haptic(1750).latency_s, 0.0);
        assert!(book.advance(1499).is_empty());
        assert!(matches!(book.advance(1500)[..], [Transition::Applied(_)]));
        assert!(matches!(book.advance(1750)[..], [Transition::Ended(_)]));
        assert!(book.list(1750).is_empty());
    }

    #[test]
    fn flooding_and_bad_commands_are_refused() {
        let mut book = FaultBook::new();
        let spike = Fault::ForceSpike { newtons: 5.0 };
        assert!(matches!(
            book.command("ann", &schedule(5, spike, Start::Now, 10), 0)
                .0,
            Outcome::Scheduled { .. }
        ));
        // Out of range, in the past: refused.
        let (o, _) = book.command(
            "ann",
            &schedule(6, Fault::PoseNoise { sigma_mm: f32::NAN }, Start::Now, 0),
            2,
        );
        assert!(
            matches!(o, Outcome::Rejected { ref reason } if reason.contains("sigma_mm")),
            "{o:?}"
        );
        let (o, _) = book.command("ann", &schedule(6, spike, Start::AtTick(1), 0), 2);
        assert!(
            matches!(o, Outcome::Rejected { ref reason } if reason.contains("has passed")),
            "{o:?}"
        );
        // A burst of 20, then 10 a second: the flood is cut off, the bucket refills.
        let mut accepted = 0;
        for k in 0..40 {
            let c = Command {
                seq: 100 + k,
                action: Action::List,
            };
            if book.command("eve", &c, 10_000).0 == Outcome::Listed {
                accepted += 1;
            }
        }
        assert_eq!(accepted, 20);
        let c = Command {
            seq: 200,
            action: Action::List,
        };
        assert_eq!(book.command("eve", &c, 10_100).0, Outcome::Listed);
    }

    #[test]
    fn clearing_ends_faults_and_a_stiffness_change_ramps_in_and_out() {
        let mut book = FaultBook::new();
        let stiff = Fault::TissueStiffness {
            factor: 3.0,
            ramp_ms: 100,
        };
        book.command("ann", &schedule(1, stiff, Start::Now, 0), 0);
        book.command(
            "ann",
            &schedule(2, Fault::SimStall, Start::AtTick(5000), 0),
            0,
        );
        let t = book.table();
        assert_eq!(t.sim(0).stiffness, 1.0);
        assert!((t.sim(50).stiffness - 2.0).abs() < 1e-12);
        assert_eq!(t.sim(400).stiffness, 3.0);
        assert!(!t.sim(400).stall && t.sim(5000).stall);
        let (o, _) = book.command(
            "ann",
            &Command {
                seq: 3,
                action: Action::Clear { id: None },
            },
            400,
        );
        assert_eq!(o, Outcome::Cleared { count: 2 });
        let t = book.table();
        assert!((t.sim(450).stiffness - 2.0).abs() < 1e-12);
        assert_eq!(t.sim(500).stiffness, 1.0);
        // Cleared halfway through a long ramp in, it ramps out from where it had got to and
        // never rises again.
        let mut slow_book = FaultBook::new();
        let slow = Fault::TissueStiffness {
            factor: 10.0,
            ramp_ms: 60_000,
        };
        slow_book.command("ann", &schedule(1, slow, Start::Now, 0), 0);
        let clear = Command {
            seq: 2,
            action: Action::Clear { id: None },
        };
        slow_book.command("ann", &clear, 2_500);
        let t = slow_book.table();
        let at_clear = t.sim(2_500).stiffness;
        assert!((at_clear - 1.375).abs() < 1e-9, "{at_clear}");
        let mut last = at_clear;
        for tick in (2_500..=62_500).step_by(500) {
            let k = t.sim(tick).stiffness;
            assert!(k <= last + 1e-12, "rose to {k} at tick {tick} from {last}");
            last = k;
        }
        assert_eq!(t.sim(62_500).stiffness, 1.0);
        let events = book.advance(400);
        // The stall was cleared before it started; the stiffness is ramping out.
        assert_eq!(events.len(), 2, "{events:?}");
        // Listed as what it was — started at tick 0, cleared after 400 ms — and still acting
        // while it ramps out (it was listed "start Now, until cleared, scheduled").
        let listed = book.list(450);
        assert_eq!(listed.len(), 1);
        assert_eq!(listed[0].spec.start, Start::AtTick(0));
        assert_eq!(listed[0].spec.duration_ms, 400);
        assert!(listed[0].active);
        assert!(!book.list(500)[0].active);
        assert!(matches!(book.advance(500)[..], [Transition::Ended(_)]));
        let (o, _) = book.command(
            "ann",
            &Command {
                seq: 4,
                action: Action::Clear { id: Some(9) },
            },
            600,
        );
        assert!(matches!(o, Outcome::Rejected { .. }));
    }

    #[test]
    fn effects_combine_and_the_book_holds_at_most_its_table() {
        let mut book = FaultBook::new();
        for (k, f) in Fault::EXAMPLES.iter().enumerate() {
            let (o, _) = book.command("ann", &schedule(k as u64 + 1, *f, Start::Now, 0), 0);
            assert!(matches!(o, Outcome::Scheduled { .. }), "{f:?}: {o:?}");
        }
        let t = book.table();
        let h = t.haptic(0);
        assert!(h.dropout && h.latency_s == 0.05 && h.noise_sigma_m == 1e-3);
        assert_eq!((h.spike_n, h.cap_n), (10.0, 1.0));
        let s = t.sim(10_000);
        assert!(s.stall && s.renderer_freeze && s.slowdown == 4.0 && s.stiffness == 2.0);
        assert!(t.stream_lost(0));
        for k in 10..MAX_FAULTS as u64 {
            book.command("ann", &schedule(k + 1, Fault::SimStall, Start::Now, 0), 0);
        }
        let (o, _) = book.command("ann", &schedule(99, Fault::SimStall, Start::Now, 0), 0);
        assert!(
            matches!(o, Outcome::Rejected { ref reason } if reason.contains("booked")),
            "{o:?}"
        );
        // A stiffness change cleared and ramping out keeps its place until it has ramped out
        // (the real-time threads still need it): the refusal says so.
        let clear = |seq, id| Command {
            seq,
            action: Action::Clear { id: Some(id) },
        };
        let stiffness_id = 6;
        assert_eq!(book.list(0)[5].spec.fault, Fault::EXAMPLES[5]);
        book.command("ann", &clear(100, stiffness_id), 1000);
        book.advance(1000);
        let (o, _) = book.command("ann", &schedule(101, Fault::SimStall, Start::Now, 0), 1050);
        assert!(
            matches!(o, Outcome::Rejected { ref reason }
                if reason.contains("1 of them stiffness changes ramping out, the first free in 150 ms")),
            "{o:?}"
        );
        // A fault whose time is up but which the book has not yet seen leave (the station
        // takes commands before it advances the book): not counted as ramping, and no
        // arithmetic on its expiry (it underflowed).
        book.advance(1200);
        let (o, _) = book.command("ann", &schedule(102, Fault::SimStall, Start::Now, 1), 1200);
        assert!(matches!(o, Outcome::Scheduled { .. }), "{o:?}");
        let (o, _) = book.command("ann", &schedule(103, Fault::SimStall, Start::Now, 0), 1205);
        assert!(
            matches!(o, Outcome::Rejected { ref reason } if reason.ends_with("already: clear some first")),
            "{o:?}"
        );
    }

    #[test]
    fn stacked_stiffness_faults_stay_within_the_range_of_one() {
        // Sixteen faults of the same factor at once: the stiffness they give together.
        let stacked = |factor: f32| {
            let mut book = FaultBook::new();
            for seq in 1..=16 {
                let f = Fault::TissueStiffness { factor, ramp_ms: 1 };
                book.command("ann", &schedule(seq, f, Start::Now, 0), 0);
            }
            book.table().sim(100).stiffness
        };
        assert_eq!(stacked(10.0), 10.0);
        assert!((stacked(0.1) - 0.1).abs() < 1e-6);
    }

    #[test]
    fn stiffness_is_applied_in_steps_and_exactly_at_the_end() {
        // Ramping: a step at a time.
        assert_eq!(stiffness_to_apply(1.0, 1.01, 1.005), None);
        assert_eq!(stiffness_to_apply(1.0, 1.03, 1.025), Some(1.03));
        // Settled: exactly the target.
        assert_eq!(stiffness_to_apply(2.99, 3.0, 3.0), Some(3.0));
        assert_eq!(stiffness_to_apply(1.01, 1.0, 1.0), Some(1.0));
        assert_eq!(stiffness_to_apply(2.0, 2.0, 2.0), None);
    }
}
