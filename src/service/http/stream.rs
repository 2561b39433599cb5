//! The event stream: Server-Sent Events with sequence numbers, a replay of what a reconnecting
//! client missed, and a resync for one that fell behind.

use super::error::ApiError;
use super::App;
use crate::service::events::{Event as BusEvent, Kind};
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use serde_json::json;

fn sse_of(e: &BusEvent) -> Event {
    Event::default()
        .id(e.seq.to_string())
        .event(e.kind.name())
        .data(&e.wire)
}

fn resync(why: &str) -> Event {
    Event::default()
        .event(Kind::Resync.name())
        .data(json!({"message": why}).to_string())
}

pub(super) async fn events(
    State(app): State<App>,
    headers: HeaderMap,
) -> Result<Sse<impl futures_util::Stream<Item = Result<Event, std::convert::Infallible>>>, ApiError>
{
    let bus = app.lab.ledger.bus.clone();
    let most = app.max_event_clients;
    if bus.clients() >= most {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "too_many_clients",
            format!("at most {most} event streams at once (the rest of the connections are kept for control)"),
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
