//! A flight's survey of ground control points and the GCP files made from
//! it: the survey is stored beside the flight (`surveys/{flight}.json`, the
//! file's text as uploaded), and the exports are computed from the stored
//! frame results whenever they are asked for, so a survey can come before
//! or after the frames.

use serde::{Deserialize, Serialize};

use crate::pipeline::georef::Transformer;
use crate::storage::{DataDir, StoredFileError};
use crate::survey::assign::parse_assignments;
use crate::survey::matching::{match_frames, Matched, DEFAULT_PIXEL_TOLERANCE};
use crate::survey::parse::{parse_survey, SurveyError};
use crate::survey::{export, Survey};

use super::model::{FlightId, FlightRecord, JobRecord};
use super::results::load_frames;
use super::review::Selection;
use crate::pipeline::frame::FrameResult;

/// A survey as stored: the uploaded text, the CRS parameter, if any, and
/// the assignment file's text, if any (see [`crate::survey::assign`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoredSurvey {
    pub crs: Option<String>,
    pub text: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub assignments: Option<String>,
}

impl StoredSurvey {
    pub fn parse(&self) -> Result<Survey, SurveyError> {
        let mut survey = parse_survey(&self.text, self.crs.as_deref())?;
        if let Some(text) = &self.assignments {
            survey.assignments = parse_assignments(text, &survey)?;
        }
        Ok(survey)
    }
}

/// Stores a flight's survey (replacing any before).
pub fn save_survey(data: &DataDir, flight: FlightId, survey: &StoredSurvey) -> std::io::Result<()> {
    let bytes = serde_json::to_vec(survey).expect("survey serializes");
    data.write_atomic(&data.survey_path(flight), &bytes)
}

/// A flight's stored survey, if it has one.
pub fn load_survey(
    data: &DataDir,
    flight: FlightId,
) -> Result<Option<StoredSurvey>, StoredFileError> {
    data.read_json(&data.survey_path(flight))
}

/// Every export file of a flight with a survey, from its succeeded jobs'
/// targets that `selection` keeps.
/// Blocking: reads results and runs PROJ.
pub fn flight_exports(
    data: &DataDir,
    flight: &FlightRecord,
    jobs: &[JobRecord],
    survey: &Survey,
    selection: Selection,
) -> Result<Vec<(&'static str, String)>, ExportError> {
    let frames = load_frames(data, jobs, selection)?;
    Ok(exports_for(&frames, flight, survey)?)
}

/// Why a flight's export files cannot be made.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Stored(#[from] StoredFileError),
    #[error(transparent)]
    Projection(#[from] export::ProjectionError),
}

/// Every export file from frame results already read.
pub fn exports_for(
    frames: &[FrameResult],
    flight: &FlightRecord,
    survey: &Survey,
) -> Result<Vec<(&'static str, String)>, export::ProjectionError> {
    let tolerance = flight
        .params
        .pixel_tolerance
        .unwrap_or(DEFAULT_PIXEL_TOLERANCE);
    let mut transformer = Transformer::default();
    let matched = match_frames(frames, survey, tolerance, &mut transformer);
    export::all(survey, &matched, tolerance, &mut transformer)
}

/// Which surveyed point each detection of `frames` is matched to, under
/// the flight's pixel tolerance.
pub fn matched_for(frames: &[FrameResult], flight: &FlightRecord, survey: &Survey) -> Matched {
    let tolerance = flight
        .params
        .pixel_tolerance
        .unwrap_or(DEFAULT_PIXEL_TOLERANCE);
    match_frames(frames, survey, tolerance, &mut Transformer::default())
}
