//! Control of the running item, the stage's jog, the live frame and the service's end.

use super::error::{ApiError, Body};
use super::{ok, Answer, App, LOOK_AGE};
use crate::service::devices::{DeviceError, Interrupt};
use crate::service::hardware::Command;
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use serde_json::json;

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct PauseBody {
    #[serde(default)]
    immediate: bool,
}

pub(super) async fn pause(State(app): State<App>, body: axum::body::Bytes) -> Answer {
    // No body: a deferred pause.
    let b: PauseBody = if body.iter().all(|c| c.is_ascii_whitespace()) {
        PauseBody::default()
    } else {
        serde_json::from_slice(&body).map_err(|e| {
            ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "bad_body", e.to_string())
        })?
    };
    let id = app.lab.pause(b.immediate)?;
    ok(json!({"id": id, "immediate": b.immediate}))
}

pub(super) async fn resume(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.resume()?}))
}

pub(super) async fn run_stop(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.end(Interrupt::Stop).await?}))
}

pub(super) async fn abort(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.end(Interrupt::Abort).await?}))
}

pub(super) async fn halt(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.end(Interrupt::Halt).await?}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct JogBody {
    dx_mm: f64,
    dy_mm: f64,
}

pub(super) async fn jog(State(app): State<App>, Body(b): Body<JogBody>) -> Answer {
    let span = (app.limits.max.x_mm() - app.limits.min.x_mm())
        .max(app.limits.max.y_mm() - app.limits.min.y_mm());
    for (f, v) in [("dx_mm", b.dx_mm), ("dy_mm", b.dy_mm)] {
        if !(v.is_finite() && v.abs() <= span) {
            return Err(ApiError::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                "bad_jog",
                format!("{f} = {v}: a jog is at most the travel, ±{span:.1} mm"),
            ));
        }
    }
    let delta = crate::coords::CarriageUm::from_mm(b.dx_mm, b.dy_mm);
    let at = app
        .lab
        .hw
        .ask(|reply| Command::Jog { delta, reply })
        .await?;
    ok(json!({"position": crate::service::devices::position_json(at)}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct FilmBody {
    laid: bool,
}

/// The simulator's film laid on the carriage or lifted off (what an operator's hands do
/// before a pixel calibration on the plate, and after it for a scan).
pub(super) async fn sim_film(State(app): State<App>, Body(b): Body<FilmBody>) -> Answer {
    app.lab
        .hw
        .ask(|reply| Command::SimFilm {
            laid: b.laid,
            reply,
        })
        .await?;
    let state = if b.laid { "laid" } else { "lifted" };
    app.lab.ledger.bus.publish(
        crate::service::events::Kind::Status,
        json!({"sim_film": state}),
    );
    ok(json!({"sim_film": state}))
}

pub(super) async fn live(State(app): State<App>) -> Result<Response, ApiError> {
    let fresh = {
        let l = app
            .lab
            .hw
            .last_look
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        l.clone()
    };
    let look = match (app.lab.hw.busy_with(), fresh) {
        // A scan runs: its newest tile.
        (Some(_), Some(l)) => l,
        (Some(id), None) => return Err(DeviceError::Busy(id).into()),
        (None, l) => match l {
            Some(l) if l.taken.elapsed() < LOOK_AGE => l,
            _ => app.lab.hw.ask(Command::Look).await?,
        },
    };
    Ok((
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (
                header::HeaderName::from_static("x-frame-number"),
                look.number.to_string(),
            ),
            (
                header::HeaderName::from_static("x-image-size"),
                format!("{},{}", look.size[0], look.size[1]),
            ),
        ],
        look.png.as_ref().clone(),
    )
        .into_response())
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct LockBody {
    note: String,
}

/// The longest lock note, bytes.
const MAX_NOTE: usize = 500;

pub(super) async fn lock(
    State(app): State<App>,
    axum::Extension(caller): axum::Extension<super::Caller>,
    Body(b): Body<LockBody>,
) -> Answer {
    if b.note.trim().is_empty() || b.note.len() > MAX_NOTE {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "bad_note",
            format!("say why, in 1 to {MAX_NOTE} bytes: the operators see it"),
        ));
    }
    let lock = crate::service::queue::Lock {
        by: caller.name,
        note: b.note,
        since_ms: crate::service::events::now_ms(),
    };
    app.lab.ledger.change(|_| {
        Some(crate::service::queue::Change::Lock {
            lock: Some(lock.clone()),
        })
    })?;
    ok(json!({ "lock": lock }))
}

pub(super) async fn unlock(State(app): State<App>) -> Answer {
    let was = app.lab.ledger.read(|s| s.lock.clone());
    app.lab.ledger.change(|s| {
        s.lock
            .is_some()
            .then_some(crate::service::queue::Change::Lock { lock: None })
    })?;
    ok(json!({ "was": was }))
}

pub(super) async fn shutdown(State(app): State<App>) -> Answer {
    app.shutdown.notify_one();
    ok(json!({"shutting_down": true}))
}
