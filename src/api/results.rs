//! Results as CSV or GeoJSON over HTTP: content negotiation and headers
//! around [`crate::jobs::results::render_jobs`].

use crate::error_code::ErrorCode;
use axum::http::{header, HeaderMap, HeaderValue};
use axum::response::{IntoResponse, Response};

use super::error::ApiError;
use super::AppState;
use crate::jobs::review::Selection;
use crate::jobs::JobRecord;
use crate::pipeline::output::Format;

/// Media types of the two formats.
pub const CSV_TYPE: &str = "text/csv; charset=utf-8";
pub const GEOJSON_TYPE: &str = "application/geo+json";

/// The format asked for by `Accept` (first acceptable range wins; none or
/// `*/*` means CSV).
pub fn negotiate(headers: &HeaderMap) -> Result<Format, ApiError> {
    let Some(accept) = headers.get(header::ACCEPT).and_then(|v| v.to_str().ok()) else {
        return Ok(Format::Csv);
    };
    for range in accept.split(',') {
        let media = range
            .split(';')
            .next()
            .unwrap_or("")
            .trim()
            .to_ascii_lowercase();
        match media.as_str() {
            "text/csv" | "text/*" | "*/*" | "" => return Ok(Format::Csv),
            "application/geo+json" | "application/json" | "application/*" => {
                return Ok(Format::GeoJson)
            }
            _ => {}
        }
    }
    Err(ApiError::new(
        ErrorCode::NotAcceptable,
        format!("cannot answer Accept: {accept}; results are text/csv or application/geo+json"),
    ))
}

/// Reads the stored results of succeeded jobs and renders them; runs on a
/// blocking thread (file reads, PROJ for the CRS's kind).
pub async fn render_jobs(
    state: &AppState,
    jobs: Vec<JobRecord>,
    crs: String,
    format: Format,
    file_stem: String,
    selection: Selection,
) -> Result<Response, ApiError> {
    let data = state.data.clone();
    let text = tokio::task::spawn_blocking(move || {
        crate::jobs::results::render_jobs(&data, &jobs, &crs, format, selection)
            .map_err(|e| ApiError::internal("rendering results", e))
    })
    .await
    .map_err(|e| ApiError::internal("rendering results", e))??;
    let (media, ext) = match format {
        Format::Csv => (CSV_TYPE, "csv"),
        Format::GeoJson => (GEOJSON_TYPE, "geojson"),
    };
    let disposition = format!("inline; filename=\"{file_stem}.{ext}\"");
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(media)),
            (
                header::CONTENT_DISPOSITION,
                HeaderValue::from_str(&disposition).expect("ascii file name"),
            ),
            (header::VARY, HeaderValue::from_static("accept")),
        ],
        text,
    )
        .into_response())
}
