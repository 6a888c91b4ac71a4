//! The main thread's answer to remote commands: each one refused or carried out on the
//! fault book, journaled and said in the station's log (or counted, in a flood), and the
//! answer sent back to its session.

use scalpel_proto::wire::{Action, Fault, Outcome, Role};

use super::{SimStatus, StationEvent, StationReport, station_tick};
use crate::command_audit::{self, CommandAudit};
use crate::faults::FaultBook;
use crate::journal;

/// When the main thread looks: the simulation's figures, the station's uptime and tick.
pub(super) struct Moment<'a> {
    pub sim: &'a SimStatus,
    pub uptime_s: f64,
    pub tick: u64,
}

/// The fault book and the audit of who sent what.
pub(super) struct CommandDesk {
    pub book: FaultBook,
    audit: CommandAudit,
    /// Tissue-stiffness faults are refused in a stiff-mode scene.
    stiff_mode: bool,
}

impl CommandDesk {
    pub fn new(stiff_mode: bool) -> Self {
        Self {
            book: FaultBook::new(),
            audit: CommandAudit::new(),
            stiff_mode,
        }
    }

    /// Answers the commands waiting on `network`; whether the fault book changed.
    pub fn answer(
        &mut self,
        network: &crate::net::Network,
        at: &Moment,
        journal: &std::sync::mpsc::Sender<String>,
        report: &mut dyn FnMut(&StationReport),
    ) -> bool {
        let mut changed = false;
        while let Ok(request) = network.commands.try_recv() {
            let outcome = self.outcome_of(&request, at.tick);
            let (outcome, listed) = outcome;
            changed |= matches!(outcome, Outcome::Scheduled { .. } | Outcome::Cleared { .. });
            let refused = matches!(outcome, Outcome::Rejected { .. });
            if self.audit.record(&request.by, refused, at.tick) == command_audit::Record::Full {
                let record = serde_json::json!({
                    "station_tick": at.tick,
                    "sim_tick": at.sim.ticks,
                    "by": request.by,
                    "role": request.role,
                    "seq": request.command.seq,
                    "action": request.command.action,
                    "outcome": outcome,
                });
                // No journal: nobody reads the channel, and that is fine.
                let _ = journal.send(journal::command_line(&record));
                report(&StationReport::Event(StationEvent {
                    uptime_s: at.uptime_s,
                    event: format!(
                        "{} {}: command {} {:?} -> {:?}",
                        role_name(request.role),
                        request.by,
                        request.command.seq,
                        request.command.action,
                        outcome
                    ),
                }));
            }
            // The session may have gone: its answer has nowhere to go.
            let _ = request.reply.send((outcome, listed));
        }
        for summary in self.audit.summaries(at.tick, false) {
            record_refusals(&summary, at, journal, report);
        }
        changed
    }

    /// Writes out the audit's last counted refusals (the station is stopping).
    pub fn close(
        &mut self,
        at: &Moment,
        journal: &std::sync::mpsc::Sender<String>,
        report: &mut dyn FnMut(&StationReport),
    ) {
        for summary in self.audit.summaries(at.tick, true) {
            record_refusals(&summary, at, journal, report);
        }
    }

    fn outcome_of(
        &mut self,
        request: &crate::net::CommandRequest,
        tick: u64,
    ) -> (Outcome, Option<Vec<scalpel_proto::wire::ScheduledFault>>) {
        let refuse = |reason: &str| {
            (
                Outcome::Rejected {
                    reason: reason.to_string(),
                },
                None,
            )
        };
        if request.reply.is_closed() {
            // The session gave up waiting (and told its client so): not carried out late.
            refuse("expired: the station did not take it in time")
        } else if request.role != Role::Instructor {
            refuse("an observer certificate may not instruct")
        } else if let Some(reason) = &request.refused {
            refuse(reason)
        } else if self.stiff_mode
            && matches!(
                &request.command.action,
                Action::Schedule(spec) if matches!(spec.fault, Fault::TissueStiffness { .. })
            )
        {
            // Each change would re-factorise the projective solver on the simulation
            // thread (milliseconds, allocating).
            refuse("tissue-stiffness is not available in a stiff-mode scene")
        } else {
            self.book.command(&request.by, &request.command, tick)
        }
    }
}

/// How a role reads in the log.
fn role_name(role: Role) -> &'static str {
    match role {
        Role::Observer => "observer",
        Role::Instructor => "instructor",
    }
}

/// Writes out refusals the audit counted: one journal line (`refused_unrecorded`, which
/// `scalpel replay` lists) and one line of the station's log.
fn record_refusals(
    summary: &command_audit::Summary,
    at: &Moment,
    journal: &std::sync::mpsc::Sender<String>,
    report: &mut dyn FnMut(&StationReport),
) {
    // Station and simulation ticks of the summary, like every command line's; the refusals
    // it counts came between the first and the last tick given.
    let record = serde_json::json!({
        "station_tick": station_tick(at.uptime_s),
        "sim_tick": at.sim.ticks,
        "by": summary.by,
        "refused_unrecorded": summary.refused,
        "first_station_tick": summary.ticks.0,
        "last_station_tick": summary.ticks.1,
    });
    let _ = journal.send(journal::command_line(&record));
    report(&StationReport::Event(StationEvent {
        uptime_s: at.uptime_s,
        event: format!(
            "client {}: {} more commands refused from station tick {} to {} (a flood: \
             counted, not written out one by one)",
            summary.by, summary.refused, summary.ticks.0, summary.ticks.1
        ),
    }));
}
