//! The service's state behind one lock: the queue ([`State`]), its journal and the event bus.
//! Every change is checked, journaled (synced) and only then applied and told, so what a
//! client was answered is on the disk, and what the disk holds was checked.

use super::events::{now_ms, Bus, Kind};
use super::journal::{Journal, JournalError, Recovery};
use super::queue::{Change, QueueError, Request, State};
use serde_json::json;
use std::path::Path;
use std::sync::{Arc, Mutex};

/// The journal's file name in the service's data folder.
pub const JOURNAL: &str = "journal";

#[derive(Debug, thiserror::Error)]
pub enum LedgerError {
    #[error(transparent)]
    Queue(#[from] QueueError),
    /// The change could not be made durable: it was not applied.
    #[error("the journal could not be written, so nothing was changed: {0}")]
    Journal(#[from] JournalError),
    /// An admin's lock, seen under the ledger's own lock (a request begun before the lock was
    /// set is refused too).
    #[error("the queue is locked by {} ({}): only an admin may change it now; pause, abort and halt stay open", .0.by, .0.note)]
    Locked(crate::service::queue::Lock),
    #[error("{path}: record {index} is not a change the service wrote ({why}); move the journal away to start empty, or restore it")]
    Damaged {
        path: std::path::PathBuf,
        index: usize,
        why: String,
    },
}

struct Inner {
    state: State,
    journal: Journal,
}

pub struct Ledger {
    inner: Mutex<Inner>,
    pub bus: Arc<Bus>,
}

impl Ledger {
    /// Opens the journal in `data`, replays it, puts an item that was running back at the
    /// front (interrupted, the queue stopped), and compacts the journal to one snapshot.
    pub fn open(data: &Path) -> Result<(Ledger, Recovery), LedgerError> {
        let path = data.join(JOURNAL);
        let (mut journal, records, recovery) = Journal::open(&path)?;
        let mut state = State::default();
        for (index, r) in records.iter().enumerate() {
            let c: Change = serde_json::from_slice(r).map_err(|e| LedgerError::Damaged {
                path: path.clone(),
                index,
                why: e.to_string(),
            })?;
            state.commit(c);
        }
        for c in state.recovered(now_ms()) {
            state.commit(c);
        }
        let snap = serde_json::to_vec(&Change::Snapshot(Box::new(state.clone())))
            .expect("the state serialises");
        journal.compact(&[snap])?;
        // Numbers go on growing across restarts (milliseconds since the epoch × 1000 at the
        // start), so a client's Last-Event-ID from an earlier run is never taken for this one's.
        let bus = Arc::new(Bus::new(now_ms().saturating_mul(1000)));
        Ok((
            Ledger {
                inner: Mutex::new(Inner { state, journal }),
                bus,
            },
            recovery,
        ))
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn write(&self, g: &mut Inner, c: Change) -> Result<(), LedgerError> {
        let bytes = serde_json::to_vec(&c).expect("a change serialises");
        g.journal.append(&bytes)?;
        let told = tell(&c, &g.state);
        g.state.commit(c);
        if let Some((kind, data)) = told {
            self.bus.publish(kind, data);
        }
        Ok(())
    }

    /// Checks, journals and applies a client's request; `None`: nothing to change (a batch
    /// whose keys were all seen).
    pub fn request(&self, r: Request) -> Result<Option<Change>, LedgerError> {
        self.request_as(true, r)
    }

    /// As [`Ledger::request`], refused while an admin's lock is set unless `admin`.
    pub fn request_as(&self, admin: bool, r: Request) -> Result<Option<Change>, LedgerError> {
        let mut g = self.lock();
        if let (false, Some(l)) = (admin, &g.state.lock) {
            return Err(LedgerError::Locked(l.clone()));
        }
        let Some(c) = g.state.plan(r)? else {
            return Ok(None);
        };
        self.write(&mut g, c.clone())?;
        Ok(Some(c))
    }

    /// As [`Ledger::change`], refused while an admin's lock is set unless `admin`.
    pub fn change_as(
        &self,
        admin: bool,
        make: impl FnOnce(&State) -> Option<Change>,
    ) -> Result<Option<Change>, LedgerError> {
        let mut g = self.lock();
        if let (false, Some(l)) = (admin, &g.state.lock) {
            return Err(LedgerError::Locked(l.clone()));
        }
        let Some(c) = make(&g.state) else {
            return Ok(None);
        };
        self.write(&mut g, c.clone())?;
        Ok(Some(c))
    }

    /// Journals and applies a change made from the state (`make` sees the state under the
    /// lock; `None`: no change).
    pub fn change(
        &self,
        make: impl FnOnce(&State) -> Option<Change>,
    ) -> Result<Option<Change>, LedgerError> {
        self.change_as(true, make)
    }

    /// Reads the state.
    pub fn read<T>(&self, f: impl FnOnce(&State) -> T) -> T {
        f(&self.lock().state)
    }
}

/// The event a change is told as (`before`: the state it applies to).
fn tell(c: &Change, before: &State) -> Option<(Kind, serde_json::Value)> {
    let running = before.running.as_ref().map(|i| i.id);
    Some(match c {
        Change::Begin { id, .. } => (Kind::Item, json!({"id": id, "state": "running"})),
        Change::Pause { paused } => (
            Kind::Item,
            json!({"id": running, "state": if *paused { "paused" } else { "running" }}),
        ),
        Change::Finish {
            outcome, message, ..
        } => (
            Kind::Item,
            json!({"id": running, "ended": outcome, "message": message}),
        ),
        Change::Options(o) => (Kind::Status, json!({"options": o})),
        Change::Lock { lock } => (Kind::Status, json!({"lock": lock})),
        Change::Snapshot(_) => return None,
        other => (Kind::Queue, serde_json::to_value(other).ok()?),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::queue::{Lock, Position, Task};

    /// The lock is read under the ledger's own mutex: a request checked before the lock was
    /// set is still refused when it reaches the ledger; an admin's goes through.
    #[test]
    fn a_lock_refuses_a_non_admins_change_at_the_ledger() {
        let d = tempfile::tempdir().unwrap();
        let (l, _) = Ledger::open(d.path()).unwrap();
        let add = || Request::Add {
            items: vec![(Task::Home, None)],
            at: Position::Back,
            now_ms: 0,
        };
        l.request_as(false, add()).unwrap();
        l.change(|_| {
            Some(Change::Lock {
                lock: Some(Lock {
                    by: "a".into(),
                    note: "lamp".into(),
                    since_ms: 0,
                }),
            })
        })
        .unwrap();
        assert!(matches!(
            l.request_as(false, add()),
            Err(LedgerError::Locked(_))
        ));
        assert!(matches!(
            l.change_as(false, |s| Some(Change::Options(s.options))),
            Err(LedgerError::Locked(_))
        ));
        l.request_as(true, add()).unwrap();
        assert_eq!(l.read(|s| s.queue.len()), 2);
    }
}
