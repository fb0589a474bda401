//! Per-client request rates: a token bucket per client (its verified key,
//! else its IP address; see `api::gate`) refilled at the configured rate
//! per minute, with a minute's worth of burst. Over the limit, a 429
//! problem with `Retry-After`. Health and metrics routes are not limited.

use crate::error_code::ErrorCode;
use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Instant;

use axum::http::header;

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
    fn take_at(&self, client: &str, now: Instant) -> Result<(), u64> {
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
pub const UNLIMITED: [&str; 3] = ["/livez", "/readyz", "/metrics"];

impl RateLimiter {
    /// Takes a token from `client`'s bucket, or the 429 to answer.
    pub fn take(&self, client: &str) -> Result<(), ApiError> {
        self.take_at(client, Instant::now()).map_err(|wait| {
            ApiError::new(
                ErrorCode::RateLimited,
                format!(
                    "more than {} requests a minute from this client; retry in {wait} s",
                    self.per_minute
                ),
            )
            .with_header(header::RETRY_AFTER, &wait.to_string())
        })
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
            assert_eq!(limiter.take_at("a", t0), Ok(()));
        }
        assert_eq!(limiter.take_at("a", t0), Err(1));
        assert_eq!(limiter.take_at("b", t0), Ok(()), "clients are separate");
        assert_eq!(limiter.take_at("a", t0 + Duration::from_secs(2)), Ok(()));
    }
}
