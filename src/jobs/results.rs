//! Stored frame results rendered as CSV or GeoJSON by the pipeline's own
//! writers, for the API and for results written back to object storage:
//! the same bytes as `gcp-tagger detect` on the same frames. Frames are
//! sorted by image name, so the order jobs finished in never shows.

use crate::pipeline::frame::FrameResult;
use crate::pipeline::georef::TargetCrs;
use crate::pipeline::output::{render, Format};
use crate::storage::DataDir;

use super::model::{JobId, JobRecord, JobState};
use super::review::{self, Selection};

/// Renders the results of the succeeded jobs among `jobs` in `crs`, the
/// targets `selection` keeps.
/// Blocking: reads files and builds a PROJ object.
pub fn render_jobs(
    data: &DataDir,
    jobs: &[JobRecord],
    crs: &str,
    format: Format,
    selection: Selection,
) -> Result<String, String> {
    let crs = TargetCrs::parse(crs).map_err(|e| format!("stored CRS: {e}"))?;
    let frames = load_frames(data, jobs, selection)?;
    Ok(render(format, &frames, &crs))
}

/// The stored results of the succeeded jobs among `jobs`, by image name,
/// with the targets their reviews and `selection` keep.
pub fn load_frames(
    data: &DataDir,
    jobs: &[JobRecord],
    selection: Selection,
) -> Result<Vec<FrameResult>, String> {
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
pub fn load_result(data: &DataDir, job: JobId) -> Result<FrameResult, String> {
    let bytes = std::fs::read(data.result_path(job))
        .map_err(|e| format!("cannot read a stored result: {e}"))?;
    serde_json::from_slice(&bytes).map_err(|e| format!("cannot parse a stored result: {e}"))
}
