//! The service's HTTP face (axum): one table of routes ([`routes`]) gives the router, each
//! route's role, the OpenAPI document and the tests' list. Every error is JSON with a kind and
//! a message; bodies are limited; every request but the event stream has a time limit.

mod calibration_api;
mod error;
mod queue_api;
mod run_api;
mod stream;

pub use error::{ApiError, Body};

use super::auth::{Role, Tokens};
use super::runner::Lab;
use axum::extract::Request as HttpRequest;
use axum::http::{header, HeaderMap, Method, StatusCode};
use axum::middleware::Next;
use axum::response::IntoResponse;
use axum::routing::{delete, get, patch, post, put, MethodRouter};
use axum::{Json, Router};
use serde_json::Value;
use std::sync::Arc;
use std::time::Duration;

/// The largest request body, bytes (a batch of 10 000 items fits).
pub const BODY_LIMIT: usize = 4 << 20;
/// Every request but `/events` is answered within this.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(60);
/// The most event streams at once (and at most three quarters of the connections, so that a
/// halt or an abort always finds one free).
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
    /// The most event streams at once: [`MAX_EVENT_CLIENTS`], and a quarter of the
    /// connections left for everything else.
    pub max_event_clients: usize,
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
    /// Refused below the admin role while an admin's lock is set.
    pub lockable: bool,
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
        lockable: false,
        handler,
    }
}

impl Route {
    /// Closed to operators while the queue is locked.
    fn lockable(mut self) -> Route {
        self.lockable = true;
        self
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
        get(stream::events),
    );
    events.stream = true;
    vec![
        route(Method::GET, "/", None, "The live view (HTML)", get(page)),
        route(
            Method::GET,
            "/api/v1/status",
            o,
            "The service's status: queue, running item, stage",
            get(queue_api::status),
        ),
        route(
            Method::GET,
            "/api/v1/queue",
            o,
            "The queue and the running item",
            get(queue_api::queue),
        ),
        route(
            Method::GET,
            "/api/v1/history",
            o,
            "Ended items, newest last",
            get(queue_api::history),
        ),
        route(
            Method::GET,
            "/api/v1/items/{id}",
            o,
            "One item wherever it is, with its attempts, folder and result",
            get(queue_api::item),
        ),
        route(
            Method::POST,
            "/api/v1/queue/items",
            op,
            "Add items: {items: [{task, key?}], at?}",
            post(queue_api::add),
        )
        .lockable(),
        route(
            Method::PATCH,
            "/api/v1/queue/items/{id}",
            op,
            "Edit a waiting item's task: {task}",
            patch(queue_api::edit),
        )
        .lockable(),
        route(
            Method::DELETE,
            "/api/v1/queue/items/{id}",
            op,
            "Remove a waiting item",
            delete(queue_api::remove),
        )
        .lockable(),
        route(
            Method::POST,
            "/api/v1/queue/items/{id}/move",
            op,
            "Move a waiting item: {to}",
            post(queue_api::move_item),
        )
        .lockable(),
        route(
            Method::POST,
            "/api/v1/queue/clear",
            op,
            "Remove every waiting item",
            post(queue_api::clear),
        )
        .lockable(),
        route(
            Method::POST,
            "/api/v1/queue/start",
            op,
            "Start the queue",
            post(queue_api::start),
        )
        .lockable(),
        route(
            Method::POST,
            "/api/v1/queue/stop",
            op,
            "Stop the queue after the running item",
            post(queue_api::stop_queue),
        )
        .lockable(),
        route(
            Method::PUT,
            "/api/v1/queue/options",
            op,
            "Set autostart and continue_on_failure",
            put(queue_api::options),
        )
        .lockable(),
        route(
            Method::POST,
            "/api/v1/run/pause",
            op,
            "Pause the running item: {immediate?}",
            post(run_api::pause),
        ),
        route(
            Method::POST,
            "/api/v1/run/resume",
            op,
            "Resume the paused item",
            post(run_api::resume),
        )
        .lockable(),
        route(
            Method::POST,
            "/api/v1/run/stop",
            op,
            "End the running item at the next tile, done",
            post(run_api::run_stop),
        )
        .lockable(),
        route(
            Method::POST,
            "/api/v1/run/abort",
            op,
            "Stop the stages now; the item goes back to the front",
            post(run_api::abort),
        ),
        route(
            Method::POST,
            "/api/v1/run/halt",
            op,
            "Reset the controller now, from any state",
            post(run_api::halt),
        ),
        route(
            Method::POST,
            "/api/v1/stage/jog",
            op,
            "Jog by {dx_mm, dy_mm} (idle only)",
            post(run_api::jog),
        )
        .lockable(),
        route(
            Method::PUT,
            "/api/v1/sim/film",
            op,
            "Simulator only: lay the film on the carriage or lift it off: {laid} (idle only)",
            put(run_api::sim_film),
        )
        .lockable(),
        route(
            Method::GET,
            "/api/v1/live.png",
            o,
            "The newest frame (PNG)",
            get(run_api::live),
        ),
        events,
        route(
            Method::GET,
            "/api/v1/calibration",
            o,
            "The newest pixel and interior sessions in the store: figures and plots",
            get(calibration_api::calibration),
        ),
        route(
            Method::GET,
            "/api/v1/calibration/{kind}/{session}/{file}",
            o,
            "One residual plot of a calibration session (PNG)",
            get(calibration_api::plot),
        ),
        route(
            Method::GET,
            "/api/v1/openapi.json",
            o,
            "This API's OpenAPI document",
            get(openapi),
        ),
        route(
            Method::POST,
            "/api/v1/lock",
            Some(Admin),
            "Lock the queue and run control to admins: {note} (pause, abort, halt stay open)",
            post(run_api::lock),
        ),
        route(
            Method::DELETE,
            "/api/v1/lock",
            Some(Admin),
            "Unlock the queue",
            delete(run_api::unlock),
        ),
        route(
            Method::POST,
            "/api/v1/shutdown",
            Some(Admin),
            "End the service (the queue is kept)",
            post(run_api::shutdown),
        ),
    ]
}

/// Who is asking: the token's name and role (with no tokens configured, "local", admin).
#[derive(Debug, Clone)]
pub struct Caller {
    pub name: String,
    pub role: Role,
}

/// The bearer token's caller, or the error for its absence.
fn caller_of(app: &App, headers: &HeaderMap) -> Result<Caller, ApiError> {
    let Some(tokens) = &app.tokens else {
        return Ok(Caller {
            name: "local".into(),
            role: Role::Admin,
        });
    };
    let token = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        // The scheme is case-insensitive (RFC 7235).
        .and_then(|v| {
            v.split_once(' ')
                .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
                .map(|(_, t)| t)
        })
        .ok_or_else(|| {
            ApiError::new(
                StatusCode::UNAUTHORIZED,
                "no_token",
                "this service needs a token: Authorization: Bearer TOKEN",
            )
        })?;
    tokens
        .check(token.trim())
        .map(|t| Caller {
            name: t.name.clone(),
            role: t.role,
        })
        .ok_or_else(|| {
            ApiError::new(
                StatusCode::UNAUTHORIZED,
                "unknown_token",
                "the token is not known here",
            )
        })
}

/// A browser's request that changes something must come from the service's own page: another
/// site's page, open on the lab's computer, could otherwise start the queue or abort a scan on
/// a service without tokens (a "no-cors" POST needs no preflight). Browsers send `Origin` with
/// such requests; tools (curl, the CLI) send none and are not affected.
fn same_origin(req: &HttpRequest) -> Result<(), ApiError> {
    if req.method() == Method::GET || req.method() == Method::HEAD {
        return Ok(());
    }
    let h = req.headers();
    let Some(origin) = h.get(header::ORIGIN).and_then(|v| v.to_str().ok()) else {
        return Ok(());
    };
    let host = h
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let origin_host = origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .unwrap_or("");
    if !host.is_empty() && origin_host.eq_ignore_ascii_case(host) {
        Ok(())
    } else {
        Err(ApiError::new(
            StatusCode::FORBIDDEN,
            "cross_origin",
            format!("a request from the page of {origin} may not change this service (only its own page at {host} may)"),
        ))
    }
}

/// Checks the caller's role and the lock; the caller goes with the request.
fn admit(app: &App, req: &mut HttpRequest, need: Role, lockable: bool) -> Result<(), ApiError> {
    let caller = caller_of(app, req.headers())?;
    if caller.role < need {
        return Err(ApiError::new(
            StatusCode::FORBIDDEN,
            "role",
            format!(
                "this needs the {} role; the token has {}",
                need.name(),
                caller.role.name()
            ),
        ));
    }
    if lockable && caller.role < Role::Admin {
        if let Some(l) = app.lab.ledger.read(|s| s.lock.clone()) {
            return Err(ApiError::new(
                StatusCode::LOCKED,
                "locked",
                format!(
                    "the queue is locked by {} ({}): only an admin may change it now; pause, abort and halt stay open",
                    l.by, l.note
                ),
            ));
        }
    }
    req.extensions_mut().insert(caller);
    Ok(())
}

/// Builds the router from [`routes`].
pub fn router(app: App) -> Router {
    let mut r = Router::new();
    for rt in routes() {
        let need = rt.role;
        let stream = rt.stream;
        let lockable = rt.lockable;
        let a = app.clone();
        let guarded = rt.handler.route_layer(axum::middleware::from_fn(
            move |mut req: HttpRequest, next: Next| {
                let a = a.clone();
                async move {
                    if let Err(e) = same_origin(&req) {
                        return e.into_response();
                    }
                    if let Some(need) = need {
                        if let Err(e) = admit(&a, &mut req, need, lockable) {
                            return e.into_response();
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
