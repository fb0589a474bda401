//! gcp-tagger: finds ground control point targets in drone frames and
//! reports their subpixel pixel positions and world coordinates.
//!
//! - [`pipeline`]: the synchronous detection pipeline (GDAL, OpenCV, PROJ).
//! - [`jobs`]: job records, the durable store and queue, the worker pool.
//! - [`storage`]: the data folder, the upload spool and S3 sources.
//! - [`survey`]: surveyed points, matching detections to them, exports.
//! - [`api`]: the HTTP API (axum), its errors and OpenAPI document.
//! - [`server`] and [`config`]: `gcp-tagger serve`.
//! - [`cli`]: the `gcp-tagger` command line.
//! - [`telemetry`]: Prometheus metrics.
//!
//! Frames with exact ground truth (for `sample`, the tests and the
//! benchmarks) come from the `gcp-synth` crate beside this one.

pub mod api;
pub mod background;
pub mod cli;
pub mod config;
pub mod error_code;
pub mod jobs;
pub mod pipeline;
pub mod server;
pub mod storage;
pub mod survey;
pub mod telemetry;
