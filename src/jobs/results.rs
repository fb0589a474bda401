//! Stored frame results rendered as CSV or GeoJSON by the pipeline's own
//! writers, for the API and for results written back to object storage:
//! the same bytes as `gcp-tagger detect` on the same frames. Frames are
//! sorted by image name, so the order jobs finished in never shows.

use crate::pipeline::frame::FrameResult;
use crate::pipeline::georef::TargetCrs;
use crate::pipeline::output::{render, Format};
use crate::storage::DataDir;

use super::model::{JobRecord, JobState};

/// Renders the results of the succeeded jobs among `jobs` in `crs`.
/// Blocking: reads files and builds a PROJ object.
pub fn render_jobs(
    data: &DataDir,
    jobs: &[JobRecord],
    crs: &str,
    format: Format,
) -> Result<String, String> {
    let crs = TargetCrs::parse(crs).map_err(|e| format!("stored CRS: {e}"))?;
    let frames = load_frames(data, jobs)?;
    Ok(render(format, &frames, &crs))
}

/// The stored results of the succeeded jobs among `jobs`, by image name.
pub fn load_frames(data: &DataDir, jobs: &[JobRecord]) -> Result<Vec<FrameResult>, String> {
    let mut frames: Vec<FrameResult> = Vec::with_capacity(jobs.len());
    for job in jobs.iter().filter(|j| j.state == JobState::Succeeded) {
        let path = data.result_path(job.id);
        let bytes =
            std::fs::read(&path).map_err(|e| format!("cannot read a stored result: {e}"))?;
        let frame = serde_json::from_slice(&bytes)
            .map_err(|e| format!("cannot parse a stored result: {e}"))?;
        frames.push(frame);
    }
    frames.sort_by(|a, b| a.image.cmp(&b.image));
    Ok(frames)
}
