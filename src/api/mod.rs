//! The HTTP API: axum routes over the job store, problem+json errors,
//! OpenAPI (utoipa) served at `/openapi.json` with Swagger UI at `/docs`
//! (bundled, works offline), metrics, request ids, CORS and bearer keys.
//! Handlers parse, call the store or the upload spool, and map the answer;
//! the pipeline runs only on the worker pool.

pub mod drain;
pub mod error;
pub mod extract;
pub mod flights;
pub mod idempotency;
pub mod jobs;
pub mod limit;
pub mod ops;
pub mod page;
pub mod results;
pub mod review;
pub mod sources;
pub mod survey;
pub mod upload;
pub mod views;
pub mod watch;

use crate::error_code::ErrorCode;
use std::net::SocketAddr;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Instant;

use axum::extract::{ConnectInfo, DefaultBodyLimit, MatchedPath, Request, State};
use axum::http::{header, HeaderName, HeaderValue, Method};
use axum::middleware::{self, Next};
use axum::response::Response;
use axum::Router;
use tower_http::cors::{AllowOrigin, CorsLayer};
use tower_http::request_id::{MakeRequestUuid, PropagateRequestIdLayer, SetRequestIdLayer};
use tower_http::trace::TraceLayer;
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;
use utoipa_swagger_ui::SwaggerUi;

use crate::jobs::SharedStore;
use crate::pipeline::memory::RamBudget;
use crate::storage::s3::S3;
use crate::storage::DataDir;
use crate::telemetry::{HttpLabels, Metrics};
use error::ApiError;
pub use upload::UploadLimits;

/// Everything a handler can reach.
#[derive(Clone)]
pub struct AppState {
    pub store: SharedStore,
    pub data: DataDir,
    pub metrics: Arc<Metrics>,
    pub budget: Arc<RamBudget>,
    pub limits: UploadLimits,
    /// Object storage for `s3://` sources and result write-back.
    pub s3: Arc<S3>,
    /// Becomes true when the server starts shutting down.
    pub shutdown: tokio::sync::watch::Receiver<bool>,
    /// Workers are running.
    pub ready: Arc<AtomicBool>,
}

/// HTTP settings that shape the router.
#[derive(Debug, Clone, Default)]
pub struct HttpConfig {
    /// Bearer keys; empty means no authentication.
    pub api_keys: Vec<String>,
    /// Origins allowed by CORS (`*` for any); empty means no CORS headers.
    pub cors_origins: Vec<String>,
    /// Requests per minute per client; 0 means no limit.
    pub rate_limit_per_minute: u32,
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "gcp-tagger",
        description = "Finds ground control point targets in drone frames and reports their subpixel \
            pixel positions and world coordinates. Upload frames (one per job, or a flight of many), \
            follow their jobs, and fetch results as CSV or GeoJSON. Errors are \
            application/problem+json with a stable `code`.",
        license(name = "Apache-2.0")
    ),
    modifiers(&BearerAuth),
    security((), ("bearer" = [])),
    tags(
        (name = "jobs", description = "One frame, one job"),
        (name = "flights", description = "Frames submitted together"),
        (name = "results", description = "Targets as CSV or GeoJSON"),
        (name = "survey", description = "Surveyed ground control points and the GCP files for photogrammetry software"),
        (name = "review", description = "Each detection's chip, each frame's preview, and a reviewer's accept or reject"),
        (name = "operations", description = "Health and metrics"),
    )
)]
struct ApiDoc;

struct BearerAuth;
impl Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "An API key from the server's configuration (--api-key); needed on every \
                         route but /livez and /readyz when keys are configured",
                    ))
                    .build(),
            ),
        );
    }
}

fn api_routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(routes!(jobs::submit_job, jobs::list_jobs))
        .routes(routes!(jobs::get_job, jobs::delete_job))
        .routes(routes!(jobs::job_events))
        .routes(routes!(jobs::get_job_results))
        .routes(routes!(jobs::get_job_results_csv))
        .routes(routes!(jobs::get_job_results_geojson))
        .routes(routes!(jobs::cancel_job))
        .routes(routes!(flights::submit_flight, flights::list_flights))
        .routes(routes!(flights::get_flight, flights::delete_flight))
        .routes(routes!(flights::add_frames))
        .routes(routes!(flights::flight_jobs))
        .routes(routes!(flights::flight_events))
        .routes(routes!(flights::get_flight_results))
        .routes(routes!(flights::get_flight_results_csv))
        .routes(routes!(flights::get_flight_results_geojson))
        .routes(routes!(flights::cancel_flight))
        .routes(routes!(survey::put_survey, survey::get_survey))
        .routes(routes!(survey::put_assignments))
        .routes(routes!(survey::get_export))
        .routes(routes!(review::flight_observations))
        .routes(routes!(review::get_chip))
        .routes(routes!(review::get_preview))
        .routes(routes!(review::put_review))
        .routes(routes!(ops::livez))
        .routes(routes!(ops::readyz))
        .routes(routes!(ops::metrics))
}

/// The OpenAPI document, as committed in `openapi/openapi.json`.
pub fn openapi() -> utoipa::openapi::OpenApi {
    let mut spec = api_routes().split_for_parts().1;
    add_common_responses(&mut spec);
    spec
}

/// The answers every route may give from the layers around it (see
/// [`router`]): 401 when keys are configured, 429 over the rate limit, 503
/// for new work while shutting down, 507 for uploads when the disk is
/// short. Probes are open and unlimited.
fn add_common_responses(spec: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::{ContentBuilder, Ref, RefOr, ResponseBuilder};
    let problem = |description: &str| {
        RefOr::T(
            ResponseBuilder::new()
                .description(description)
                .content(
                    "application/problem+json",
                    ContentBuilder::new()
                        .schema(Some(Ref::from_schema_name("Problem")))
                        .build(),
                )
                .build(),
        )
    };
    for (path, item) in spec.paths.paths.iter_mut() {
        if OPEN_PATHS.contains(&path.as_str()) {
            continue;
        }
        let uploads = matches!(
            path.as_str(),
            "/v1/jobs" | "/v1/flights" | "/v1/flights/{id}/frames"
        );
        let operations = [
            (&mut item.get, false),
            (&mut item.put, true),
            (&mut item.post, true),
            (&mut item.delete, true),
        ];
        for (op, changes) in operations {
            let Some(op) = op.as_mut() else { continue };
            let mut add = |code: &str, description: &str| {
                op.responses
                    .responses
                    .entry(code.to_string())
                    .or_insert_with(|| problem(description));
            };
            add(
                "401",
                "No valid API key (`unauthorized`; only when the server has keys)",
            );
            if !limit::UNLIMITED.contains(&path.as_str()) {
                add(
                    "429",
                    "Over the client's requests per minute (`rate_limited`, with Retry-After)",
                );
            }
            if changes {
                add(
                    "503",
                    "The service is shutting down (`shutting_down`, with Retry-After)",
                );
            }
            if changes && uploads {
                add(
                    "507",
                    "Too little free disk for the upload (`insufficient_storage`)",
                );
            }
        }
    }
}

/// The whole application.
pub fn router(state: AppState, config: &HttpConfig) -> Router {
    let (routes, mut spec) = api_routes().split_for_parts();
    add_common_responses(&mut spec);
    let request_id = HeaderName::from_static("x-request-id");
    let mut app = routes
        .merge(SwaggerUi::new("/docs").url("/openapi.json", spec))
        .merge(page::routes())
        .fallback(error::not_found)
        .method_not_allowed_fallback(error::method_not_allowed)
        // Uploads enforce their own limits while streaming (see upload).
        .layer(DefaultBodyLimit::disable())
        .layer(middleware::from_fn_with_state(state.clone(), refuse_new_work))
        .layer(middleware::from_fn_with_state(
            Arc::new(Gate {
                keys: config.api_keys.clone(),
                limiter: limit::RateLimiter::new(config.rate_limit_per_minute),
            }),
            gate,
        ))
        .layer(middleware::from_fn_with_state(state.clone(), record_metrics))
        // Outside auth and limits, so their refusals are drained too.
        .layer(middleware::from_fn(drain::drain_refused))
        .layer(
            TraceLayer::new_for_http().make_span_with(|req: &Request| {
                let id = req
                    .headers()
                    .get("x-request-id")
                    .and_then(|v| v.to_str().ok())
                    .unwrap_or("");
                tracing::info_span!("request", request.id = %id, method = %req.method(), path = %req.uri().path())
            }),
        )
        .layer(PropagateRequestIdLayer::new(request_id.clone()))
        .layer(SetRequestIdLayer::new(request_id, MakeRequestUuid))
        .with_state(state);
    if let Some(cors) = cors_layer(&config.cors_origins) {
        // Outermost, so preflight requests are answered before auth.
        app = app.layer(cors);
    }
    app
}

fn cors_layer(origins: &[String]) -> Option<CorsLayer> {
    if origins.is_empty() {
        return None;
    }
    let allow = if origins.iter().any(|o| o == "*") {
        AllowOrigin::any()
    } else {
        AllowOrigin::list(
            origins
                .iter()
                .filter_map(|o| HeaderValue::from_str(o.trim_end_matches('/')).ok()),
        )
    };
    Some(
        CorsLayer::new()
            .allow_origin(allow)
            .allow_methods([Method::GET, Method::POST, Method::DELETE])
            .allow_headers([
                header::AUTHORIZATION,
                header::CONTENT_TYPE,
                header::ACCEPT,
                header::CONTENT_DISPOSITION,
                idempotency::HEADER,
            ])
            .expose_headers([
                header::LOCATION,
                header::RETRY_AFTER,
                header::CONTENT_DISPOSITION,
                HeaderName::from_static("x-request-id"),
                HeaderName::from_static("idempotent-replayed"),
            ])
            .max_age(std::time::Duration::from_secs(600)),
    )
}

/// Routes open without a key: probes must work without secrets.
const OPEN_PATHS: &[&str] = &["/livez", "/readyz"];

/// While the server shuts down (the listener stays open through the
/// grace period), requests that would start or change work get a 503 with
/// `Retry-After`; reads, long polls' answers and probes go on.
async fn refuse_new_work(
    State(state): State<AppState>,
    req: Request,
    next: Next,
) -> Result<Response, ApiError> {
    let reads = [Method::GET, Method::HEAD, Method::OPTIONS];
    if *state.shutdown.borrow() && !reads.contains(req.method()) {
        return Err(ApiError::new(
            ErrorCode::ShuttingDown,
            "the service is shutting down; send this again to its next start or another replica",
        )
        .with_header(header::RETRY_AFTER, "5"));
    }
    Ok(next.run(req).await)
}

/// Who may call, and how often.
struct Gate {
    /// Bearer keys; empty means no authentication.
    keys: Vec<String>,
    limiter: limit::RateLimiter,
}

/// Authentication, then the rate limit of the client that request is
/// from: its verified key's allowance, or, with no key (none configured,
/// or a wrong one), its address's. A header's spelling names no one, so
/// varying it buys nothing, and wrong keys spend the guessing address's
/// allowance (401s until it is spent, then 429s).
async fn gate(
    State(gate): State<Arc<Gate>>,
    req: Request,
    next: Next,
) -> Result<Response, ApiError> {
    let path = req.uri().path();
    let limited = !gate.limiter.is_off() && !limit::UNLIMITED.contains(&path);
    let open = gate.keys.is_empty() || OPEN_PATHS.contains(&path) || page::PATHS.contains(&path);
    let address = req
        .extensions()
        .get::<ConnectInfo<SocketAddr>>()
        .map_or_else(|| "ip:unknown".to_string(), |c| format!("ip:{}", c.0.ip()));
    let client = if open {
        address
    } else {
        match verify_key(&gate.keys, &req) {
            Ok(k) => format!("key:{k}"),
            Err(unauthorized) => {
                if limited {
                    gate.limiter.take(&address)?;
                }
                return Err(unauthorized);
            }
        }
    };
    if limited {
        gate.limiter.take(&client)?;
    }
    Ok(next.run(req).await)
}

/// The index of the configured key the request's bearer token is.
fn verify_key(keys: &[String], req: &Request) -> Result<usize, ApiError> {
    let given = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::trim);
    let unauthorized = |detail: &str| {
        ApiError::new(ErrorCode::Unauthorized, detail)
            .with_header(header::WWW_AUTHENTICATE, "Bearer realm=\"gcp-tagger\"")
    };
    let Some(given) = given else {
        return Err(unauthorized(
            "this route needs Authorization: Bearer <api key>",
        ));
    };
    // Every key is compared, so timing does not tell which one matched.
    keys.iter()
        .enumerate()
        .fold(None, |found, (i, k)| {
            let same = constant_time_eq(k.as_bytes(), given.as_bytes());
            found.or(same.then_some(i))
        })
        .ok_or_else(|| unauthorized("the API key is not valid"))
}

/// Compares without an early exit, so timing does not reveal how much of a
/// key matched.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

async fn record_metrics(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let started = Instant::now();
    let method = req.method().to_string();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or("unmatched", |p| p.as_str())
        .to_string();
    let response = next.run(req).await;
    let labels = HttpLabels {
        method,
        route,
        status: response.status().as_u16(),
    };
    state.metrics.http_requests.get_or_create(&labels).inc();
    state
        .metrics
        .http_duration
        .get_or_create(&labels)
        .observe(started.elapsed().as_secs_f64());
    response
}

/// The OpenAPI document as pretty JSON, as committed.
pub fn openapi_json() -> String {
    openapi()
        .to_pretty_json()
        .expect("the OpenAPI document serializes")
}
