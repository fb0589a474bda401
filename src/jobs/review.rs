//! A person's word on each detection: accepted or rejected, stored with
//! the job (`results/{job}.review.json`, written atomically) and applied
//! wherever stored results are read. A rejected detection leaves every
//! result and export; with [`Selection::AcceptedOnly`] only accepted ones
//! stay.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::pipeline::frame::FrameResult;
use crate::storage::{DataDir, StoredFileError};

use super::model::JobId;

/// What a reviewer said of one detection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Accepted,
    Rejected,
    /// Not looked at yet (or the word taken back).
    Unreviewed,
}

/// Which detections results and exports keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Selection {
    /// Every detection but the rejected ones.
    #[default]
    NotRejected,
    /// The accepted ones only.
    AcceptedOnly,
}

impl Selection {
    pub fn from_accepted_only(accepted_only: Option<bool>) -> Selection {
        if accepted_only.unwrap_or(false) {
            Selection::AcceptedOnly
        } else {
            Selection::NotRejected
        }
    }

    fn keeps(self, verdict: Verdict) -> bool {
        match self {
            Selection::NotRejected => verdict != Verdict::Rejected,
            Selection::AcceptedOnly => verdict == Verdict::Accepted,
        }
    }
}

/// A job's verdicts by target index (its place in the stored result);
/// a target not listed is unreviewed.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Reviews {
    pub verdicts: BTreeMap<u32, Verdict>,
}

impl Reviews {
    pub fn verdict(&self, target: u32) -> Verdict {
        self.verdicts
            .get(&target)
            .copied()
            .unwrap_or(Verdict::Unreviewed)
    }

    pub fn set(&mut self, target: u32, verdict: Verdict) {
        if verdict == Verdict::Unreviewed {
            self.verdicts.remove(&target);
        } else {
            self.verdicts.insert(target, verdict);
        }
    }

    /// Removes the targets `selection` does not keep from `frame` (read
    /// from this job's stored result, whose order the indices follow).
    pub fn apply(&self, frame: &mut FrameResult, selection: Selection) {
        if self.verdicts.is_empty() && selection == Selection::NotRejected {
            return;
        }
        let mut index = 0u32;
        frame.targets.retain(|_| {
            let keep = selection.keeps(self.verdict(index));
            index += 1;
            keep
        });
    }
}

/// A job's stored reviews (none stored: every target unreviewed).
pub fn load(data: &DataDir, job: JobId) -> Result<Reviews, StoredFileError> {
    Ok(data.read_json(&data.review_path(job))?.unwrap_or_default())
}

/// Stores a job's reviews, replacing what was there.
pub fn save(data: &DataDir, job: JobId, reviews: &Reviews) -> std::io::Result<()> {
    let bytes = serde_json::to_vec(reviews).expect("reviews serialize");
    data.write_atomic(&data.review_path(job), &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selections_keep_what_they_say() {
        let mut r = Reviews::default();
        r.set(0, Verdict::Accepted);
        r.set(1, Verdict::Rejected);
        r.set(3, Verdict::Rejected);
        r.set(3, Verdict::Unreviewed);
        let kept = |s: Selection| {
            (0..4)
                .filter(|i| s.keeps(r.verdict(*i)))
                .collect::<Vec<_>>()
        };
        assert_eq!(kept(Selection::NotRejected), vec![0, 2, 3]);
        assert_eq!(kept(Selection::AcceptedOnly), vec![0]);
        assert_eq!(
            serde_json::to_string(&r).unwrap(),
            r#"{"verdicts":{"0":"accepted","1":"rejected"}}"#
        );
    }
}
