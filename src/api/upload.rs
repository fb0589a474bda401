//! Receiving frames: raw bodies and multipart parts streamed chunk by chunk
//! into the spool (never held whole in memory), with size limits counted as
//! bytes arrive, each file recognised as an image by its first bytes, then
//! moved into `frames/` and recorded as jobs in one store transaction.

use crate::error_code::ErrorCode;
use std::path::PathBuf;

use axum::extract::{FromRequest, Multipart, Request};
use axum::http::{header, HeaderMap, StatusCode};
use futures_util::{Stream, StreamExt};
use tokio::io::AsyncWriteExt;
use uuid::Uuid;

use super::error::ApiError;
use super::AppState;
use crate::jobs::model::JobError;
use crate::jobs::{FlightId, FlightRecord, IdemKey, JobParams, JobRecord, NewJob};
use crate::storage::header::{self as frame_header, PixelLimits};
use crate::storage::spool::{magic_hex, sanitize_name, sniff_image};
use crate::storage::DataDir;

/// Upload limits.
#[derive(Debug, Clone)]
pub struct UploadLimits {
    pub max_frame_bytes: u64,
    /// What a frame's header may claim.
    pub pixels: PixelLimits,
    /// Uploads are refused (507) while the data folder has less free.
    pub min_free_bytes: u64,
    pub max_request_bytes: u64,
    pub max_frames_per_request: usize,
    /// Most frames one flight may hold, across requests.
    pub max_frames_per_flight: usize,
}

/// One file of a request, in the spool.
#[derive(Debug)]
pub struct Part {
    pub image: String,
    pub bytes: u64,
    /// The spooled file and its type, or why it is not an image.
    pub content: Result<(PathBuf, &'static str), JobError>,
}

/// Every file of a request. Dropping it removes spooled files not yet
/// committed, so a failed request leaves nothing behind.
#[derive(Debug, Default)]
pub struct Upload {
    pub parts: Vec<Part>,
}

impl Drop for Upload {
    fn drop(&mut self) {
        for part in &self.parts {
            if let Ok((path, _)) = &part.content {
                let _ = std::fs::remove_file(path);
            }
        }
    }
}

/// How many files a request may carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Expect {
    One,
    Many,
}

/// Reads the request body into the spool: multipart (every part with a
/// file name is a frame) or a raw body named by `raw_name`.
pub async fn receive(
    state: &AppState,
    req: Request,
    expect: Expect,
    raw_name: Option<String>,
) -> Result<Upload, ApiError> {
    let limits = &state.limits;
    if let Some(len) = content_length(req.headers()) {
        if len > limits.max_request_bytes {
            return Err(request_too_large(limits));
        }
    }
    if let Err(e) = check_free_space(state).await {
        drain(&mut req.into_body().into_data_stream()).await;
        return Err(e);
    }
    let content_type = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    let mut upload = Upload::default();
    let mut total = 0u64;
    if content_type.starts_with("multipart/form-data") {
        let mut multipart = Multipart::from_request(req, &()).await.map_err(|e| {
            ApiError::new(
                ErrorCode::InvalidMultipart,
                format!("bad multipart body: {e}"),
            )
        })?;
        loop {
            let field = multipart.next_field().await.map_err(multipart_error)?;
            let Some(field) = field else { break };
            let field_name = field.name().unwrap_or("").to_string();
            let Some(file_name) = field.file_name().map(str::to_string) else {
                return Err(ApiError::new(
                    ErrorCode::UnexpectedField,
                    format!(
                        "multipart field {field_name:?} is not a file; send frames as file parts \
                         (curl -F frame=@DJI_0001.JPG) and parameters in the query string"
                    ),
                )
                .with_field(field_name));
            };
            if upload.parts.len() == limits.max_frames_per_request {
                return Err(ApiError::new(
                    ErrorCode::TooManyFrames,
                    format!(
                        "more than {} frames in one request",
                        limits.max_frames_per_request
                    ),
                ));
            }
            if expect == Expect::One && !upload.parts.is_empty() {
                return Err(ApiError::new(
                    ErrorCode::ExpectedOneFrame,
                    "this route takes one frame; POST /v1/flights takes many",
                ));
            }
            let mut stream = field.map(|r| r.map_err(multipart_error));
            match spool_stream(state, file_name, &mut stream, &mut total).await {
                Ok(part) => upload.parts.push(part),
                Err(e) => {
                    drain(&mut stream).await;
                    drop(stream);
                    while let Ok(Ok(Some(mut field))) =
                        tokio::time::timeout(DRAIN_TIME, multipart.next_field()).await
                    {
                        drain(&mut field).await;
                    }
                    return Err(e);
                }
            }
        }
    } else {
        if content_type.starts_with("application/json")
            || content_type.starts_with("application/x-www-form-urlencoded")
            || content_type.starts_with("text/")
        {
            return Err(ApiError::new(
                ErrorCode::UnsupportedMediaType,
                format!(
                    "Content-Type {content_type:?}: send the frame's bytes (image/jpeg, \
                     image/tiff, image/png, application/octet-stream) or multipart/form-data"
                ),
            ));
        }
        if expect == Expect::Many {
            return Err(ApiError::new(
                ErrorCode::MultipartRequired,
                "a flight is submitted as multipart/form-data, one file part per frame",
            ));
        }
        let name = raw_name
            .or_else(|| disposition_filename(req.headers()))
            .unwrap_or_else(|| "upload".to_string());
        let mut stream = req
            .into_body()
            .into_data_stream()
            .map(|r| r.map_err(|e| ApiError::new(ErrorCode::BodyReadFailed, e.to_string())));
        match spool_stream(state, name, &mut stream, &mut total).await {
            Ok(part) => upload.parts.push(part),
            Err(e) => {
                drain(&mut stream).await;
                return Err(e);
            }
        }
    }
    if upload.parts.is_empty() {
        return Err(ApiError::new(
            ErrorCode::NoFrames,
            "the request carries no file part",
        ));
    }
    Ok(upload)
}

/// Streams one file into the spool, counting bytes against the limits.
async fn spool_stream(
    state: &AppState,
    raw_name: String,
    stream: &mut (impl Stream<Item = Result<axum::body::Bytes, ApiError>> + Unpin),
    total: &mut u64,
) -> Result<Part, ApiError> {
    let limits = &state.limits;
    let image = sanitize_name(&raw_name).ok_or_else(|| {
        ApiError::new(
            ErrorCode::InvalidFileName,
            format!("file name {raw_name:?} has no usable name"),
        )
    })?;
    let path = state.data.spool_path();
    let mut file = tokio::fs::File::create(&path)
        .await
        .map_err(|e| ApiError::internal("cannot create a spool file", e))?;
    // Removes the file on every early return below.
    let mut guard = RemoveOnDrop(Some(path.clone()));
    let mut head: Vec<u8> = Vec::with_capacity(16);
    let mut bytes = 0u64;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk?;
        bytes += chunk.len() as u64;
        *total += chunk.len() as u64;
        if bytes > limits.max_frame_bytes {
            return Err(ApiError::new(
                ErrorCode::FrameTooLarge,
                format!(
                    "{image}: larger than the {} MiB limit per frame",
                    limits.max_frame_bytes >> 20
                ),
            ));
        }
        if *total > limits.max_request_bytes {
            return Err(request_too_large(limits));
        }
        if head.len() < 16 {
            let take = (16 - head.len()).min(chunk.len());
            head.extend_from_slice(&chunk[..take]);
        }
        file.write_all(&chunk).await.map_err(spool_error)?;
    }
    // Durable before the client hears "created".
    file.sync_all().await.map_err(spool_error)?;
    drop(file);
    let content = if bytes == 0 {
        Err(JobError {
            code: ErrorCode::EmptyFrame,
            message: format!("{image}: the file is empty"),
        })
    } else {
        match sniff_image(&head) {
            Some(ext) => {
                let (spooled, pixels) = (path.clone(), limits.pixels);
                let claimed =
                    tokio::task::spawn_blocking(move || frame_header::check(&spooled, pixels))
                        .await
                        .map_err(|e| ApiError::internal("reading a frame header", e))?;
                match claimed {
                    Err(e) => Err(JobError {
                        code: e.code(),
                        message: format!("{image}: {e}"),
                    }),
                    Ok(_) => Ok((guard.0.take().expect("path kept"), ext)),
                }
            }
            None => Err(JobError {
                code: ErrorCode::NotAnImage,
                message: format!(
                    "{image}: not a JPEG, TIFF or PNG image (first bytes {})",
                    magic_hex(&head)
                ),
            }),
        }
    };
    Ok(Part {
        image,
        bytes,
        content,
    })
}

/// A spool write that failed: a full disk is the client's 507, anything
/// else ours.
fn spool_error(e: std::io::Error) -> ApiError {
    if e.raw_os_error() == Some(libc::ENOSPC) {
        insufficient_storage("the data folder's disk filled up during the upload")
    } else {
        ApiError::internal("cannot write to the spool", e)
    }
}

pub fn insufficient_storage(why: &str) -> ApiError {
    ApiError::new(
        ErrorCode::InsufficientStorage,
        format!("{why}; running jobs go on, try again once space is freed"),
    )
    .with_header(axum::http::header::RETRY_AFTER, "60")
}

/// Refuses uploads while the data folder has less than the minimum free.
pub async fn check_free_space(state: &AppState) -> Result<(), ApiError> {
    let data = state.data.clone();
    let free = tokio::task::spawn_blocking(move || data.free_bytes())
        .await
        .map_err(|e| ApiError::internal("checking free disk space", e))?
        .map_err(|e| ApiError::internal("checking free disk space", e))?;
    if free < state.limits.min_free_bytes {
        return Err(insufficient_storage(&format!(
            "the data folder has {} MiB free, less than the {} MiB kept in reserve",
            free >> 20,
            state.limits.min_free_bytes >> 20
        )));
    }
    Ok(())
}

/// After refusing an upload, this much more of the body is read and thrown
/// away so that clients still sending see the error response instead of a
/// reset connection; beyond it the connection is closed.
const DRAIN_BYTES: usize = 64 << 20;
const DRAIN_TIME: std::time::Duration = std::time::Duration::from_secs(10);

async fn drain<S, T, E>(stream: &mut S)
where
    S: Stream<Item = Result<T, E>> + Unpin,
    T: AsRef<[u8]>,
{
    let mut left = DRAIN_BYTES;
    let _ = tokio::time::timeout(DRAIN_TIME, async {
        while let Some(Ok(chunk)) = stream.next().await {
            left = left.saturating_sub(chunk.as_ref().len());
            if left == 0 {
                break;
            }
        }
    })
    .await;
}

struct RemoveOnDrop(Option<PathBuf>);
impl Drop for RemoveOnDrop {
    fn drop(&mut self) {
        if let Some(path) = self.0.take() {
            let _ = std::fs::remove_file(path);
        }
    }
}

fn request_too_large(limits: &UploadLimits) -> ApiError {
    ApiError::new(
        ErrorCode::RequestTooLarge,
        format!(
            "the request is larger than the {} MiB limit",
            limits.max_request_bytes >> 20
        ),
    )
}

fn multipart_error(e: axum::extract::multipart::MultipartError) -> ApiError {
    let status = e.status();
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::new(ErrorCode::RequestTooLarge, e.body_text())
    } else {
        ApiError::new(
            ErrorCode::InvalidMultipart,
            format!("bad multipart body: {}", e.body_text()),
        )
    }
}

fn content_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)?
        .to_str()
        .ok()?
        .parse()
        .ok()
}

/// `filename` of a `Content-Disposition` header, if any.
fn disposition_filename(headers: &HeaderMap) -> Option<String> {
    let value = headers.get(header::CONTENT_DISPOSITION)?.to_str().ok()?;
    value.split(';').find_map(|p| {
        let (k, v) = p.trim().split_once('=')?;
        (k.trim().eq_ignore_ascii_case("filename")).then(|| v.trim().trim_matches('"').to_string())
    })
}

/// Where the jobs of an upload go.
pub enum Target {
    /// A new flight with its parameters and, optionally, an
    /// `s3://bucket/prefix/` its results are written to when it finishes.
    NewFlight(Box<JobParams>, Option<String>),
    Flight(FlightId),
}

/// Refuses a name used twice in the request or already in the flight
/// (names identify frames in results), and a flight that would grow past
/// `max_frames` frames.
pub fn check_names<'a>(
    store: &dyn crate::jobs::JobStore,
    target: &Target,
    names: impl Iterator<Item = &'a str>,
    max_frames: usize,
) -> Result<(), ApiError> {
    let mut seen: std::collections::HashSet<String> = match target {
        Target::Flight(id) => store.flight_images(*id)?.into_iter().collect(),
        Target::NewFlight(..) => Default::default(),
    };
    let names: Vec<&str> = names.collect();
    if seen.len() + names.len() > max_frames {
        return Err(ApiError::new(ErrorCode::TooManyFrames,
            format!(
                "the flight would hold {} frames, more than the {max_frames} allowed (--max-frames-per-flight)",
                seen.len() + names.len()
            ),
        ));
    }
    for name in names {
        if !seen.insert(name.to_string()) {
            return Err(ApiError::new(ErrorCode::DuplicateImage,
                format!(
                    "{name}: a frame of this name is already in the flight; names identify frames in results"
                ),
            ));
        }
    }
    Ok(())
}

/// Records jobs in one store transaction, in a new flight or an existing
/// one (whose names and limit the store checks again under its lock:
/// [`check_names`] runs before the upload is moved into place, and two
/// requests may pass it at once).
pub fn record(
    store: &dyn crate::jobs::JobStore,
    jobs: &[NewJob],
    target: Target,
    idem: Option<&IdemKey>,
    max_frames: usize,
) -> Result<(FlightRecord, Vec<JobRecord>), ApiError> {
    let recorded = match target {
        Target::NewFlight(params, export_to) => {
            let flight = store.create_flight(&params, jobs, export_to, idem)?;
            let jobs = store.flight_jobs(flight.id)?.unwrap_or_default();
            Some((flight, jobs))
        }
        Target::Flight(id) => match store.add_to_flight(id, jobs, idem, max_frames)? {
            Some(jobs) => store.flight(id)?.map(|flight| (flight, jobs)),
            None => None,
        },
    };
    recorded.ok_or_else(|| ApiError::not_found("flight", "(deleted meanwhile)"))
}

/// Moves an upload's frames into place and records them as jobs, in one
/// store transaction. Refused parts become failed jobs with their reason,
/// so the rest of a flight goes on. Runs on a blocking thread.
pub fn commit(
    store: &dyn crate::jobs::JobStore,
    data: &DataDir,
    mut upload: Upload,
    target: Target,
    idem: Option<IdemKey>,
    max_frames: usize,
) -> Result<(FlightRecord, Vec<JobRecord>), ApiError> {
    check_names(
        store,
        &target,
        upload.parts.iter().map(|p| p.image.as_str()),
        max_frames,
    )?;
    let mut jobs = Vec::with_capacity(upload.parts.len());
    for part in upload.parts.iter_mut() {
        let id = Uuid::now_v7();
        let (ext, rejected) = match part.content.clone() {
            Ok((tmp, ext)) => {
                let dest = data.frame_path(id, ext);
                std::fs::rename(&tmp, &dest)
                    .map_err(|e| ApiError::internal("cannot move a frame into place", e))?;
                // Until the commit below succeeds, dropping the upload
                // removes the frame from its new place.
                part.content = Ok((dest, ext));
                (ext.to_string(), None)
            }
            Err(e) => ("none".to_string(), Some(e.clone())),
        };
        jobs.push(NewJob {
            id,
            image: part.image.clone(),
            ext,
            bytes: part.bytes,
            rejected,
            source: None,
        });
    }
    sync_dir(&data.root().join("frames"));
    let frames: Vec<PathBuf> = jobs
        .iter()
        .filter(|j| j.rejected.is_none())
        .map(|j| data.frame_path(j.id, &j.ext))
        .collect();
    data.publish_all(&frames.iter().map(PathBuf::as_path).collect::<Vec<_>>())
        .map_err(|e| ApiError::internal("cannot write a frame to the shared files", e))?;
    let done = record(store, &jobs, target, idem.as_ref(), max_frames)?;
    // Committed: the frames belong to their jobs now.
    upload.parts.clear();
    Ok(done)
}

/// Makes renames in `dir` durable.
fn sync_dir(dir: &std::path::Path) {
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
}
