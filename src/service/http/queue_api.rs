//! Reading the queue and the history, and changing the queue.

use super::error::{ApiError, Body};
use super::{ok, Answer, App};
use crate::service::auth::Role;
use crate::service::hardware::Command;
use crate::service::queue::{ItemId, Options, Place, Position, QueueError, Request, Task};
use crate::service::runner::item_dir;
use axum::extract::{Path as UrlPath, State};
use axum::http::StatusCode;
use serde::Deserialize;
use serde_json::{json, Value};

pub(super) async fn status(State(app): State<App>) -> Answer {
    let (options, lock, running, queued) = app.lab.ledger.read(|s| {
        (
            s.options,
            s.lock.clone(),
            s.running
                .as_ref()
                .map(|i| json!({"id": i.id, "state": i.state})),
            s.queue.len(),
        )
    });
    let stage = match app.lab.hw.ask(Command::Status).await {
        Ok(st) => {
            json!({"position": crate::service::devices::position_json(st.position), "homed": st.homed, "state": format!("{:?}", st.state)})
        }
        Err(e) => json!({"unavailable": e.to_string()}),
    };
    ok(json!({
        "options": options,
        "lock": lock,
        "running": running,
        "queued": queued,
        "stage": stage,
        "limits": {"x_mm": [app.limits.min.x_mm(), app.limits.max.x_mm()], "y_mm": [app.limits.min.y_mm(), app.limits.max.y_mm()]},
        "next_event": app.lab.ledger.bus.next_seq(),
        "event_clients": app.lab.ledger.bus.clients(),
        // The simulator's film ("laid", "lifted"); null on real hardware.
        "sim_film": app.lab.hw.sim_film.as_ref().map(|f| {
            if f.load(std::sync::atomic::Ordering::SeqCst) { "laid" } else { "lifted" }
        }),
    }))
}

pub(super) async fn queue(State(app): State<App>) -> Answer {
    ok(app
        .lab
        .ledger
        .read(|s| json!({"queue": s.queue, "running": s.running, "options": s.options})))
}

pub(super) async fn history(State(app): State<App>) -> Answer {
    ok(app.lab.ledger.read(|s| json!({"history": s.history})))
}

fn parse_id(s: &str) -> Result<ItemId, ApiError> {
    s.parse().map_err(|_| {
        ApiError::new(
            StatusCode::BAD_REQUEST,
            "bad_id",
            format!("{s:?} is not an item id (a whole number)"),
        )
    })
}

pub(super) async fn item(State(app): State<App>, UrlPath(id): UrlPath<String>) -> Answer {
    let id = parse_id(&id)?;
    let (it, place) = app
        .lab
        .ledger
        .read(|s| s.locate(id).map(|(i, p)| (i.clone(), p)))
        .ok_or(QueueError::NoItem(id))?;
    let (place, index) = match place {
        Place::Queue(k) => ("queue", Some(k)),
        Place::Running => ("running", None),
        Place::History => ("history", None),
    };
    // Its folder: a scan's under the service's data, a calibration's session in the store.
    let dir = Some(item_dir(&app.lab.data, id))
        .filter(|d| d.exists())
        .or_else(|| {
            let session = it.result.as_ref()?.get("session")?.as_str()?;
            Some(std::path::PathBuf::from(session))
        });
    ok(json!({"item": it, "where": place, "index": index, "dir": dir}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct NewItem {
    task: Task,
    key: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct AddBody {
    items: Vec<NewItem>,
    #[serde(default)]
    at: Position,
}

pub(super) async fn add(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
    Body(b): Body<AddBody>,
) -> Answer {
    // Refused before each task is checked (a scan's check plans it).
    let queued = app.lab.ledger.read(|s| s.queue.len());
    if queued + b.items.len() > crate::service::queue::MAX_QUEUED {
        return Err(QueueError::Full {
            queued,
            adding: b.items.len(),
        }
        .into());
    }
    for (i, it) in b.items.iter().enumerate() {
        crate::service::task::check(&it.task, &app.limits, &app.settings).map_err(|e| {
            let mut a: ApiError = e.into();
            a.message = format!("items[{i}]: {}", a.message);
            a
        })?;
    }
    let keys: Vec<Option<String>> = b.items.iter().map(|i| i.key.clone()).collect();
    let change = app.lab.ledger.request_as(
        caller.role == Role::Admin,
        Request::Add {
            items: b.items.into_iter().map(|i| (i.task, i.key)).collect(),
            at: b.at,
            now_ms: crate::service::events::now_ms(),
        },
    )?;
    // The ids in the order given: new items' from the change, repeated keys' from the state.
    let inserted: Vec<ItemId> = match &change {
        Some(crate::service::queue::Change::Insert { items, .. }) => {
            items.iter().map(|i| i.id).collect()
        }
        _ => vec![],
    };
    let seen = app
        .lab
        .ledger
        .read(|s| s.ids_of_keys(keys.iter().map(|k| k.as_deref().unwrap_or(""))));
    let mut fresh = inserted.iter();
    let ids: Vec<Option<ItemId>> = keys
        .iter()
        .zip(seen)
        .map(|(k, old)| match (k, old) {
            (Some(_), Some(id)) if !inserted.contains(&id) => Some(id),
            _ => fresh.next().copied(),
        })
        .collect();
    app.lab.ledger.change(|s| {
        (s.options.autostart && !s.options.running && s.running.is_none()).then_some(
            crate::service::queue::Change::Options(Options {
                running: true,
                ..s.options
            }),
        )
    })?;
    app.lab.kick();
    ok(json!({"ids": ids, "added": change.is_some()}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct EditBody {
    task: Task,
}

pub(super) async fn edit(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
    UrlPath(id): UrlPath<String>,
    Body(b): Body<EditBody>,
) -> Answer {
    let id = parse_id(&id)?;
    crate::service::task::check(&b.task, &app.limits, &app.settings)?;
    app.lab.ledger.request_as(
        caller.role == Role::Admin,
        Request::Edit { id, task: b.task },
    )?;
    ok(json!({"id": id}))
}

pub(super) async fn remove(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
    UrlPath(id): UrlPath<String>,
) -> Answer {
    let id = parse_id(&id)?;
    app.lab.ledger.request_as(
        caller.role == Role::Admin,
        Request::Remove {
            id,
            now_ms: crate::service::events::now_ms(),
        },
    )?;
    ok(json!({"id": id}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct MoveBody {
    to: Position,
}

pub(super) async fn move_item(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
    UrlPath(id): UrlPath<String>,
    Body(b): Body<MoveBody>,
) -> Answer {
    let id = parse_id(&id)?;
    app.lab
        .ledger
        .request_as(caller.role == Role::Admin, Request::Move { id, to: b.to })?;
    ok(json!({"id": id}))
}

pub(super) async fn clear(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
) -> Answer {
    app.lab.ledger.request_as(
        caller.role == Role::Admin,
        Request::Clear {
            now_ms: crate::service::events::now_ms(),
        },
    )?;
    ok(json!({}))
}

pub(super) async fn start(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
) -> Answer {
    app.lab.ledger.change_as(caller.role == Role::Admin, |s| {
        Some(crate::service::queue::Change::Options(Options {
            running: true,
            stop_after_current: false,
            ..s.options
        }))
    })?;
    app.lab.kick();
    ok(json!({"running": true}))
}

pub(super) async fn stop_queue(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
) -> Answer {
    let after = app.lab.ledger.change_as(caller.role == Role::Admin, |s| {
        Some(crate::service::queue::Change::Options(match s.running {
            Some(_) => Options {
                stop_after_current: true,
                ..s.options
            },
            None => Options {
                running: false,
                ..s.options
            },
        }))
    })?;
    ok(
        json!({"stop_after_current": matches!(after, Some(crate::service::queue::Change::Options(o)) if o.stop_after_current)}),
    )
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct OptionsBody {
    autostart: Option<bool>,
    continue_on_failure: Option<bool>,
}

pub(super) async fn options(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
    Body(b): Body<OptionsBody>,
) -> Answer {
    let c = app.lab.ledger.change_as(caller.role == Role::Admin, |s| {
        Some(crate::service::queue::Change::Options(Options {
            autostart: b.autostart.unwrap_or(s.options.autostart),
            continue_on_failure: b
                .continue_on_failure
                .unwrap_or(s.options.continue_on_failure),
            ..s.options
        }))
    })?;
    ok(
        json!({"options": c.map(|c| match c { crate::service::queue::Change::Options(o) => json!(o), _ => Value::Null })}),
    )
}
