//! Per-client request rates: a token bucket per client (its bearer key
//! when it sends one, else its IP address) refilled at the configured rate
//! per minute, with a minute's worth of burst. Over the limit, a 429
//! problem with `Retry-After`. Health and metrics routes are not limited.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::extract::{ConnectInfo, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::Response;

use super::error::ApiError;

/// Entries kept before idle clients are forgotten.
const MAX_CLIENTS: usize = 10_000;

/// The buckets of every client.
pub struct RateLimiter {
    per_minute: f64,
    buckets: Mutex<HashMap<String, (f64, Instant)>>,
}

impl RateLimiter {
    pub fn new(per_minute: u32) -> RateLimiter {
        RateLimiter {
            per_minute: per_minute as f64,
            buckets: Mutex::new(HashMap::new()),
        }
    }

    pub fn is_off(&self) -> bool {
        self.per_minute <= 0.0
    }

    /// Takes a token for `client`; `Err(seconds)` until the next one.
    fn take(&self, client: &str, now: Instant) -> Result<(), u64> {
        let mut buckets = self.buckets.lock().expect("rate limiter lock");
        if buckets.len() > MAX_CLIENTS {
            let per_second = self.per_minute / 60.0;
            buckets.retain(|_, (tokens, at)| {
                *tokens + now.duration_since(*at).as_secs_f64() * per_second < self.per_minute
            });
        }
        let (tokens, at) = buckets
            .entry(client.to_string())
            .or_insert((self.per_minute, now));
        let refill = now.duration_since(*at).as_secs_f64() * self.per_minute / 60.0;
        *tokens = (*tokens + refill).min(self.per_minute);
        *at = now;
        if *tokens >= 1.0 {
            *tokens -= 1.0;
            Ok(())
        } else {
            Err(((1.0 - *tokens) * 60.0 / self.per_minute).ceil().max(1.0) as u64)
        }
    }
}

/// Routes never limited: probes and scrapes.
const UNLIMITED: [&str; 3] = ["/livez", "/readyz", "/metrics"];

pub async fn limit_rate(
    State(limiter): State<Arc<RateLimiter>>,
    req: Request,
    next: Next,
) -> Result<Response, ApiError> {
    if UNLIMITED.contains(&req.uri().path()) {
        return Ok(next.run(req).await);
    }
    let client = match req.headers().get(header::AUTHORIZATION) {
        Some(key) => format!("key:{:x}", md5::Md5::digest_bytes(key.as_bytes())),
        None => req
            .extensions()
            .get::<ConnectInfo<SocketAddr>>()
            .map_or_else(|| "ip:unknown".to_string(), |c| format!("ip:{}", c.0.ip())),
    };
    match limiter.take(&client, Instant::now()) {
        Ok(()) => Ok(next.run(req).await),
        Err(wait) => Err(ApiError::new(
            StatusCode::TOO_MANY_REQUESTS,
            "rate_limited",
            format!(
                "more than {} requests a minute from this client; retry in {wait} s",
                limiter.per_minute
            ),
        )
        .with_header(header::RETRY_AFTER, &wait.to_string())),
    }
}

trait DigestBytes {
    fn digest_bytes(bytes: &[u8]) -> u128;
}

impl DigestBytes for md5::Md5 {
    fn digest_bytes(bytes: &[u8]) -> u128 {
        use md5::Digest;
        u128::from_be_bytes(md5::Md5::digest(bytes).into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_bucket_allows_its_rate_and_refills() {
        let limiter = RateLimiter::new(60);
        let t0 = Instant::now();
        for _ in 0..60 {
            assert_eq!(limiter.take("a", t0), Ok(()));
        }
        assert_eq!(limiter.take("a", t0), Err(1));
        assert_eq!(limiter.take("b", t0), Ok(()), "clients are separate");
        assert_eq!(limiter.take("a", t0 + Duration::from_secs(2)), Ok(()));
    }
}
