//! The service's HTTP face (axum): one table of routes ([`routes`]) gives the router, each
//! route's role, the OpenAPI document and the tests' list. Every error is JSON with a kind and
//! a message; bodies are limited; every request but the event stream has a time limit.

use super::auth::{Role, Tokens};
use super::devices::{DeviceError, Interrupt};
use super::events::{Event as BusEvent, Kind};
use super::hardware::Command;
use super::ledger::LedgerError;
use super::queue::{ItemId, Options, Place, Position, QueueError, Request, Task};
use super::runner::{item_dir, ControlError, Lab};
use super::task::TaskError;
use axum::extract::{FromRequest, Path as UrlPath, Request as HttpRequest, State};
use axum::http::{header, HeaderMap, Method, StatusCode};
use axum::middleware::Next;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{delete, get, patch, post, put, MethodRouter};
use axum::{Json, Router};
use serde::Deserialize;
use serde_json::{json, Value};
use std::sync::Arc;
use std::time::Duration;

/// The largest request body, bytes (a batch of 10 000 items fits).
pub const BODY_LIMIT: usize = 4 << 20;
/// Every request but `/events` is answered within this.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(60);
/// The most event streams at once.
pub const MAX_EVENT_CLIENTS: usize = 1000;
/// A live frame older than this is taken again when asked for (if the hardware is free).
const LOOK_AGE: Duration = Duration::from_millis(200);

#[derive(Clone)]
pub struct App {
    pub lab: Arc<Lab>,
    /// `None`: no tokens configured (loopback only): every client may do everything.
    pub tokens: Option<Arc<Tokens>>,
    pub limits: crate::stage::SoftLimits,
    pub settings: super::devices::Settings,
    pub shutdown: Arc<tokio::sync::Notify>,
}

/// An error as the client sees it: a status, a kind to branch on, a message to show.
#[derive(Debug)]
pub struct ApiError {
    pub status: StatusCode,
    pub kind: &'static str,
    pub message: String,
}

impl ApiError {
    pub fn new(status: StatusCode, kind: &'static str, message: impl Into<String>) -> Self {
        ApiError {
            status,
            kind,
            message: message.into(),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (
            self.status,
            Json(json!({"error": self.kind, "message": self.message})),
        )
            .into_response()
    }
}

impl From<QueueError> for ApiError {
    fn from(e: QueueError) -> Self {
        let (s, k) = match e {
            QueueError::NoItem(_) => (StatusCode::NOT_FOUND, "no_item"),
            QueueError::NotQueued { .. } => (StatusCode::CONFLICT, "not_queued"),
            QueueError::Full { .. } => (StatusCode::INSUFFICIENT_STORAGE, "queue_full"),
            QueueError::BadIndex { .. } => (StatusCode::UNPROCESSABLE_ENTITY, "bad_position"),
            _ => (StatusCode::UNPROCESSABLE_ENTITY, "bad_request"),
        };
        ApiError::new(s, k, e.to_string())
    }
}

impl From<LedgerError> for ApiError {
    fn from(e: LedgerError) -> Self {
        match e {
            LedgerError::Queue(q) => q.into(),
            e => ApiError::new(StatusCode::SERVICE_UNAVAILABLE, "journal", e.to_string()),
        }
    }
}

impl From<DeviceError> for ApiError {
    fn from(e: DeviceError) -> Self {
        use crate::stage::StageError as S;
        let (s, k) = match &e {
            DeviceError::Busy(_) => (StatusCode::CONFLICT, "busy"),
            DeviceError::Stage(S::OutOfLimits { .. }) => {
                (StatusCode::UNPROCESSABLE_ENTITY, "out_of_limits")
            }
            DeviceError::Stage(S::NotHomed) => (StatusCode::CONFLICT, "not_homed"),
            _ => (StatusCode::BAD_GATEWAY, "device"),
        };
        ApiError::new(s, k, e.to_string())
    }
}

impl From<ControlError> for ApiError {
    fn from(e: ControlError) -> Self {
        match e {
            ControlError::Device(d) => d.into(),
            ControlError::Ledger(l) => l.into(),
            e => ApiError::new(StatusCode::CONFLICT, "state", e.to_string()),
        }
    }
}

impl From<TaskError> for ApiError {
    fn from(e: TaskError) -> Self {
        let k = match &e {
            TaskError::Stage(_) | TaskError::Plan(_) => "out_of_limits",
            _ => "bad_task",
        };
        ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, k, e.to_string())
    }
}

/// A JSON body whose every rejection (syntax, wrong type, no content type, too large) is an
/// [`ApiError`] naming what was wrong.
pub struct Body<T>(pub T);

impl<T: serde::de::DeserializeOwned, S: Send + Sync> FromRequest<S> for Body<T> {
    type Rejection = ApiError;
    async fn from_request(req: HttpRequest, state: &S) -> Result<Self, ApiError> {
        use axum::extract::rejection::JsonRejection as J;
        match Json::<T>::from_request(req, state).await {
            Ok(Json(v)) => Ok(Body(v)),
            Err(e) => {
                let kind = match &e {
                    J::JsonDataError(_) => "wrong_type",
                    J::JsonSyntaxError(_) => "malformed_json",
                    J::MissingJsonContentType(_) => "content_type",
                    // Too large (413) or unreadable.
                    _ => "body",
                };
                Err(ApiError::new(e.status(), kind, e.body_text()))
            }
        }
    }
}

type Answer = Result<Json<Value>, ApiError>;

/// One route: what the router, the roles, the OpenAPI document and the tests share.
pub struct Route {
    pub method: Method,
    pub path: &'static str,
    /// `None`: open to anyone (the page).
    pub role: Option<Role>,
    pub summary: &'static str,
    /// A long-lived stream: no time limit.
    pub stream: bool,
    pub handler: MethodRouter<App>,
}

fn route(
    method: Method,
    path: &'static str,
    role: Option<Role>,
    summary: &'static str,
    handler: MethodRouter<App>,
) -> Route {
    Route {
        method,
        path,
        role,
        summary,
        stream: false,
        handler,
    }
}

/// Every route of the service.
pub fn routes() -> Vec<Route> {
    use Role::{Admin, Observer, Operator};
    let o = Some(Observer);
    let op = Some(Operator);
    let mut events = route(
        Method::GET,
        "/api/v1/events",
        o,
        "Server-Sent Events, each with a sequence number; Last-Event-ID replays what was missed",
        get(events),
    );
    events.stream = true;
    vec![
        route(Method::GET, "/", None, "The live view (HTML)", get(page)),
        route(
            Method::GET,
            "/api/v1/status",
            o,
            "The service's status: queue, running item, stage",
            get(status),
        ),
        route(
            Method::GET,
            "/api/v1/queue",
            o,
            "The queue and the running item",
            get(queue),
        ),
        route(
            Method::GET,
            "/api/v1/history",
            o,
            "Ended items, newest last",
            get(history),
        ),
        route(
            Method::GET,
            "/api/v1/items/{id}",
            o,
            "One item wherever it is, with its attempts, folder and result",
            get(item),
        ),
        route(
            Method::POST,
            "/api/v1/queue/items",
            op,
            "Add items: {items: [{task, key?}], at?}",
            post(add),
        ),
        route(
            Method::PATCH,
            "/api/v1/queue/items/{id}",
            op,
            "Edit a waiting item's task: {task}",
            patch(edit),
        ),
        route(
            Method::DELETE,
            "/api/v1/queue/items/{id}",
            op,
            "Remove a waiting item",
            delete(remove),
        ),
        route(
            Method::POST,
            "/api/v1/queue/items/{id}/move",
            op,
            "Move a waiting item: {to}",
            post(move_item),
        ),
        route(
            Method::POST,
            "/api/v1/queue/clear",
            op,
            "Remove every waiting item",
            post(clear),
        ),
        route(
            Method::POST,
            "/api/v1/queue/start",
            op,
            "Start the queue",
            post(start),
        ),
        route(
            Method::POST,
            "/api/v1/queue/stop",
            op,
            "Stop the queue after the running item",
            post(stop_queue),
        ),
        route(
            Method::PUT,
            "/api/v1/queue/options",
            op,
            "Set autostart and continue_on_failure",
            put(options),
        ),
        route(
            Method::POST,
            "/api/v1/run/pause",
            op,
            "Pause the running item: {immediate?}",
            post(pause),
        ),
        route(
            Method::POST,
            "/api/v1/run/resume",
            op,
            "Resume the paused item",
            post(resume),
        ),
        route(
            Method::POST,
            "/api/v1/run/stop",
            op,
            "End the running item at the next tile, done",
            post(run_stop),
        ),
        route(
            Method::POST,
            "/api/v1/run/abort",
            op,
            "Stop the stages now; the item goes back to the front",
            post(abort),
        ),
        route(
            Method::POST,
            "/api/v1/run/halt",
            op,
            "Reset the controller now, from any state",
            post(halt),
        ),
        route(
            Method::POST,
            "/api/v1/stage/jog",
            op,
            "Jog by {dx_mm, dy_mm} (idle only)",
            post(jog),
        ),
        route(
            Method::GET,
            "/api/v1/live.png",
            o,
            "The newest frame (PNG)",
            get(live),
        ),
        events,
        route(
            Method::GET,
            "/api/v1/openapi.json",
            o,
            "This API's OpenAPI document",
            get(openapi),
        ),
        route(
            Method::POST,
            "/api/v1/shutdown",
            Some(Admin),
            "End the service (the queue is kept)",
            post(shutdown),
        ),
    ]
}

/// The bearer token's role, or the error for its absence.
fn role_of(app: &App, headers: &HeaderMap) -> Result<Role, ApiError> {
    let Some(tokens) = &app.tokens else {
        return Ok(Role::Admin);
    };
    let token = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .ok_or_else(|| {
            ApiError::new(
                StatusCode::UNAUTHORIZED,
                "no_token",
                "this service needs a token: Authorization: Bearer TOKEN",
            )
        })?;
    tokens.check(token.trim()).map(|t| t.role).ok_or_else(|| {
        ApiError::new(
            StatusCode::UNAUTHORIZED,
            "unknown_token",
            "the token is not known here",
        )
    })
}

/// Builds the router from [`routes`].
pub fn router(app: App) -> Router {
    let mut r = Router::new();
    for rt in routes() {
        let need = rt.role;
        let stream = rt.stream;
        let a = app.clone();
        let guarded = rt.handler.route_layer(axum::middleware::from_fn(
            move |req: HttpRequest, next: Next| {
                let a = a.clone();
                async move {
                    if let Some(need) = need {
                        match role_of(&a, req.headers()) {
                            Err(e) => return e.into_response(),
                            Ok(have) if have < need => {
                                return ApiError::new(
                                    StatusCode::FORBIDDEN,
                                    "role",
                                    format!(
                                        "this needs the {} role; the token has {}",
                                        need.name(),
                                        have.name()
                                    ),
                                )
                                .into_response()
                            }
                            Ok(_) => {}
                        }
                    }
                    if stream {
                        return next.run(req).await;
                    }
                    match tokio::time::timeout(REQUEST_TIMEOUT, next.run(req)).await {
                        Ok(r) => r,
                        Err(_) => ApiError::new(
                            StatusCode::GATEWAY_TIMEOUT,
                            "timeout",
                            format!("no answer within {} s", REQUEST_TIMEOUT.as_secs()),
                        )
                        .into_response(),
                    }
                }
            },
        ));
        r = r.route(rt.path, guarded);
    }
    r.fallback(|| async {
        ApiError::new(
            StatusCode::NOT_FOUND,
            "no_route",
            "no such route: GET /api/v1/openapi.json lists them",
        )
    })
    .layer(axum::extract::DefaultBodyLimit::max(BODY_LIMIT))
    .with_state(app)
}

fn ok(v: Value) -> Answer {
    Ok(Json(v))
}

async fn page() -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "text/html; charset=utf-8")],
        include_str!("page.html"),
    )
}

async fn status(State(app): State<App>) -> Answer {
    let (options, running, queued) = app.lab.ledger.read(|s| {
        (
            s.options,
            s.running
                .as_ref()
                .map(|i| json!({"id": i.id, "state": i.state})),
            s.queue.len(),
        )
    });
    let stage = match app.lab.hw.ask(Command::Status).await {
        Ok(st) => {
            json!({"position": super::devices::position_json(st.position), "homed": st.homed, "state": format!("{:?}", st.state)})
        }
        Err(e) => json!({"unavailable": e.to_string()}),
    };
    ok(json!({
        "options": options,
        "running": running,
        "queued": queued,
        "stage": stage,
        "limits": {"x_mm": [app.limits.min.x_mm(), app.limits.max.x_mm()], "y_mm": [app.limits.min.y_mm(), app.limits.max.y_mm()]},
        "next_event": app.lab.ledger.bus.next_seq(),
        "event_clients": app.lab.ledger.bus.clients(),
    }))
}

async fn queue(State(app): State<App>) -> Answer {
    ok(app
        .lab
        .ledger
        .read(|s| json!({"queue": s.queue, "running": s.running, "options": s.options})))
}

async fn history(State(app): State<App>) -> Answer {
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

async fn item(State(app): State<App>, UrlPath(id): UrlPath<String>) -> Answer {
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
    let dir = item_dir(&app.lab.data, id);
    ok(json!({"item": it, "where": place, "index": index, "dir": dir.exists().then_some(dir)}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct NewItem {
    task: Task,
    key: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AddBody {
    items: Vec<NewItem>,
    #[serde(default)]
    at: Position,
}

async fn add(State(app): State<App>, Body(b): Body<AddBody>) -> Answer {
    // Refused before each task is checked (a scan's check plans it).
    let queued = app.lab.ledger.read(|s| s.queue.len());
    if queued + b.items.len() > super::queue::MAX_QUEUED {
        return Err(QueueError::Full {
            queued,
            adding: b.items.len(),
        }
        .into());
    }
    for (i, it) in b.items.iter().enumerate() {
        super::task::check(&it.task, &app.limits, &app.settings).map_err(|e| {
            let mut a: ApiError = e.into();
            a.message = format!("items[{i}]: {}", a.message);
            a
        })?;
    }
    let keys: Vec<Option<String>> = b.items.iter().map(|i| i.key.clone()).collect();
    let change = app.lab.ledger.request(Request::Add {
        items: b.items.into_iter().map(|i| (i.task, i.key)).collect(),
        at: b.at,
        now_ms: super::events::now_ms(),
    })?;
    // The ids in the order given: new items' from the change, repeated keys' from the state.
    let inserted: Vec<ItemId> = match &change {
        Some(super::queue::Change::Insert { items, .. }) => items.iter().map(|i| i.id).collect(),
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
            super::queue::Change::Options(Options {
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
struct EditBody {
    task: Task,
}

async fn edit(
    State(app): State<App>,
    UrlPath(id): UrlPath<String>,
    Body(b): Body<EditBody>,
) -> Answer {
    let id = parse_id(&id)?;
    super::task::check(&b.task, &app.limits, &app.settings)?;
    app.lab.ledger.request(Request::Edit { id, task: b.task })?;
    ok(json!({"id": id}))
}

async fn remove(State(app): State<App>, UrlPath(id): UrlPath<String>) -> Answer {
    let id = parse_id(&id)?;
    app.lab.ledger.request(Request::Remove {
        id,
        now_ms: super::events::now_ms(),
    })?;
    ok(json!({"id": id}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MoveBody {
    to: Position,
}

async fn move_item(
    State(app): State<App>,
    UrlPath(id): UrlPath<String>,
    Body(b): Body<MoveBody>,
) -> Answer {
    let id = parse_id(&id)?;
    app.lab.ledger.request(Request::Move { id, to: b.to })?;
    ok(json!({"id": id}))
}

async fn clear(State(app): State<App>) -> Answer {
    app.lab.ledger.request(Request::Clear {
        now_ms: super::events::now_ms(),
    })?;
    ok(json!({}))
}

async fn start(State(app): State<App>) -> Answer {
    app.lab.ledger.change(|s| {
        Some(super::queue::Change::Options(Options {
            running: true,
            stop_after_current: false,
            ..s.options
        }))
    })?;
    app.lab.kick();
    ok(json!({"running": true}))
}

async fn stop_queue(State(app): State<App>) -> Answer {
    let after = app.lab.ledger.change(|s| {
        Some(super::queue::Change::Options(match s.running {
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
        json!({"stop_after_current": matches!(after, Some(super::queue::Change::Options(o)) if o.stop_after_current)}),
    )
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct OptionsBody {
    autostart: Option<bool>,
    continue_on_failure: Option<bool>,
}

async fn options(State(app): State<App>, Body(b): Body<OptionsBody>) -> Answer {
    let c = app.lab.ledger.change(|s| {
        Some(super::queue::Change::Options(Options {
            autostart: b.autostart.unwrap_or(s.options.autostart),
            continue_on_failure: b
                .continue_on_failure
                .unwrap_or(s.options.continue_on_failure),
            ..s.options
        }))
    })?;
    ok(
        json!({"options": c.map(|c| match c { super::queue::Change::Options(o) => json!(o), _ => Value::Null })}),
    )
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct PauseBody {
    #[serde(default)]
    immediate: bool,
}

async fn pause(State(app): State<App>, body: axum::body::Bytes) -> Answer {
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

async fn resume(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.resume()?}))
}

async fn run_stop(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.end(Interrupt::Stop).await?}))
}

async fn abort(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.end(Interrupt::Abort).await?}))
}

async fn halt(State(app): State<App>) -> Answer {
    ok(json!({"id": app.lab.end(Interrupt::Halt).await?}))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JogBody {
    dx_mm: f64,
    dy_mm: f64,
}

async fn jog(State(app): State<App>, Body(b): Body<JogBody>) -> Answer {
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
    ok(json!({"position": super::devices::position_json(at)}))
}

async fn live(State(app): State<App>) -> Result<Response, ApiError> {
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
        ],
        look.png.as_ref().clone(),
    )
        .into_response())
}

fn sse_of(e: &BusEvent) -> Event {
    Event::default()
        .id(e.seq.to_string())
        .event(e.kind.name())
        .data(json!({"seq": e.seq, "at_ms": e.at_ms, "data": e.data}).to_string())
}

fn resync(why: &str) -> Event {
    Event::default()
        .event(Kind::Resync.name())
        .data(json!({"message": why}).to_string())
}

async fn events(
    State(app): State<App>,
    headers: HeaderMap,
) -> Result<Sse<impl futures_util::Stream<Item = Result<Event, std::convert::Infallible>>>, ApiError>
{
    let bus = app.lab.ledger.bus.clone();
    if bus.clients() >= MAX_EVENT_CLIENTS {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "too_many_clients",
            format!("at most {MAX_EVENT_CLIENTS} event streams at once"),
        ));
    }
    let last = headers
        .get("last-event-id")
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    let sub = bus.subscribe(last);
    let mut first: Vec<Event> = Vec::new();
    if sub.gap {
        first.push(resync(
            "the events since your last one are no longer kept: read the state afresh",
        ));
    }
    first.extend(sub.missed.iter().map(|e| sse_of(e)));
    let head = futures_util::stream::iter(first.into_iter().map(Ok));
    let live = futures_util::stream::unfold(Some(sub.live), |rx| async move {
        let mut rx = rx?;
        match rx.recv().await {
            Ok(e) => Some((Ok(sse_of(&e)), Some(rx))),
            // Fell a whole backlog behind: told to resync, then dropped.
            Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => Some((
                Ok(resync(&format!("you fell {n} events behind and are disconnected: read the state afresh and reconnect"))),
                None,
            )),
            Err(tokio::sync::broadcast::error::RecvError::Closed) => None,
        }
    });
    use futures_util::StreamExt;
    Ok(Sse::new(head.chain(live)).keep_alive(KeepAlive::default()))
}

async fn openapi() -> Answer {
    let all = routes();
    ok(super::openapi::document(all.iter().map(|r| {
        super::openapi::Described {
            method: r.method.as_str(),
            path: r.path,
            role: r.role,
            summary: r.summary,
        }
    })))
}

async fn shutdown(State(app): State<App>) -> Answer {
    app.shutdown.notify_one();
    ok(json!({"shutting_down": true}))
}
