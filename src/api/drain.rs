//! Reading what a refused request still sends. A request refused before its
//! body is read (413 from its Content-Length, 503 while shutting down, 401)
//! would otherwise be answered while the client is still sending; clients
//! that send the whole body before reading the answer (Python `requests`,
//! many scripts) then see a broken pipe instead of the problem document.
//! The body is wrapped so that, when the handler drops it unread, the rest
//! comes back here and is read and discarded, up to [`DRAIN_MAX_BYTES`]
//! and [`DRAIN_MAX_TIME`], before the answer goes out.

use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::extract::Request;
use axum::middleware::Next;
use axum::response::Response;
use futures_util::StreamExt;
use http_body::{Frame, SizeHint};

/// Most bytes read from a refused request; a larger remainder is cut off.
pub const DRAIN_MAX_BYTES: u64 = 1 << 30;
/// Longest time spent reading a refused request's remainder.
pub const DRAIN_MAX_TIME: Duration = Duration::from_secs(60);

type Slot = Arc<Mutex<Option<Body>>>;

/// A request body that hands its unread rest to `slot` when dropped.
struct Tracked {
    inner: Option<Body>,
    ended: bool,
    slot: Slot,
}

impl http_body::Body for Tracked {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        let Some(inner) = self.inner.as_mut() else {
            return Poll::Ready(None);
        };
        let polled = Pin::new(inner).poll_frame(cx);
        if matches!(polled, Poll::Ready(None)) {
            self.ended = true;
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.as_ref().is_none_or(|b| b.is_end_stream())
    }

    fn size_hint(&self) -> SizeHint {
        self.inner
            .as_ref()
            .map_or_else(|| SizeHint::with_exact(0), |b| b.size_hint())
    }
}

impl Drop for Tracked {
    fn drop(&mut self) {
        if let Some(inner) = self.inner.take() {
            if !self.ended && !http_body::Body::is_end_stream(&inner) {
                *self.slot.lock().expect("drain slot") = Some(inner);
            }
        }
    }
}

/// Middleware: runs the request; if the answer is an error and the body
/// was left unread, reads the rest (bounded) before answering.
pub async fn drain_refused(req: Request, next: Next) -> Response {
    let slot: Slot = Arc::default();
    let (parts, body) = req.into_parts();
    let tracked = Tracked {
        inner: Some(body),
        ended: false,
        slot: slot.clone(),
    };
    let response = next
        .run(Request::from_parts(parts, Body::new(tracked)))
        .await;
    let status = response.status();
    if status.is_client_error() || status.is_server_error() {
        let rest = slot.lock().expect("drain slot").take();
        // A rest declared larger than the bound would be cut off anyway.
        let within = |b: &Body| {
            http_body::Body::size_hint(b)
                .upper()
                .is_none_or(|n| n <= DRAIN_MAX_BYTES)
        };
        if let Some(rest) = rest.filter(within) {
            let _ = tokio::time::timeout(DRAIN_MAX_TIME, discard(rest)).await;
        }
    }
    response
}

async fn discard(body: Body) {
    let mut read = 0u64;
    let mut stream = body.into_data_stream();
    while let Some(Ok(chunk)) = stream.next().await {
        read += chunk.len() as u64;
        if read > DRAIN_MAX_BYTES {
            return;
        }
    }
}
