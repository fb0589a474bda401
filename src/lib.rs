//! gcp-tagger: finds ground control point targets in drone frames and
//! reports their subpixel pixel positions and world coordinates.
//!
//! - [`pipeline`]: the synchronous detection pipeline (GDAL, OpenCV, PROJ).
//! - [`cli`]: the `gcp-tagger` command line.
//! - [`synth`]: frames with exact ground truth for tests and benchmarks.

pub mod cli;
pub mod pipeline;
pub mod synth;
