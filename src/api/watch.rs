//! Waiting without busy polling: long-poll (`?wait=`) and server-sent
//! events. Both sleep on the store's change signal and end early when the
//! server shuts down.

use crate::error_code::ErrorCode;
use std::convert::Infallible;
use std::time::Duration;

use axum::http::{header, HeaderValue};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use futures_util::Stream;
use tokio::time::Instant;

use super::views::MAX_WAIT_SECS;
use super::AppState;
use crate::api::error::ApiError;

/// Least time between two events of one stream: a 100-tile frame would
/// otherwise send 100 events a second.
const EVENT_INTERVAL: Duration = Duration::from_millis(200);

/// Checks `wait=` and turns it into a duration.
pub fn wait_duration(wait: Option<u64>) -> Result<Duration, ApiError> {
    match wait {
        None => Ok(Duration::ZERO),
        Some(s) if s <= MAX_WAIT_SECS => Ok(Duration::from_secs(s)),
        Some(s) => Err(ApiError::new(
            ErrorCode::InvalidQuery,
            format!("wait={s} is above the {MAX_WAIT_SECS} s maximum"),
        )
        .with_field("wait")),
    }
}

/// A long-poll's answer: when the client waited and the job or flight has
/// not ended, `Retry-After: 0` says the wait ran out (at most
/// [`MAX_WAIT_SECS`]) and to ask again, so clients loop without guessing.
pub fn answer(body: impl IntoResponse, wait: Duration, ended: bool) -> Response {
    let mut response = body.into_response();
    if !wait.is_zero() && !ended {
        response
            .headers_mut()
            .insert(header::RETRY_AFTER, HeaderValue::from_static("0"));
    }
    response
}

/// Waits until `done()` holds, `wait` passes, or the server shuts down.
pub async fn wait_until(state: &AppState, wait: Duration, done: impl Fn() -> bool) {
    if wait.is_zero() {
        return;
    }
    let deadline = Instant::now() + wait;
    let mut changes = state.store.subscribe();
    let mut shutdown = state.shutdown.clone();
    loop {
        changes.borrow_and_update();
        if done() || *shutdown.borrow() {
            return;
        }
        tokio::select! {
            r = changes.changed() => if r.is_err() { return },
            _ = shutdown.changed() => return,
            _ = tokio::time::sleep_until(deadline) => return,
        }
    }
}

/// An event stream: `snapshot()` gives the current JSON and whether it is
/// final; an event is sent whenever the JSON changes, and `end` after the
/// final one.
pub fn event_stream<F>(
    state: AppState,
    event: &'static str,
    snapshot: F,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>>
where
    F: Fn() -> Option<(String, bool)> + Send + 'static,
{
    struct Cursor<F> {
        next_at: Instant,
        changes: tokio::sync::watch::Receiver<u64>,
        shutdown: tokio::sync::watch::Receiver<bool>,
        last: Option<String>,
        ended: bool,
        snapshot: F,
    }
    let cursor = Cursor {
        changes: state.store.subscribe(),
        shutdown: state.shutdown.clone(),
        next_at: Instant::now(),
        last: None,
        ended: false,
        snapshot,
    };
    let stream = futures_util::stream::unfold(cursor, move |mut c| async move {
        if c.ended {
            return None;
        }
        loop {
            tokio::time::sleep_until(c.next_at).await;
            c.changes.borrow_and_update();
            let Some((json, last)) = (c.snapshot)() else {
                // Deleted meanwhile.
                c.ended = true;
                return Some((Ok(Event::default().event("deleted").data("{}")), c));
            };
            if last {
                c.ended = true;
                return Some((Ok(Event::default().event("end").data(json)), c));
            }
            if c.last.as_deref() != Some(json.as_str()) {
                c.last = Some(json.clone());
                c.next_at = Instant::now() + EVENT_INTERVAL;
                return Some((Ok(Event::default().event(event).data(json)), c));
            }
            if *c.shutdown.borrow() {
                return None;
            }
            tokio::select! {
                r = c.changes.changed() => if r.is_err() { return None },
                _ = c.shutdown.changed() => return None,
            }
        }
    });
    Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
}
