//! The detection pipeline: synchronous and framework-free, shared unchanged
//! by the command-line tool and the service.
//!
//! raster (GDAL strips) -> tiles -> detect (per mode) -> dedup -> georef ->
//! output, with memory deciding how many frames run at once (batch).

pub mod batch;
pub mod camera;
pub mod dedup;
pub mod detect;
pub mod frame;
pub mod georef;
pub mod layout;
pub mod memory;
pub mod output;
pub mod pictures;
pub mod raster;
pub mod tiles;

use std::sync::Once;

/// Process-wide settings for the native libraries; idempotent.
pub fn init_native() {
    static INIT: Once = Once::new();
    INIT.call_once(|| {
        let options = [
            ("GDAL_CACHEMAX", memory::GDAL_CACHE_MIB.to_string()),
            // A truncated JPEG is an error, not a grey tail.
            ("GDAL_ERROR_ON_LIBJPEG_WARNING", "TRUE".into()),
            // Never write .aux.xml files next to a user's frames.
            ("GDAL_PAM_ENABLED", "NO".into()),
        ];
        for (key, value) in options {
            if let Err(e) = gdal::config::set_config_option(key, &value) {
                tracing::warn!(key, error = %e, "cannot set GDAL option");
            }
        }
        // GDAL prints errors to stderr by default; they surface through our
        // own error values instead, so keep them in the debug log.
        gdal::config::set_error_handler(|class, code, message| {
            tracing::debug!(?class, code, message, "gdal");
        });
        // Our workers are the parallelism; OpenCV's own threads (TBB) would
        // oversubscribe the cores.
        if let Err(e) = opencv::core::set_num_threads(1) {
            tracing::warn!(error = %e, "cannot set OpenCV threads");
        }
    });
}
