//! Stored frame results rendered as CSV or GeoJSON by the pipeline's own
//! writers, for the API and for results written back to object storage:
//! the same bytes as `gcp-tagger detect` on the same frames. Frames are
//! sorted by image name, so the order jobs finished in never shows.

use crate::pipeline::frame::FrameResult;
use crate::pipeline::georef::{GeorefError, TargetCrs};
use crate::pipeline::output::{render, Format};
use crate::storage::{DataDir, StoredFileError};

use super::model::{JobId, JobRecord, JobState};
use super::review::{self, Selection};

/// Why stored results cannot be rendered.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Stored(#[from] StoredFileError),
    #[error("the flight's stored CRS {crs:?} no longer parses: {source}")]
    Crs { crs: String, source: GeorefError },
}

/// Renders the results of the succeeded jobs among `jobs` in `crs`, the
/// targets `selection` keeps.
/// Blocking: reads files and builds a PROJ object.
pub fn render_jobs(
    data: &DataDir,
    jobs: &[JobRecord],
    crs: &str,
    format: Format,
    selection: Selection,
) -> Result<String, RenderError> {
    let crs = TargetCrs::parse(crs).map_err(|source| RenderError::Crs {
        crs: crs.to_string(),
        source,
    })?;
    let frames = load_frames(data, jobs, selection)?;
    Ok(render(format, &frames, &crs))
}

/// The stored results of the succeeded jobs among `jobs`, by image name,
/// with the targets their reviews and `selection` keep.
pub fn load_frames(
    data: &DataDir,
    jobs: &[JobRecord],
    selection: Selection,
) -> Result<Vec<FrameResult>, StoredFileError> {
    let mut frames: Vec<FrameResult> = Vec::with_capacity(jobs.len());
    for job in jobs.iter().filter(|j| j.state == JobState::Succeeded) {
        let mut frame = load_result(data, job.id)?;
        review::load(data, job.id)?.apply(&mut frame, selection);
        frames.push(frame);
    }
    frames.sort_by(|a, b| a.image.cmp(&b.image));
    Ok(frames)
}

/// A succeeded job's stored result, every target kept.
pub fn load_result(data: &DataDir, job: JobId) -> Result<FrameResult, StoredFileError> {
    let path = data.result_path(job);
    data.read_json(&path)?.ok_or(StoredFileError::Missing(path))
}
