//! What happens, told to every client in one order: each event has the next sequence number,
//! so a client sees a gap if it missed one, and a client that reconnects with the last number
//! it saw (`Last-Event-ID`) is sent what it missed from a bounded backlog.
//!
//! Publishing never waits for a client: events go into a ring of fixed size
//! (`tokio::sync::broadcast`). A client that falls a whole ring behind is told to resync (read
//! the state afresh) and dropped, so a client that does not read never slows the hardware and
//! never grows memory.

use serde::Serialize;
use serde_json::Value;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::broadcast;

/// Events kept for reconnecting clients, and the most a live client may fall behind.
pub const BACKLOG: usize = 4096;
/// Position events are sent at most this often (10 Hz).
pub const POSITION_EVERY: Duration = Duration::from_millis(100);

/// The kinds of event; their `data` is documented in docs/service.md.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// The service's status (queue running or not, the item running, the stage).
    Status,
    /// The queue was changed (the change itself, as journaled).
    Queue,
    /// An item changed state (started, paused, ended).
    Item,
    /// Progress of the running item: step, of, seconds left.
    Progress,
    /// The stage's position, mm.
    Position,
    /// A new frame or tile to look at: its URL.
    Preview,
    Warning,
    Log,
    /// The client fell behind or asked for events no longer kept: read the state afresh.
    Resync,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Status => "status",
            Kind::Queue => "queue",
            Kind::Item => "item",
            Kind::Progress => "progress",
            Kind::Position => "position",
            Kind::Preview => "preview",
            Kind::Warning => "warning",
            Kind::Log => "log",
            Kind::Resync => "resync",
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Event {
    pub seq: u64,
    pub kind: Kind,
    /// Milliseconds since the Unix epoch.
    pub at_ms: u64,
    pub data: Value,
    /// The text every event client is sent (`{"seq", "at_ms", "data"}`), written once here
    /// rather than once per client.
    #[serde(skip)]
    pub wire: String,
}

struct Ring {
    next: u64,
    kept: VecDeque<Arc<Event>>,
    last_position: Option<Instant>,
    /// The last position sent: one standing still is not sent again.
    last_place: Option<Value>,
}

/// The one publisher of events.
pub struct Bus {
    ring: Mutex<Ring>,
    tx: broadcast::Sender<Arc<Event>>,
}

/// A new subscriber: the events it missed since its last one, then the live ones.
pub struct Subscription {
    pub missed: Vec<Arc<Event>>,
    /// The backlog no longer reaches back to the client's last event.
    pub gap: bool,
    pub live: broadcast::Receiver<Arc<Event>>,
}

pub fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

impl Bus {
    /// A bus whose first event will carry `first` (a restarted service goes on from where its
    /// journal says it stopped, so a reconnecting client never sees a number twice).
    pub fn new(first: u64) -> Bus {
        let (tx, _) = broadcast::channel(BACKLOG);
        Bus {
            ring: Mutex::new(Ring {
                next: first,
                kept: VecDeque::with_capacity(BACKLOG),
                last_position: None,
                last_place: None,
            }),
            tx,
        }
    }

    /// Publishes an event; returns its sequence number.
    pub fn publish(&self, kind: Kind, data: Value) -> u64 {
        let mut r = self.ring.lock().unwrap_or_else(|e| e.into_inner());
        let (seq, at_ms) = (r.next, now_ms());
        let wire = serde_json::json!({"seq": seq, "at_ms": at_ms, "data": &data}).to_string();
        let e = Arc::new(Event {
            seq,
            kind,
            at_ms,
            data,
            wire,
        });
        r.next += 1;
        if r.kept.len() == BACKLOG {
            r.kept.pop_front();
        }
        r.kept.push_back(e.clone());
        // Sent under the lock, so that live receivers see the ring's order. No receiver: fine.
        let _ = self.tx.send(e.clone());
        e.seq
    }

    /// Publishes a position unless one went out less than [`POSITION_EVERY`] ago (`force`:
    /// the last position of a motion, always sent).
    pub fn position(&self, data: Value, force: bool) {
        {
            let mut r = self.ring.lock().unwrap_or_else(|e| e.into_inner());
            let now = Instant::now();
            if !force
                && (r.last_position.is_some_and(|t| now - t < POSITION_EVERY)
                    || r.last_place.as_ref() == Some(&data))
            {
                return;
            }
            r.last_position = Some(now);
            r.last_place = Some(data.clone());
        }
        self.publish(Kind::Position, data);
    }

    /// The number the next event will carry.
    pub fn next_seq(&self) -> u64 {
        self.ring.lock().unwrap_or_else(|e| e.into_inner()).next
    }

    pub fn clients(&self) -> usize {
        self.tx.receiver_count()
    }

    /// Subscribes after event `last` (none: from now on).
    pub fn subscribe(&self, last: Option<u64>) -> Subscription {
        let r = self.ring.lock().unwrap_or_else(|e| e.into_inner());
        let live = self.tx.subscribe();
        let (missed, gap) = match last {
            None => (vec![], false),
            Some(l) => {
                let first_kept = r.kept.front().map_or(r.next, |e| e.seq);
                let missed: Vec<_> = r.kept.iter().filter(|e| e.seq > l).cloned().collect();
                // Events l+1 .. first_kept-1 are gone; a number from the future is a client of
                // another run of the service.
                (missed, l + 1 < first_kept || l >= r.next)
            }
        };
        Subscription { missed, gap, live }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn numbers_are_gapless_and_a_reconnect_gets_what_it_missed() {
        let bus = Bus::new(7);
        let mut a = bus.subscribe(None).live;
        for i in 0..10 {
            assert_eq!(bus.publish(Kind::Log, json!(i)), 7 + i);
        }
        for i in 0..10 {
            assert_eq!(a.try_recv().unwrap().seq, 7 + i);
        }
        let s = bus.subscribe(Some(12));
        assert!(!s.gap);
        assert_eq!(
            s.missed.iter().map(|e| e.seq).collect::<Vec<_>>(),
            [13, 14, 15, 16]
        );
        // Beyond the backlog, or from another run: told to resync.
        // (One more than the ring holds, so that `a`, which read none of them, lags.)
        for _ in 0..=BACKLOG {
            bus.publish(Kind::Log, json!(0));
        }
        assert!(bus.subscribe(Some(12)).gap);
        assert!(bus.subscribe(Some(bus.next_seq() + 5)).gap);
        assert!(!bus.subscribe(Some(bus.next_seq() - 1)).gap);
        // The client that did not read lags, it is not waited for.
        assert!(matches!(
            a.try_recv(),
            Err(broadcast::error::TryRecvError::Lagged(_))
        ));
    }

    #[test]
    fn positions_are_thinned_to_ten_a_second_but_the_last_is_sent() {
        let bus = Bus::new(0);
        let at = |x: i32| json!({"x_mm": x});
        for i in 0..100 {
            bus.position(at(i), false);
        }
        assert_eq!(bus.next_seq(), 1);
        bus.position(at(100), true);
        assert_eq!(bus.next_seq(), 2);
        std::thread::sleep(POSITION_EVERY);
        // Standing still: not sent again, however long.
        bus.position(at(100), false);
        assert_eq!(bus.next_seq(), 2);
        bus.position(at(101), false);
        assert_eq!(bus.next_seq(), 3);
    }
}
