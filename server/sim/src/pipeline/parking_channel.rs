//! A bounded channel between two threads whose receiver parks instead of blocking in the
//! channel, for the hand-offs of the simulation thread (the re-cut worker's jobs and
//! results).
//!
//! A thread blocked in std's channel makes every sender to it take the channel's waker
//! lock, and the first time a thread blocks it allocates its wait context and a slot in the
//! receivers' list: on the simulation thread, in a tick. Here both sides only ever
//! `try_send` and `try_recv`; a receiver with nothing to take parks, and the sender unparks
//! it after each message and when it is dropped. Parking and unparking neither lock nor
//! allocate.

use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, TrySendError, sync_channel};
use std::sync::{Arc, OnceLock};
use std::thread::Thread;
use std::time::Duration;

/// A channel of room for `bound` messages.
pub(crate) fn parking_channel<T>(bound: usize) -> (ParkingSender<T>, ParkingReceiver<T>) {
    let (tx, rx) = sync_channel(bound);
    let receiver = Arc::new(OnceLock::new());
    (
        ParkingSender {
            tx,
            receiver: Wakes(Arc::clone(&receiver)),
        },
        ParkingReceiver { rx, receiver },
    )
}

/// The sending end.
pub(crate) struct ParkingSender<T> {
    // Declared first, so dropped before `receiver` wakes the receiving thread, which then
    // finds the channel closed.
    tx: SyncSender<T>,
    receiver: Wakes,
}

/// The thread receiving, once it has first looked; woken once more when dropped.
struct Wakes(Arc<OnceLock<Thread>>);

impl Wakes {
    fn wake(&self) {
        if let Some(thread) = self.0.get() {
            thread.unpark();
        }
    }
}

impl Drop for Wakes {
    fn drop(&mut self) {
        self.wake();
    }
}

impl<T> ParkingSender<T> {
    /// Sends `message` and wakes the receiver; gives it back if the receiver is gone.
    pub fn send(&self, message: T) -> Result<(), T> {
        let sent = match self.tx.try_send(message) {
            Ok(()) => Ok(()),
            // The hand-offs keep within their bounds; past one, this waits as the
            // channel's own `send` does.
            Err(TrySendError::Full(message)) => self.tx.send(message).map_err(|e| e.0),
            Err(TrySendError::Disconnected(message)) => Err(message),
        };
        self.receiver.wake();
        sent
    }
}

/// The receiving end. The first thread to receive is the one senders wake; another thread
/// receiving later still gets its messages, looking every `limit` of `recv`.
pub(crate) struct ParkingReceiver<T> {
    rx: Receiver<T>,
    receiver: Arc<OnceLock<Thread>>,
}

impl<T> ParkingReceiver<T> {
    /// The next message, parking until one comes (or, with a `limit`, looking again at
    /// least that often; it backs up a wake-up that cannot come, such as a sender that
    /// died without dropping its end). `None` once every sender is gone and the channel
    /// is empty. `waited` is set when the message was not there at first.
    pub fn recv(&self, limit: Option<Duration>, waited: &mut bool) -> Option<T> {
        self.receiver.get_or_init(std::thread::current);
        *waited = false;
        loop {
            match self.rx.try_recv() {
                Ok(message) => return Some(message),
                Err(TryRecvError::Disconnected) => return None,
                // A wake-up between the look and the park is kept for the park (its
                // token), so none is lost.
                Err(TryRecvError::Empty) => {
                    *waited = true;
                    match limit {
                        Some(limit) => std::thread::park_timeout(limit),
                        None => std::thread::park(),
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A receiver parked before the message is sent is woken by it; one parked when the
    /// sender goes is woken to find the channel closed.
    #[test]
    fn a_parked_receiver_is_woken_by_a_message_and_by_the_senders_drop() {
        let (tx, rx) = parking_channel::<u32>(2);
        let receiving = std::thread::spawn(move || {
            let mut waited = false;
            let first = rx.recv(None, &mut waited);
            let first_waited = waited;
            let then = rx.recv(None, &mut waited);
            (first, first_waited, then, waited)
        });
        // Long enough for the receiver to look and park.
        std::thread::sleep(Duration::from_millis(50));
        tx.send(7).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        drop(tx);
        // (A receiver nobody wakes stays parked: fail, not hang.)
        let ended = (0..2000).any(|_| {
            std::thread::sleep(Duration::from_millis(1));
            receiving.is_finished()
        });
        assert!(ended, "the receiver was not woken by the sender's drop");
        let (first, first_waited, then, then_waited) = receiving.join().unwrap();
        assert_eq!(first, Some(7));
        assert!(first_waited, "the message came after the receiver looked");
        assert_eq!(then, None, "the sender's drop closes the channel");
        assert!(then_waited);
    }

    /// A message already there is taken without waiting, in order; a sender whose receiver
    /// is gone gets its message back.
    #[test]
    fn messages_waiting_are_taken_in_order_and_a_lost_receiver_returns_them() {
        let (tx, rx) = parking_channel::<u32>(2);
        tx.send(1).unwrap();
        tx.send(2).unwrap();
        let mut waited = true;
        assert_eq!(rx.recv(None, &mut waited), Some(1));
        assert!(!waited);
        assert_eq!(
            rx.recv(Some(Duration::from_millis(1)), &mut waited),
            Some(2)
        );
        drop(rx);
        assert_eq!(tx.send(3), Err(3));
    }
}
