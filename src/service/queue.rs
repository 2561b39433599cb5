//! The queue of work, the running item and the history, as one state that changes only by
//! [`Change`]s. A request is first checked against the state ([`State::plan`], which touches
//! nothing and resolves positions and ids), the resulting change is journaled, and only then
//! applied ([`State::commit`], which cannot fail). Replaying the journal's changes in order
//! rebuilds the state exactly; so a crash loses nothing that was answered.
//!
//! Where an item is tells what became of it: queued (waiting), running, or in the history
//! (ended: done, failed, stopped, removed). An aborted, halted or interrupted attempt puts the
//! item back at the front of the queue for a new attempt, and stops the queue, as bluesky's
//! queue server does: the operator decides when it goes on.

use serde::{Deserialize, Serialize};
use serde_json::Value;
use std::path::PathBuf;

pub type ItemId = u64;

/// The most items waiting at once (a batch beyond it is refused whole), and the most ended
/// items kept in the history (the oldest are forgotten first, at compaction).
pub const MAX_QUEUED: usize = 10_000;
pub const MAX_HISTORY: usize = 10_000;
/// The longest idempotency key, bytes.
pub const MAX_KEY: usize = 200;

/// What an item does. Checked when added ([`super::task`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Task {
    /// Home both axes.
    Home,
    /// Move to a carriage position, mm.
    Move { x_mm: f64, y_mm: f64 },
    /// Scan film by a script (its TOML text); `name` names the output folder.
    Scan { name: String, script: String },
    /// A pixel calibration session into the store (as `rig calibrate pixel`).
    CalibratePixel {
        /// Frames averaged at each position.
        #[serde(default = "default_frames")]
        frames: u32,
        /// Positions per side of the grid.
        #[serde(default = "default_grid")]
        grid: usize,
        /// Only the grid: not the crosses that locate the measuring mark.
        #[serde(default)]
        grid_only: bool,
        /// No flat field.
        #[serde(default)]
        no_flat: bool,
        /// Nominal pixel spacing to start from, µm.
        #[serde(default = "default_pixel_um")]
        pixel_um: [f64; 2],
        /// The plate certificate: a file name in `--certificates`; with the simulator, its own.
        #[serde(default)]
        plate_cert: Option<PathBuf>,
    },
    /// An interior orientation session into the store (as `rig calibrate interior`).
    CalibrateInterior {
        #[serde(default = "default_frames")]
        frames: u32,
        /// Where the film's centre lies on the carriage, roughly, mm.
        #[serde(default = "default_film_centre")]
        film_centre_mm: [f64; 2],
        /// The pixel session to use, by its folder's name in the store (default: the newest).
        #[serde(default)]
        pixel_session: Option<PathBuf>,
        /// The film camera's certificate: a file name in `--certificates`; with the simulator,
        /// its own.
        #[serde(default)]
        camera_cert: Option<PathBuf>,
    },
}

fn default_frames() -> u32 {
    32
}
fn default_grid() -> usize {
    5
}
fn default_pixel_um() -> [f64; 2] {
    [10.0, 10.0]
}
fn default_film_centre() -> [f64; 2] {
    [125.0, 125.0]
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ItemState {
    Queued,
    Running,
    Paused,
    Done,
    Failed,
    /// Stopped on request (`stop`): ended, not to be tried again.
    Stopped,
    Removed,
}

/// How an attempt ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    Done,
    Failed,
    Stopped,
    /// `abort`: stages stopped, the item goes back to the front.
    Aborted,
    /// `halt`: controller reset at once, the item goes back to the front.
    Halted,
    /// The service ended (killed, crashed) while it ran; found so at the next start.
    Interrupted,
}

impl Outcome {
    /// Whether the item is tried again (back at the front) rather than ended.
    pub fn retried(self) -> bool {
        matches!(
            self,
            Outcome::Aborted | Outcome::Halted | Outcome::Interrupted
        )
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Attempt {
    pub started_ms: u64,
    pub ended_ms: Option<u64>,
    pub outcome: Option<Outcome>,
    pub message: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Item {
    pub id: ItemId,
    pub task: Task,
    pub key: Option<String>,
    pub state: ItemState,
    pub added_ms: u64,
    pub attempts: Vec<Attempt>,
    /// What it produced (a scan's manifest summary, a move's position).
    pub result: Option<Value>,
}

/// Where an item is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Place {
    /// Waiting, at this index.
    Queue(usize),
    Running,
    History,
}

/// Where to put items in the queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Position {
    #[default]
    Back,
    Front,
    Index(usize),
    Before(ItemId),
    After(ItemId),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub struct Options {
    /// Start the next item when one ends (the queue is running).
    pub running: bool,
    /// Go on with the next item after a failure (else the queue stops).
    pub continue_on_failure: bool,
    /// Stop the queue when the running item ends.
    pub stop_after_current: bool,
    /// Start the queue when an item is added to an idle, empty queue.
    pub autostart: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct State {
    pub next_id: ItemId,
    pub queue: Vec<Item>,
    pub running: Option<Item>,
    pub history: Vec<Item>,
    pub options: Options,
    /// An admin's lock: while set, only admins change the queue or control the run (pause,
    /// abort and halt stay open to operators: stopping is never locked out).
    #[serde(default)]
    pub lock: Option<Lock>,
}

/// Who locked the queue, when and why (bluesky's queue server's lock, by role).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Lock {
    /// The token's name.
    pub by: String,
    pub note: String,
    pub since_ms: u64,
}

/// A checked, resolved change: what the journal holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "change", rename_all = "snake_case")]
pub enum Change {
    Insert {
        at: usize,
        items: Vec<Item>,
    },
    Edit {
        id: ItemId,
        task: Task,
    },
    Remove {
        id: ItemId,
        at_ms: u64,
    },
    Move {
        id: ItemId,
        to: usize,
    },
    Clear {
        at_ms: u64,
    },
    Options(Options),
    Begin {
        id: ItemId,
        at_ms: u64,
    },
    Pause {
        paused: bool,
    },
    Finish {
        outcome: Outcome,
        message: Option<String>,
        result: Option<Value>,
        at_ms: u64,
    },
    Lock {
        lock: Option<Lock>,
    },
    Snapshot(Box<State>),
}

/// What a request asks of the queue.
#[derive(Debug, Clone)]
pub enum Request {
    Add {
        items: Vec<(Task, Option<String>)>,
        at: Position,
        now_ms: u64,
    },
    Edit {
        id: ItemId,
        task: Task,
    },
    Remove {
        id: ItemId,
        now_ms: u64,
    },
    Move {
        id: ItemId,
        to: Position,
    },
    Clear {
        now_ms: u64,
    },
    Options(Options),
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum QueueError {
    #[error("no item {0}")]
    NoItem(ItemId),
    #[error("item {id} is {state:?}, not queued: only a waiting item can be {what}")]
    NotQueued {
        id: ItemId,
        state: ItemState,
        what: &'static str,
    },
    #[error("position {at} is beyond the queue's {len} items")]
    BadIndex { at: usize, len: usize },
    #[error("the queue holds {queued} items and takes at most {MAX_QUEUED}: {adding} more would be too many")]
    Full { queued: usize, adding: usize },
    #[error("an idempotency key is 1 to {MAX_KEY} bytes")]
    BadKey,
    #[error("the batch is empty")]
    Empty,
    #[error("idempotency key {key:?} is given twice in one batch")]
    DuplicateKey { key: String },
}

impl State {
    /// The item with `id` and where it is.
    pub fn locate(&self, id: ItemId) -> Option<(&Item, Place)> {
        if let Some(k) = self.queue.iter().position(|i| i.id == id) {
            return Some((&self.queue[k], Place::Queue(k)));
        }
        if let Some(i) = self.running.as_ref().filter(|i| i.id == id) {
            return Some((i, Place::Running));
        }
        self.history
            .iter()
            .find(|i| i.id == id)
            .map(|i| (i, Place::History))
    }

    /// The item with `id` wherever it is.
    pub fn find(&self, id: ItemId) -> Option<&Item> {
        self.locate(id).map(|(i, _)| i)
    }

    fn by_key(&self, key: &str) -> Option<&Item> {
        self.queue
            .iter()
            .chain(self.running.as_ref())
            .chain(self.history.iter())
            .find(|i| i.key.as_deref() == Some(key))
    }

    fn queued_index(&self, id: ItemId, what: &'static str) -> Result<usize, QueueError> {
        if let Some(i) = self.queue.iter().position(|i| i.id == id) {
            return Ok(i);
        }
        match self.find(id) {
            Some(i) => Err(QueueError::NotQueued {
                id,
                state: i.state,
                what,
            }),
            None => Err(QueueError::NoItem(id)),
        }
    }

    /// Where `p` points in a queue of `len` items, `moving` (if any) taken out first.
    fn index(&self, p: Position, moving: Option<ItemId>) -> Result<usize, QueueError> {
        let rest = || self.queue.iter().filter(move |i| Some(i.id) != moving);
        let len = rest().count();
        let of = |id: ItemId| -> Result<usize, QueueError> {
            if Some(id) == moving {
                return Err(QueueError::NotQueued {
                    id,
                    state: ItemState::Queued,
                    what: "a position relative to itself",
                });
            }
            rest()
                .position(|i| i.id == id)
                .ok_or_else(|| match self.find(id) {
                    Some(i) => QueueError::NotQueued {
                        id,
                        state: i.state,
                        what: "a position to place before or after",
                    },
                    None => QueueError::NoItem(id),
                })
        };
        match p {
            Position::Back => Ok(len),
            Position::Front => Ok(0),
            Position::Index(at) if at <= len => Ok(at),
            Position::Index(at) => Err(QueueError::BadIndex { at, len }),
            Position::Before(id) => of(id),
            Position::After(id) => Ok(of(id)? + 1),
        }
    }

    /// Checks `r` against the state and resolves it into the change to journal; `Ok(None)`
    /// when there is nothing to change (a batch whose keys were all seen: the ids it gives are
    /// [`State::ids_of_keys`]).
    pub fn plan(&self, r: Request) -> Result<Option<Change>, QueueError> {
        Ok(Some(match r {
            Request::Add { items, at, now_ms } => {
                if items.is_empty() {
                    return Err(QueueError::Empty);
                }
                let mut seen = std::collections::HashSet::new();
                let mut new = Vec::new();
                for (task, key) in items {
                    if let Some(k) = &key {
                        if k.is_empty() || k.len() > MAX_KEY {
                            return Err(QueueError::BadKey);
                        }
                        if !seen.insert(k.clone()) {
                            return Err(QueueError::DuplicateKey { key: k.clone() });
                        }
                        // Added before (a retried request): not again.
                        if self.by_key(k).is_some() {
                            continue;
                        }
                    }
                    new.push(Item {
                        id: self.next_id + new.len() as u64,
                        task,
                        key,
                        state: ItemState::Queued,
                        added_ms: now_ms,
                        attempts: vec![],
                        result: None,
                    });
                }
                if new.is_empty() {
                    return Ok(None);
                }
                if self.queue.len() + new.len() > MAX_QUEUED {
                    return Err(QueueError::Full {
                        queued: self.queue.len(),
                        adding: new.len(),
                    });
                }
                Change::Insert {
                    at: self.index(at, None)?,
                    items: new,
                }
            }
            Request::Edit { id, task } => {
                self.queued_index(id, "edited")?;
                Change::Edit { id, task }
            }
            Request::Remove { id, now_ms } => {
                self.queued_index(id, "removed")?;
                Change::Remove { id, at_ms: now_ms }
            }
            Request::Move { id, to } => {
                self.queued_index(id, "moved")?;
                Change::Move {
                    id,
                    to: self.index(to, Some(id))?,
                }
            }
            Request::Clear { now_ms } => Change::Clear { at_ms: now_ms },
            Request::Options(o) => Change::Options(o),
        }))
    }

    /// The ids of the items carrying these keys (those a repeated batch already added).
    pub fn ids_of_keys<'a>(&self, keys: impl Iterator<Item = &'a str>) -> Vec<Option<ItemId>> {
        keys.map(|k| self.by_key(k).map(|i| i.id)).collect()
    }

    /// The change that starts the front item, if the queue may start one now.
    pub fn next_to_run(&self, now_ms: u64) -> Option<Change> {
        if !self.options.running || self.running.is_some() {
            return None;
        }
        self.queue.first().map(|i| Change::Begin {
            id: i.id,
            at_ms: now_ms,
        })
    }

    /// The change that ends the running item (none running: none).
    pub fn finish(
        &self,
        outcome: Outcome,
        message: Option<String>,
        result: Option<Value>,
        now_ms: u64,
    ) -> Option<Change> {
        self.running.as_ref().map(|_| Change::Finish {
            outcome,
            message,
            result,
            at_ms: now_ms,
        })
    }

    fn end_in_history(&mut self, item: Item) {
        self.history.push(item);
        if self.history.len() > MAX_HISTORY {
            let over = self.history.len() - MAX_HISTORY;
            self.history.drain(..over);
        }
    }

    /// Applies a change made by [`State::plan`] (or read back from the journal). A change
    /// that no longer fits (a damaged journal edited by hand) is skipped with a warning,
    /// never half applied.
    pub fn commit(&mut self, c: Change) {
        let skip =
            |c: &Change| tracing::warn!(?c, "a journaled change does not fit the state; skipped");
        match c {
            Change::Insert { at, items } => {
                let at = at.min(self.queue.len());
                if let Some(last) = items.iter().map(|i| i.id).max() {
                    self.next_id = self.next_id.max(last + 1);
                }
                self.queue.splice(at..at, items);
            }
            Change::Edit { id, ref task } => match self.queue.iter_mut().find(|i| i.id == id) {
                Some(i) => i.task = task.clone(),
                None => skip(&c),
            },
            Change::Remove { id, at_ms } => match self.queue.iter().position(|i| i.id == id) {
                Some(k) => {
                    let mut i = self.queue.remove(k);
                    i.state = ItemState::Removed;
                    i.result = Some(serde_json::json!({"removed_ms": at_ms}));
                    self.end_in_history(i);
                }
                None => skip(&c),
            },
            Change::Move { id, to } => match self.queue.iter().position(|i| i.id == id) {
                Some(k) => {
                    let i = self.queue.remove(k);
                    let to = to.min(self.queue.len());
                    self.queue.insert(to, i);
                }
                None => skip(&c),
            },
            Change::Clear { at_ms } => {
                for mut i in std::mem::take(&mut self.queue) {
                    i.state = ItemState::Removed;
                    i.result = Some(serde_json::json!({"removed_ms": at_ms}));
                    self.end_in_history(i);
                }
            }
            Change::Options(o) => self.options = o,
            Change::Lock { lock } => self.lock = lock,
            Change::Begin { id, at_ms } => {
                if self.running.is_some() || self.queue.first().map(|i| i.id) != Some(id) {
                    return skip(&c);
                }
                let mut i = self.queue.remove(0);
                i.state = ItemState::Running;
                i.attempts.push(Attempt {
                    started_ms: at_ms,
                    ended_ms: None,
                    outcome: None,
                    message: None,
                });
                self.running = Some(i);
            }
            Change::Pause { paused } => match &mut self.running {
                Some(i) => {
                    i.state = if paused {
                        ItemState::Paused
                    } else {
                        ItemState::Running
                    }
                }
                None => skip(&c),
            },
            Change::Finish {
                outcome,
                message,
                result,
                at_ms,
            } => {
                let Some(mut i) = self.running.take() else {
                    return skip(&Change::Finish {
                        outcome,
                        message,
                        result,
                        at_ms,
                    });
                };
                if let Some(a) = i.attempts.last_mut() {
                    a.ended_ms = Some(at_ms);
                    a.outcome = Some(outcome);
                    a.message = message;
                }
                if result.is_some() {
                    i.result = result;
                }
                let stop = outcome.retried()
                    || self.options.stop_after_current
                    || (outcome == Outcome::Failed && !self.options.continue_on_failure);
                if stop {
                    self.options.running = false;
                }
                self.options.stop_after_current = false;
                if outcome.retried() {
                    i.state = ItemState::Queued;
                    self.queue.insert(0, i);
                } else {
                    i.state = match outcome {
                        Outcome::Done => ItemState::Done,
                        Outcome::Stopped => ItemState::Stopped,
                        _ => ItemState::Failed,
                    };
                    self.end_in_history(i);
                }
            }
            Change::Snapshot(s) => *self = *s,
        }
    }

    /// The state as found at a start: an item that was running when the service ended is
    /// put back at the front, its attempt marked interrupted, and the queue is stopped until
    /// an operator starts it.
    pub fn recovered(&self, now_ms: u64) -> Vec<Change> {
        let mut v = Vec::new();
        if self.running.is_some() {
            v.push(Change::Finish {
                outcome: Outcome::Interrupted,
                message: Some("the service ended while this item ran".into()),
                result: None,
                at_ms: now_ms,
            });
        }
        if self.options.running || self.running.is_some() {
            v.push(Change::Options(Options {
                running: false,
                stop_after_current: false,
                ..self.options
            }));
        }
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mv(x: f64) -> Task {
        Task::Move { x_mm: x, y_mm: 0.0 }
    }

    fn apply(s: &mut State, log: &mut Vec<Change>, r: Request) -> Result<(), QueueError> {
        if let Some(c) = s.plan(r)? {
            log.push(c.clone());
            s.commit(c);
        }
        Ok(())
    }

    fn add(items: Vec<(Task, Option<String>)>, at: Position) -> Request {
        Request::Add {
            items,
            at,
            now_ms: 1,
        }
    }

    fn ids(s: &State) -> Vec<ItemId> {
        s.queue.iter().map(|i| i.id).collect()
    }

    /// A sequence of requests, the changes replayed from their journal rebuild the same
    /// state; positions, keys and attempts behave as documented.
    #[test]
    fn replayed_changes_rebuild_the_state_and_positions_resolve() {
        let mut s = State::default();
        let mut log = vec![];
        let a = |s: &mut State, log: &mut Vec<Change>, r| apply(s, log, r).unwrap();
        a(
            &mut s,
            &mut log,
            add(vec![(mv(1.0), None), (mv(2.0), None)], Position::Back),
        );
        a(
            &mut s,
            &mut log,
            add(vec![(mv(3.0), Some("k".into()))], Position::Front),
        );
        assert_eq!(ids(&s), [2, 0, 1]);
        a(
            &mut s,
            &mut log,
            add(vec![(mv(4.0), None)], Position::After(0)),
        );
        assert_eq!(ids(&s), [2, 0, 3, 1]);
        a(
            &mut s,
            &mut log,
            add(vec![(mv(5.0), None)], Position::Before(2)),
        );
        assert_eq!(ids(&s), [4, 2, 0, 3, 1]);
        // The same key again adds nothing and names the first item.
        a(
            &mut s,
            &mut log,
            add(vec![(mv(9.0), Some("k".into()))], Position::Back),
        );
        assert_eq!(ids(&s), [4, 2, 0, 3, 1]);
        assert_eq!(s.ids_of_keys(["k"].into_iter()), [Some(2)]);
        a(
            &mut s,
            &mut log,
            Request::Move {
                id: 1,
                to: Position::Front,
            },
        );
        assert_eq!(ids(&s), [1, 4, 2, 0, 3]);
        a(
            &mut s,
            &mut log,
            Request::Move {
                id: 1,
                to: Position::After(3),
            },
        );
        assert_eq!(ids(&s), [4, 2, 0, 3, 1]);
        a(
            &mut s,
            &mut log,
            Request::Move {
                id: 4,
                to: Position::Index(2),
            },
        );
        assert_eq!(ids(&s), [2, 0, 4, 3, 1]);
        a(&mut s, &mut log, Request::Remove { id: 0, now_ms: 5 });
        assert_eq!(s.find(0).unwrap().state, ItemState::Removed);
        a(
            &mut s,
            &mut log,
            Request::Edit {
                id: 3,
                task: Task::Home,
            },
        );
        a(
            &mut s,
            &mut log,
            Request::Options(Options {
                running: true,
                ..Default::default()
            }),
        );
        // Run the front item and abort it: back at the front, queue stopped, two attempts
        // after a second run that succeeds.
        let b = s.next_to_run(10).unwrap();
        log.push(b.clone());
        s.commit(b);
        assert_eq!(s.running.as_ref().unwrap().id, 2);
        let f = s.finish(Outcome::Aborted, None, None, 11).unwrap();
        log.push(f.clone());
        s.commit(f);
        assert_eq!(ids(&s)[0], 2);
        assert!(!s.options.running);
        assert!(s.next_to_run(12).is_none());
        s.options.running = true;
        log.push(Change::Options(s.options));
        for c in [
            s.next_to_run(13).unwrap(),
            Change::Finish {
                outcome: Outcome::Done,
                message: None,
                result: Some(serde_json::json!({"ok": 1})),
                at_ms: 14,
            },
        ] {
            log.push(c.clone());
            s.commit(c);
        }
        let done = s.find(2).unwrap();
        assert_eq!(done.state, ItemState::Done);
        assert_eq!(done.attempts.len(), 2);
        assert_eq!(done.attempts[0].outcome, Some(Outcome::Aborted));
        // Replayed through JSON (as the journal holds them): the same state.
        let mut r = State::default();
        for c in &log {
            let j = serde_json::to_vec(c).unwrap();
            r.commit(serde_json::from_slice(&j).unwrap());
        }
        assert_eq!(r, s);
        // A snapshot holds it all.
        let mut t = State::default();
        t.commit(Change::Snapshot(Box::new(s.clone())));
        assert_eq!(t, s);
    }

    #[test]
    fn bad_requests_are_refused_and_change_nothing() {
        let mut s = State::default();
        let mut log = vec![];
        apply(&mut s, &mut log, add(vec![(mv(1.0), None)], Position::Back)).unwrap();
        let before = s.clone();
        let cases: Vec<(Request, QueueError)> = vec![
            (add(vec![], Position::Back), QueueError::Empty),
            (
                add(vec![(mv(1.0), None)], Position::Index(5)),
                QueueError::BadIndex { at: 5, len: 1 },
            ),
            (
                add(vec![(mv(1.0), None)], Position::After(7)),
                QueueError::NoItem(7),
            ),
            (Request::Remove { id: 9, now_ms: 0 }, QueueError::NoItem(9)),
            (
                add(
                    vec![(mv(1.0), Some("a".into())), (mv(2.0), Some("a".into()))],
                    Position::Back,
                ),
                QueueError::DuplicateKey { key: "a".into() },
            ),
            (
                add(vec![(mv(1.0), Some(String::new()))], Position::Back),
                QueueError::BadKey,
            ),
            (
                add(vec![(mv(1.0), None); MAX_QUEUED], Position::Back),
                QueueError::Full {
                    queued: 1,
                    adding: MAX_QUEUED,
                },
            ),
        ];
        for (r, e) in cases {
            assert_eq!(s.plan(r).unwrap_err(), e);
        }
        assert_eq!(s, before);
        // A running or ended item cannot be edited, moved or removed.
        s.options.running = true;
        let b = s.next_to_run(1).unwrap();
        s.commit(b);
        for r in [
            Request::Remove { id: 0, now_ms: 0 },
            Request::Move {
                id: 0,
                to: Position::Front,
            },
            Request::Edit {
                id: 0,
                task: Task::Home,
            },
        ] {
            assert!(matches!(
                s.plan(r),
                Err(QueueError::NotQueued {
                    id: 0,
                    state: ItemState::Running,
                    ..
                })
            ));
        }
    }

    #[test]
    fn a_start_after_a_crash_puts_the_running_item_back_interrupted_and_stops_the_queue() {
        let mut s = State::default();
        let mut log = vec![];
        apply(
            &mut s,
            &mut log,
            add(vec![(mv(1.0), None), (mv(2.0), None)], Position::Back),
        )
        .unwrap();
        s.commit(Change::Options(Options {
            running: true,
            continue_on_failure: true,
            ..Default::default()
        }));
        let b = s.next_to_run(3).unwrap();
        s.commit(b);
        for c in s.recovered(4) {
            s.commit(c);
        }
        assert!(s.running.is_none());
        assert_eq!(ids(&s), [0, 1]);
        let i = &s.queue[0];
        assert_eq!(i.state, ItemState::Queued);
        assert_eq!(i.attempts[0].outcome, Some(Outcome::Interrupted));
        assert!(!s.options.running);
        assert!(s.options.continue_on_failure);
        // A failure stops a queue that does not continue after failures.
        s.commit(Change::Options(Options {
            running: true,
            ..Default::default()
        }));
        let b = s.next_to_run(5).unwrap();
        s.commit(b);
        s.commit(
            s.finish(Outcome::Failed, Some("x".into()), None, 6)
                .unwrap(),
        );
        assert!(!s.options.running);
        assert_eq!(s.find(0).unwrap().state, ItemState::Failed);
    }
}
