//! The journal's writer thread: the simulation thread pushes each tick's input into a
//! lock-free ring ([`SimJournal`]) and [`spawn_journal_writer`] writes the records, and the
//! instructors' command lines, to the journal file off the real-time threads.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;

use crate::journal::{self, TickRecord};

/// Journal records in flight to the writer thread (a minute at 1 kHz).
pub(super) const JOURNAL_RING: usize = 1 << 16;

/// The simulation thread's end of the journal.
pub(super) struct SimJournal {
    pub(super) records: Option<rtrb::Producer<TickRecord>>,
    pub(super) dropped: Arc<AtomicU64>,
}

/// Writes journal records as they come, until the simulation has stopped and the ring is
/// empty; hands the file back for the footer.
pub(super) fn spawn_journal_writer(
    mut file: std::io::BufWriter<std::fs::File>,
    mut records: rtrb::Consumer<TickRecord>,
    commands: std::sync::mpsc::Receiver<String>,
    sim_done: Arc<AtomicBool>,
) -> std::io::Result<JoinHandle<std::io::Result<std::io::BufWriter<std::fs::File>>>> {
    std::thread::Builder::new()
        .name("journal".into())
        .spawn(move || {
            loop {
                let done = sim_done.load(Ordering::Acquire);
                while let Ok(line) = commands.try_recv() {
                    std::io::Write::write_all(&mut file, line.as_bytes())?;
                }
                while let Ok(r) = records.pop() {
                    journal::write_record(&mut file, &r)?;
                }
                if done {
                    return Ok(file);
                }
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
        })
}
