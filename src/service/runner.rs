//! Runs the queue: starts the front item when the queue runs and the hardware is free, waits
//! for its end, records it, and in between takes the operator's pause, resume, stop, abort
//! and halt (bluesky's queue server's verbs, with GRBL's hold and reset beneath them).

use super::devices::{DeviceError, Ended, Interrupt, Ran};
use super::events::now_ms;
use super::hardware::{Command, Handle};
use super::ledger::{Ledger, LedgerError};
use super::queue::{Change, ItemId, ItemState, Outcome, Task};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tokio::sync::{mpsc, oneshot};

/// Folder of item `id`'s files under the service's data folder.
pub fn item_dir(data: &Path, id: ItemId) -> PathBuf {
    data.join("items").join(id.to_string())
}

/// What the runner is told between items and while one is paused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Msg {
    /// Look at the queue again (an item was added, the queue was started).
    Kick,
    Resume,
    Stop,
    Abort,
    Halt,
}

#[derive(Debug, thiserror::Error)]
pub enum ControlError {
    #[error("no item is running")]
    NothingRunning,
    #[error("item {0} is not paused")]
    NotPaused(ItemId),
    #[error("item {0} is already paused")]
    AlreadyPaused(ItemId),
    #[error(transparent)]
    Device(#[from] DeviceError),
    #[error(transparent)]
    Ledger(#[from] LedgerError),
}

/// The service as the routes see it.
pub struct Lab {
    pub ledger: Arc<Ledger>,
    pub hw: Arc<Handle>,
    pub data: PathBuf,
    tx: mpsc::UnboundedSender<Msg>,
}

impl Lab {
    /// The lab and its runner (to spawn on the runtime).
    pub fn new(
        ledger: Arc<Ledger>,
        hw: Arc<Handle>,
        data: PathBuf,
    ) -> (Arc<Lab>, impl std::future::Future<Output = ()>) {
        let (tx, rx) = mpsc::unbounded_channel();
        let lab = Arc::new(Lab {
            ledger,
            hw,
            data,
            tx,
        });
        let run = runner(lab.clone(), rx);
        (lab, run)
    }

    pub fn kick(&self) {
        let _ = self.tx.send(Msg::Kick);
    }

    fn running(&self) -> Option<(ItemId, ItemState)> {
        self.ledger
            .read(|s| s.running.as_ref().map(|i| (i.id, i.state)))
    }

    /// Pause the running item: at the next tile (`immediate` false) or now, the tile being
    /// taken to be taken again.
    pub fn pause(&self, immediate: bool) -> Result<ItemId, ControlError> {
        match self.running() {
            None => Err(ControlError::NothingRunning),
            Some((id, ItemState::Paused)) => Err(ControlError::AlreadyPaused(id)),
            Some((id, _)) => {
                self.hw.control.interrupt(if immediate {
                    Interrupt::PauseNow
                } else {
                    Interrupt::Pause
                });
                Ok(id)
            }
        }
    }

    pub fn resume(&self) -> Result<ItemId, ControlError> {
        match self.running() {
            None => Err(ControlError::NothingRunning),
            Some((id, ItemState::Paused)) => {
                let _ = self.tx.send(Msg::Resume);
                Ok(id)
            }
            Some((id, _)) => Err(ControlError::NotPaused(id)),
        }
    }

    /// Stop (ends done at the next tile), abort (stages stopped now, the item back at the
    /// front) or halt (controller reset now; from any state, also with nothing running).
    pub async fn end(&self, how: Interrupt) -> Result<Option<ItemId>, ControlError> {
        let msg = match how {
            Interrupt::Stop => Msg::Stop,
            Interrupt::Abort => Msg::Abort,
            Interrupt::Halt => Msg::Halt,
            Interrupt::Pause | Interrupt::PauseNow => unreachable!("pauses are not ends"),
        };
        match self.running() {
            Some((id, ItemState::Paused)) => {
                let _ = self.tx.send(msg);
                Ok(Some(id))
            }
            Some((id, _)) => {
                self.hw.control.interrupt(how);
                Ok(Some(id))
            }
            None if how == Interrupt::Halt => {
                let what = self.hw.ask(Command::Halt).await?;
                self.ledger.bus.publish(
                    super::events::Kind::Log,
                    serde_json::json!({"message": what}),
                );
                Ok(None)
            }
            None => Err(ControlError::NothingRunning),
        }
    }
}

fn outcome_of(e: Ended) -> Option<Outcome> {
    Some(match e {
        Ended::Done => Outcome::Done,
        Ended::Failed => Outcome::Failed,
        Ended::Stopped => Outcome::Stopped,
        Ended::Aborted => Outcome::Aborted,
        Ended::Halted => Outcome::Halted,
        Ended::Paused => return None,
    })
}

async fn run_once(lab: &Lab, id: ItemId, task: &Task) -> Ran {
    let (tx, rx) = oneshot::channel();
    let sent = lab.hw.run(id, task.clone(), item_dir(&lab.data, id), tx);
    let gone = || Ran {
        ended: Ended::Failed,
        message: Some(DeviceError::Gone.to_string()),
        result: None,
    };
    if sent.is_err() {
        return gone();
    }
    rx.await.unwrap_or_else(|_| gone())
}

fn record(lab: &Lab, c: Change) {
    if let Err(e) = lab.ledger.change(|_| Some(c)) {
        // The state stays as the disk has it; the operator is told.
        tracing::error!("{e}");
        lab.ledger.bus.publish(
            super::events::Kind::Warning,
            serde_json::json!({"message": e.to_string()}),
        );
    }
}

async fn runner(lab: Arc<Lab>, mut rx: mpsc::UnboundedReceiver<Msg>) {
    loop {
        let began = lab.ledger.change(|s| s.next_to_run(now_ms()));
        let (id, task) = match began {
            Ok(Some(Change::Begin { id, .. })) => {
                let task = lab
                    .ledger
                    .read(|s| s.running.as_ref().map(|i| i.task.clone()));
                match task {
                    Some(t) => (id, t),
                    None => continue,
                }
            }
            Ok(_) => {
                // Nothing to start: wait to be told (messages for a paused item are stale).
                if rx.recv().await.is_none() {
                    return;
                }
                continue;
            }
            Err(e) => {
                tracing::error!("{e}");
                if rx.recv().await.is_none() {
                    return;
                }
                continue;
            }
        };
        loop {
            let ran = run_once(&lab, id, &task).await;
            if let Some(o) = outcome_of(ran.ended) {
                record(
                    &lab,
                    Change::Finish {
                        outcome: o,
                        message: ran.message,
                        result: ran.result,
                        at_ms: now_ms(),
                    },
                );
                break;
            }
            record(&lab, Change::Pause { paused: true });
            // Paused: wait for the operator.
            let end = loop {
                match rx.recv().await {
                    None => return,
                    Some(Msg::Kick) => continue,
                    Some(Msg::Resume) => break None,
                    Some(Msg::Stop) => break Some((Outcome::Stopped, None)),
                    Some(Msg::Abort) => break Some((Outcome::Aborted, None)),
                    Some(Msg::Halt) => {
                        let what = match lab.hw.ask(Command::Halt).await {
                            Ok(w) => w,
                            Err(e) => format!("the halt's reset was not confirmed: {e}"),
                        };
                        break Some((Outcome::Halted, Some(what)));
                    }
                }
            };
            match end {
                None => record(&lab, Change::Pause { paused: false }),
                Some((o, message)) => {
                    record(
                        &lab,
                        Change::Finish {
                            outcome: o,
                            message,
                            result: None,
                            at_ms: now_ms(),
                        },
                    );
                    break;
                }
            }
        }
    }
}
