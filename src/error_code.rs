//! Every machine-readable error code the service gives, in one enum: a
//! request's problem document (`code`, with its HTTP status and title) and a
//! failed job's `error.code` (the status is what the request that carried
//! the frame would have got, had it been checked then). The OpenAPI
//! document lists them all from here.

use std::fmt;
use std::str::FromStr;

macro_rules! error_codes {
    ($( $(#[doc = $doc:literal])+ $name:ident = $code:literal, $status:literal, $title:literal; )+) => {
        /// A stable machine-readable error code.
        #[derive(
            Debug, Clone, Copy, PartialEq, Eq, Hash,
            serde::Serialize, serde::Deserialize,
        )]
        pub enum ErrorCode {
            $( $(#[doc = $doc])+ #[serde(rename = $code)] $name, )+
        }

        impl ErrorCode {
            /// Every code, in the order of the OpenAPI table.
            pub const ALL: &'static [ErrorCode] = &[$(ErrorCode::$name),+];

            /// The code as written in problem documents and job records.
            pub const fn as_str(self) -> &'static str {
                match self { $(ErrorCode::$name => $code),+ }
            }

            /// The HTTP status a request failing with this code gets.
            pub const fn status(self) -> u16 {
                match self { $(ErrorCode::$name => $status),+ }
            }

            /// A short summary of the kind of problem.
            pub const fn title(self) -> &'static str {
                match self { $(ErrorCode::$name => $title),+ }
            }

            /// What the code means (its doc comment).
            pub fn meaning(self) -> &'static str {
                match self { $(ErrorCode::$name => concat!($($doc),+).trim()),+ }
            }
        }
    };
}

error_codes! {
    // The request: its path, query, headers and body.
    /// A path parameter is malformed.
    InvalidPath = "invalid_path", 400, "Invalid path parameter";
    /// The query string is malformed, or a query value is out of range.
    InvalidQuery = "invalid_query", 400, "Invalid query";
    /// A query or form parameter the route does not take.
    UnknownParameter = "unknown_parameter", 400, "Unknown parameter";
    /// A detection parameter's value is invalid (`field` names it).
    InvalidParameter = "invalid_parameter", 422, "Invalid parameter";
    /// A job id is not a UUID.
    InvalidId = "invalid_id", 400, "Invalid id";
    /// A target index is not one of the job's targets.
    InvalidIndex = "invalid_index", 400, "Invalid index";
    /// A JSON body does not parse or does not have the expected shape.
    InvalidJson = "invalid_json", 400, "Invalid JSON";
    /// A review body is malformed.
    InvalidBody = "invalid_body", 400, "Invalid body";
    /// The Idempotency-Key header is malformed.
    InvalidIdempotencyKey = "invalid_idempotency_key", 400, "Invalid Idempotency-Key";
    /// The Idempotency-Key was used before with another request.
    IdempotencyKeyReused = "idempotency_key_reused", 422, "Idempotency-Key reused";
    /// Another request with this Idempotency-Key was recorded first.
    IdempotencyKeyTaken = "idempotency_key_taken", 409, "Idempotency-Key taken";
    /// The submission an Idempotency-Key names has been removed.
    IdempotentResultGone = "idempotent_result_gone", 410, "Idempotent result gone";
    /// A multipart body is malformed.
    InvalidMultipart = "invalid_multipart", 400, "Invalid multipart body";
    /// The body could not be read to its end (the client stopped sending).
    BodyReadFailed = "body_read_failed", 400, "Body read failed";
    /// A multipart field the route does not take.
    UnexpectedField = "unexpected_field", 400, "Unexpected field";
    /// A frame's file name is empty, too long or holds a path.
    InvalidFileName = "invalid_file_name", 400, "Invalid file name";
    /// A flight needs a name.
    MissingName = "missing_name", 400, "Missing name";
    /// A job is one frame; the request names more or none.
    ExpectedOneFrame = "expected_one_frame", 400, "Expected one frame";
    /// The request holds no frame.
    NoFrames = "no_frames", 400, "No frames";
    /// The request's media type is not one the route takes.
    UnsupportedMediaType = "unsupported_media_type", 415, "Unsupported media type";
    /// Flights are submitted as multipart/form-data (or JSON sources).
    MultipartRequired = "multipart_required", 415, "Multipart required";
    /// No format the Accept header allows.
    NotAcceptable = "not_acceptable", 406, "Not acceptable";
    /// The request is larger than the server takes.
    RequestTooLarge = "request_too_large", 413, "Request too large";
    /// More frames than a flight may hold.
    TooManyFrames = "too_many_frames", 413, "Too many frames";
    /// A frame name already in the flight.
    DuplicateImage = "duplicate_image", 409, "Duplicate image";
    /// A survey file does not parse.
    InvalidSurvey = "invalid_survey", 422, "Invalid survey";
    /// Assignments of targets to surveyed points do not parse or name
    /// unknown points.
    InvalidAssignments = "invalid_assignments", 422, "Invalid assignments";
    // What the request names.
    /// No such job, flight or file.
    NotFound = "not_found", 404, "Not found";
    /// No such route.
    RouteNotFound = "route_not_found", 404, "Route not found";
    /// The route does not take this method.
    MethodNotAllowed = "method_not_allowed", 405, "Method not allowed";
    /// The flight has no survey.
    NoSurvey = "no_survey", 404, "No survey";
    /// The flight still has jobs queued or running.
    FlightNotFinished = "flight_not_finished", 409, "Flight not finished";
    /// The job has no result (it has not succeeded).
    JobNotSucceeded = "job_not_succeeded", 409, "Job not succeeded";
    // S3 sources.
    /// A source is not an `s3://bucket/key` or `s3://bucket/prefix/` URL.
    InvalidSource = "invalid_source", 422, "Invalid source";
    /// The bucket is not on the server's allow-list.
    BucketNotAllowed = "bucket_not_allowed", 403, "Bucket not allowed";
    /// The bucket does not exist.
    NoSuchBucket = "no_such_bucket", 422, "No such bucket";
    /// The object does not exist.
    NoSuchObject = "no_such_object", 422, "No such object";
    /// No object under the prefix.
    EmptyPrefix = "empty_prefix", 422, "Empty prefix";
    /// The object store refused the server's credentials.
    S3AccessDenied = "s3_access_denied", 502, "Object store access denied";
    /// The object changed while it was read.
    ObjectChanged = "object_changed", 422, "Object changed";
    /// The object's bytes do not match its checksum.
    IntegrityCheckFailed = "integrity_check_failed", 422, "Integrity check failed";
    /// The object store is unreachable or failing.
    S3Unavailable = "s3_unavailable", 502, "Object store unavailable";
    // Frames (answered at once for a one-frame job; a flight's frame fails
    // its job instead).
    /// The frame is empty.
    EmptyFrame = "empty_frame", 400, "Empty frame";
    /// The frame is larger than the server's pixel, byte or memory limits.
    FrameTooLarge = "frame_too_large", 413, "Frame too large";
    /// The frame is too small to hold a target.
    FrameTooSmall = "frame_too_small", 422, "Frame too small";
    /// The frame does not decode.
    UnreadableFrame = "unreadable_frame", 422, "Unreadable frame";
    /// The file is not an image format the service reads.
    NotAnImage = "not_an_image", 415, "Not an image";
    /// The raster's format is one GDAL reads but the pipeline does not.
    UnsupportedFrame = "unsupported_frame", 422, "Unsupported frame";
    /// The raster's bands are not grey, RGB(A) or multispectral.
    UnsupportedBands = "unsupported_bands", 422, "Unsupported bands";
    /// A job's stored parameters are invalid.
    InvalidParameters = "invalid_parameters", 422, "Invalid parameters";
    /// Detection failed inside a library.
    DetectionFailed = "detection_failed", 500, "Detection failed";
    /// The worker process running the job died.
    WorkerCrashed = "worker_crashed", 500, "Worker crashed";
    // The server.
    /// No valid API key.
    Unauthorized = "unauthorized", 401, "Unauthorized";
    /// Over the client's requests per minute (see Retry-After).
    RateLimited = "rate_limited", 429, "Rate limited";
    /// The service is starting or shutting down.
    NotReady = "not_ready", 503, "Not ready";
    /// The service is shutting down (see Retry-After).
    ShuttingDown = "shutting_down", 503, "Shutting down";
    /// Too little free disk for the upload or the result.
    InsufficientStorage = "insufficient_storage", 507, "Insufficient storage";
    /// Between a worker process and the server only: the disk filled while
    /// a job's result was written; the job goes back to the queue, so no
    /// client sees this code.
    NoSpace = "no_space", 507, "No space";
    /// A failure of the server's; its log has the cause.
    Internal = "internal", 500, "Internal error";
}

impl utoipa::PartialSchema for ErrorCode {
    /// A string enum of every code; its description tabulates each code's
    /// HTTP status, title and meaning.
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{ObjectBuilder, SchemaType, Type};
        let mut table = String::from(
            "A stable machine-readable error code. Each code has one HTTP status.\n\n\
             | code | status | title | meaning |\n|---|---|---|---|\n",
        );
        for c in ErrorCode::ALL {
            table.push_str(&format!(
                "| `{}` | {} | {} | {} |\n",
                c.as_str(),
                c.status(),
                c.title(),
                c.meaning()
            ));
        }
        ObjectBuilder::new()
            .schema_type(SchemaType::Type(Type::String))
            .enum_values(Some(ErrorCode::ALL.iter().map(|c| c.as_str())))
            .description(Some(table))
            .into()
    }
}

impl utoipa::ToSchema for ErrorCode {}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A string that is no [`ErrorCode`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is no error code")]
pub struct UnknownCode(pub String);

impl FromStr for ErrorCode {
    type Err = UnknownCode;
    fn from_str(s: &str) -> Result<ErrorCode, UnknownCode> {
        ErrorCode::ALL
            .iter()
            .copied()
            .find(|c| c.as_str() == s)
            .ok_or_else(|| UnknownCode(s.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_is_distinct_snake_case_and_parses_back() {
        let mut seen = std::collections::HashSet::new();
        for &c in ErrorCode::ALL {
            let s = c.as_str();
            assert!(seen.insert(s), "{s} twice");
            assert!(
                s.chars()
                    .all(|ch| ch.is_ascii_lowercase() || ch == '_' || ch.is_ascii_digit()),
                "{s}"
            );
            assert_eq!(s.parse::<ErrorCode>(), Ok(c));
            assert_eq!(serde_json::to_value(c).unwrap(), serde_json::json!(s));
            assert!((400..600).contains(&c.status()), "{s}");
            assert!(!c.title().is_empty() && !c.meaning().is_empty(), "{s}");
        }
        assert!("no_such_code".parse::<ErrorCode>().is_err());
    }

    #[test]
    fn the_api_guide_lists_every_code_with_its_status() {
        let guide =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/api.md")).unwrap();
        for &c in ErrorCode::ALL {
            let row = format!("| `{}` | {} | {} |", c.as_str(), c.status(), c.title());
            assert!(guide.contains(&row), "docs/api.md lacks {row}");
        }
    }
}
