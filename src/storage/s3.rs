//! S3-style object storage: client-named sources (`s3://bucket/key` for one
//! frame, `s3://bucket/prefix/` for every frame under a prefix) resolved to
//! objects, streamed into the spool with integrity checks, and results
//! written back.
//!
//! The endpoint, region and credentials come from the server's
//! configuration only (the standard `AWS_*` environment and credential
//! chain of the `object_store` crate, plus `--s3-endpoint` for MinIO/Ceph
//! style stores). A client names a bucket and a key, never a host: bucket
//! names are checked against S3's naming rules (so a "bucket" can never
//! carry a host or a path into the request) and, when configured, an
//! allow-list.

use crate::error_code::ErrorCode;
use std::collections::HashMap;
use std::path::Path as FsPath;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::StreamExt;
use md5::{Digest, Md5};
use object_store::aws::{AmazonS3, AmazonS3Builder};
use object_store::path::Path;
use object_store::{
    Attribute, Attributes, BackoffConfig, ClientOptions, GetOptions, ObjectStore, ObjectStoreExt,
    PutOptions, PutPayload, RetryConfig,
};
use tokio::io::AsyncWriteExt;

/// File name extensions listed from a prefix (case-insensitive); the
/// content is checked again when the object arrives.
pub const IMAGE_EXTENSIONS: [&str; 5] = ["jpg", "jpeg", "tif", "tiff", "png"];

/// Server-side S3 settings.
#[derive(Debug, Clone, Default)]
pub struct S3Config {
    /// Endpoint URL of an S3-compatible store (MinIO, Ceph); `None` uses
    /// `AWS_ENDPOINT_URL` or AWS itself.
    pub endpoint: Option<String>,
    /// Region; `None` uses `AWS_REGION` / `AWS_DEFAULT_REGION`, else us-east-1.
    pub region: Option<String>,
    /// Buckets clients may name; empty allows any bucket at the endpoint.
    pub allowed_buckets: Vec<String>,
    /// Checks a downloaded object's MD5 against a plain (non-multipart)
    /// ETag. Stores that encrypt with SSE-KMS use other ETags: turn it off.
    pub verify_md5: bool,
    /// Seconds one request may take at most (a whole object's download).
    pub request_timeout_secs: u64,
}

/// What went wrong with a source, with a stable code for problems and jobs.
#[derive(Debug, Clone, thiserror::Error)]
pub enum S3Error {
    #[error("{0}")]
    BadUrl(String),
    #[error("bucket {0:?} is not in the server's S3 allow-list")]
    BucketNotAllowed(String),
    #[error("bucket {0:?} does not exist")]
    NoSuchBucket(String),
    #[error("no object at {0}")]
    NotFound(String),
    #[error("no image objects (.jpg, .jpeg, .tif, .tiff, .png) under {0}")]
    EmptyPrefix(String),
    #[error("the object store refused the server's credentials for {0}: {1}")]
    AccessDenied(String, String),
    #[error("{0} changed after it was submitted (its ETag no longer matches); submit it again")]
    Changed(String),
    #[error("{0}: {1}")]
    Integrity(String, String),
    #[error("{url} is {bytes} bytes, more than the {limit} bytes allowed per frame")]
    TooLarge { url: String, bytes: u64, limit: u64 },
    #[error("cannot reach the object store for {0}: {1}")]
    Unavailable(String, String),
    #[error("cannot write {0} to the spool: {1}")]
    Spool(String, String),
}

impl S3Error {
    pub fn code(&self) -> ErrorCode {
        match self {
            S3Error::BadUrl(_) => ErrorCode::InvalidSource,
            S3Error::BucketNotAllowed(_) => ErrorCode::BucketNotAllowed,
            S3Error::NoSuchBucket(_) => ErrorCode::NoSuchBucket,
            S3Error::NotFound(_) => ErrorCode::NoSuchObject,
            S3Error::EmptyPrefix(_) => ErrorCode::EmptyPrefix,
            S3Error::AccessDenied(..) => ErrorCode::S3AccessDenied,
            S3Error::Changed(_) => ErrorCode::ObjectChanged,
            S3Error::Integrity(..) => ErrorCode::IntegrityCheckFailed,
            S3Error::TooLarge { .. } => ErrorCode::FrameTooLarge,
            S3Error::Unavailable(..) => ErrorCode::S3Unavailable,
            S3Error::Spool(..) => ErrorCode::Internal,
        }
    }
}

/// A parsed `s3://` source.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum S3Url {
    Object {
        bucket: String,
        key: String,
    },
    /// Every object under `prefix` (empty: the whole bucket; else ends in `/`).
    Prefix {
        bucket: String,
        prefix: String,
    },
}

impl S3Url {
    /// Parses `s3://bucket/key` (one object) or `s3://bucket/prefix/` and
    /// `s3://bucket` (every object under it). Keys are taken literally.
    pub fn parse(raw: &str) -> Result<S3Url, S3Error> {
        let bad = |why: &str| S3Error::BadUrl(format!("{raw:?}: {why}"));
        let rest = raw
            .strip_prefix("s3://")
            .ok_or_else(|| bad("sources are s3://bucket/key or s3://bucket/prefix/"))?;
        let (bucket, key) = rest.split_once('/').unwrap_or((rest, ""));
        check_bucket_name(bucket).map_err(|why| bad(&why))?;
        let bucket = bucket.to_string();
        if key.is_empty() {
            return Ok(S3Url::Prefix {
                bucket,
                prefix: String::new(),
            });
        }
        if key.len() > 1024 {
            return Err(bad("keys are at most 1024 bytes"));
        }
        if key.chars().any(char::is_control) {
            return Err(bad("the key has control characters"));
        }
        // An empty segment anywhere (object_store drops a leading one, so
        // `s3://b//secret/x` would fetch `secret/x`), "." or "..": no key
        // names another object than it reads as, or climbs out of its prefix.
        if key.trim_end_matches('/').split('/').any(str::is_empty) {
            return Err(bad(
                "the key has an empty segment (two slashes, or one after the bucket)",
            ));
        }
        Path::parse(key.trim_end_matches('/')).map_err(|e| bad(&e.to_string()))?;
        Ok(if key.ends_with('/') {
            S3Url::Prefix {
                bucket,
                prefix: key.to_string(),
            }
        } else {
            S3Url::Object {
                bucket,
                key: key.to_string(),
            }
        })
    }

    pub fn bucket(&self) -> &str {
        match self {
            S3Url::Object { bucket, .. } | S3Url::Prefix { bucket, .. } => bucket,
        }
    }
}

impl std::fmt::Display for S3Url {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            S3Url::Object { bucket, key } => write!(f, "s3://{bucket}/{key}"),
            S3Url::Prefix { bucket, prefix } => write!(f, "s3://{bucket}/{prefix}"),
        }
    }
}

/// S3's bucket naming rules: 3-63 characters of lowercase letters, digits,
/// dots and hyphens, starting and ending with a letter or digit, no `..`,
/// not an IP address.
fn check_bucket_name(bucket: &str) -> Result<(), String> {
    let ok_chars = bucket
        .bytes()
        .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'.' || b == b'-');
    let edges = bucket
        .bytes()
        .next()
        .zip(bucket.bytes().last())
        .is_some_and(|(a, z)| a.is_ascii_alphanumeric() && z.is_ascii_alphanumeric());
    if !(3..=63).contains(&bucket.len()) || !ok_chars || !edges || bucket.contains("..") {
        return Err(format!(
            "{bucket:?} is not a bucket name (3-63 of a-z, 0-9, '.', '-')"
        ));
    }
    if bucket.parse::<std::net::Ipv4Addr>().is_ok() {
        return Err(format!("{bucket:?} is an IP address, not a bucket"));
    }
    Ok(())
}

/// One object to fetch: where it is and what it was at submission.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ObjectRef {
    pub bucket: String,
    pub key: String,
    pub size: u64,
    pub etag: Option<String>,
}

impl ObjectRef {
    pub fn url(&self) -> String {
        format!("s3://{}/{}", self.bucket, self.key)
    }
}

/// What a source expands to.
#[derive(Debug, Clone, Default)]
pub struct Resolved {
    /// Image objects, sorted by key.
    pub objects: Vec<ObjectRef>,
    /// Keys under a prefix skipped because their extension is not an image's.
    pub skipped: Vec<String>,
}

/// The S3 client of the server: one `object_store` client per bucket, built
/// on first use and kept.
pub struct S3 {
    config: S3Config,
    clients: Mutex<HashMap<String, Arc<AmazonS3>>>,
}

impl S3 {
    pub fn new(config: S3Config) -> S3 {
        S3 {
            config,
            clients: Mutex::new(HashMap::new()),
        }
    }

    pub fn config(&self) -> &S3Config {
        &self.config
    }

    /// The client for a bucket named by the server's own configuration
    /// (the shared files' bucket), through the same checks as a client's.
    pub fn client_for(&self, bucket: &str) -> Result<Arc<AmazonS3>, S3Error> {
        self.client(bucket)
    }

    /// The client for a bucket, after the allow-list.
    fn client(&self, bucket: &str) -> Result<Arc<AmazonS3>, S3Error> {
        check_bucket_name(bucket).map_err(S3Error::BadUrl)?;
        if !self.config.allowed_buckets.is_empty()
            && !self.config.allowed_buckets.iter().any(|b| b == bucket)
        {
            return Err(S3Error::BucketNotAllowed(bucket.to_string()));
        }
        let mut clients = self.clients.lock().expect("s3 clients lock");
        if let Some(c) = clients.get(bucket) {
            return Ok(c.clone());
        }
        let mut builder = AmazonS3Builder::from_env().with_bucket_name(bucket);
        let endpoint = self.config.endpoint.clone().or_else(|| {
            std::env::var("AWS_ENDPOINT_URL")
                .or_else(|_| std::env::var("AWS_ENDPOINT"))
                .ok()
        });
        if let Some(endpoint) = &endpoint {
            builder = builder.with_endpoint(endpoint);
        }
        if let Some(region) = &self.config.region {
            builder = builder.with_region(region);
        }
        let timeout = Duration::from_secs(self.config.request_timeout_secs.max(1));
        // These options replace the builder's client options as a whole.
        let options = ClientOptions::new()
            .with_allow_http(endpoint.is_some_and(|e| e.starts_with("http://")))
            .with_connect_timeout(Duration::from_secs(10))
            // A stalled transfer fails fast and is retried from where it
            // stopped; a slow but moving one has the whole timeout.
            .with_read_timeout(Duration::from_secs(30))
            .with_timeout(timeout);
        let retry = RetryConfig {
            backoff: BackoffConfig {
                init_backoff: Duration::from_millis(200),
                max_backoff: Duration::from_secs(10),
                base: 2.0,
            },
            max_retries: 5,
            retry_timeout: Duration::from_secs(180),
        };
        let client = builder
            .with_client_options(options)
            .with_retry(retry)
            .build()
            .map_err(|e| S3Error::BadUrl(format!("S3 client for bucket {bucket:?}: {e}")))?;
        let client = Arc::new(client);
        clients.insert(bucket.to_string(), client.clone());
        Ok(client)
    }

    /// Checks that a source can be read and lists what it names: one
    /// object, or the image objects under a prefix sorted by key.
    pub async fn resolve(&self, url: &S3Url) -> Result<Resolved, S3Error> {
        let client = self.client(url.bucket())?;
        let shown = url.to_string();
        match url {
            S3Url::Object { bucket, key } => {
                let path = Path::parse(key).map_err(|e| S3Error::BadUrl(e.to_string()))?;
                match client.head(&path).await {
                    Ok(meta) => Ok(Resolved {
                        objects: vec![ObjectRef {
                            bucket: bucket.clone(),
                            key: key.clone(),
                            size: meta.size,
                            etag: meta.e_tag,
                        }],
                        skipped: Vec::new(),
                    }),
                    // A HEAD cannot tell a missing bucket from a missing
                    // key; a listing can.
                    Err(object_store::Error::NotFound { .. }) => {
                        match client.list(Some(&path)).next().await {
                            Some(Err(e)) => Err(classify(bucket, &shown, e)),
                            _ => Err(S3Error::NotFound(shown)),
                        }
                    }
                    Err(e) => Err(classify(bucket, &shown, e)),
                }
            }
            S3Url::Prefix { bucket, prefix } => {
                let base = (!prefix.is_empty())
                    .then(|| Path::parse(prefix.trim_end_matches('/')))
                    .transpose()
                    .map_err(|e| S3Error::BadUrl(e.to_string()))?;
                let mut listing = client.list(base.as_ref());
                let mut out = Resolved::default();
                while let Some(meta) = listing.next().await {
                    let meta = meta.map_err(|e| classify(bucket, &shown, e))?;
                    let key = meta.location.to_string();
                    let is_image = meta.location.extension().is_some_and(|ext| {
                        IMAGE_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str())
                    });
                    if is_image {
                        out.objects.push(ObjectRef {
                            bucket: bucket.clone(),
                            key,
                            size: meta.size,
                            etag: meta.e_tag,
                        });
                    } else {
                        out.skipped.push(key);
                    }
                }
                if out.objects.is_empty() {
                    return Err(S3Error::EmptyPrefix(shown));
                }
                // Byte order of keys: stable whatever order a store lists in.
                out.objects.sort_by(|a, b| a.key.cmp(&b.key));
                out.skipped.sort();
                Ok(out)
            }
        }
    }

    /// Streams an object into `dest` (a spool file), chunk by chunk, and
    /// checks it: same ETag as at submission, the size it was listed with,
    /// and the MD5 of a plain ETag. Interrupted transfers are resumed by
    /// range (`object_store` retries the body with the same ETag). Returns
    /// the bytes written and the first bytes of the object.
    pub async fn fetch(
        &self,
        obj: &ObjectRef,
        dest: &FsPath,
        max_bytes: u64,
    ) -> Result<(u64, Vec<u8>), S3Error> {
        let url = obj.url();
        let client = self.client(&obj.bucket)?;
        let path = Path::parse(&obj.key).map_err(|e| S3Error::BadUrl(e.to_string()))?;
        let options = GetOptions {
            if_match: obj.etag.clone(),
            ..Default::default()
        };
        let got = client.get_opts(&path, options).await.map_err(|e| match e {
            object_store::Error::Precondition { .. } => S3Error::Changed(url.clone()),
            e => classify(&obj.bucket, &url, e),
        })?;
        let size = got.meta.size;
        if size > max_bytes {
            return Err(S3Error::TooLarge {
                url,
                bytes: size,
                limit: max_bytes,
            });
        }
        let spool_err = |e: std::io::Error| S3Error::Spool(url.clone(), e.to_string());
        let mut file = tokio::fs::File::create(dest).await.map_err(spool_err)?;
        let mut md5 = Md5::new();
        let mut head = Vec::with_capacity(16);
        let mut written = 0u64;
        let mut stream = got.into_stream();
        while let Some(chunk) = stream.next().await {
            let chunk = chunk.map_err(|e| classify(&obj.bucket, &url, e))?;
            written += chunk.len() as u64;
            if written > max_bytes {
                return Err(S3Error::TooLarge {
                    url,
                    bytes: written,
                    limit: max_bytes,
                });
            }
            if head.len() < 16 {
                let take = (16 - head.len()).min(chunk.len());
                head.extend_from_slice(&chunk[..take]);
            }
            md5.update(&chunk);
            file.write_all(&chunk).await.map_err(spool_err)?;
        }
        file.sync_all().await.map_err(spool_err)?;
        if written != size || written != obj.size {
            return Err(S3Error::Integrity(
                url,
                format!(
                    "received {written} bytes, the object was listed with {} (and announced {size})",
                    obj.size
                ),
            ));
        }
        if self.config.verify_md5 {
            if let Some(expected) = obj.etag.as_deref().and_then(plain_md5_etag) {
                let actual: String = md5.finalize().iter().map(|b| format!("{b:02x}")).collect();
                if actual != expected {
                    return Err(S3Error::Integrity(
                        url,
                        format!(
                            "MD5 {actual} of the received bytes differs from the ETag {expected}"
                        ),
                    ));
                }
            }
        }
        Ok((written, head))
    }

    /// Writes `bytes` to `s3://bucket/key` (one PUT: the object appears
    /// whole or not at all), with the Content-Type its name's extension
    /// calls for.
    pub async fn put(&self, bucket: &str, key: &str, bytes: Vec<u8>) -> Result<(), S3Error> {
        let url = format!("s3://{bucket}/{key}");
        let client = self.client(bucket)?;
        let path = Path::parse(key).map_err(|e| S3Error::BadUrl(e.to_string()))?;
        let mut attributes = Attributes::new();
        attributes.insert(Attribute::ContentType, content_type(key).into());
        let options = PutOptions {
            attributes,
            ..Default::default()
        };
        client
            .put_opts(&path, PutPayload::from(bytes), options)
            .await
            .map_err(|e| classify(bucket, &url, e))?;
        Ok(())
    }
}

/// The media type of a file the service writes, from its name.
pub fn content_type(name: &str) -> &'static str {
    let ext = name.rsplit_once('.').map_or("", |(_, e)| e);
    match ext.to_ascii_lowercase().as_str() {
        "csv" => "text/csv; charset=utf-8",
        "geojson" => "application/geo+json",
        "json" => "application/json",
        "txt" => "text/plain; charset=utf-8",
        "xml" => "application/xml",
        "zip" => "application/zip",
        _ => "application/octet-stream",
    }
}

/// The hex MD5 in a plain ETag (`"9e107d9d372bb6826bd81d3542a419d6"`);
/// `None` for multipart (`...-3`) and other forms.
fn plain_md5_etag(etag: &str) -> Option<String> {
    let inner = etag.trim().trim_start_matches("W/").trim_matches('"');
    (inner.len() == 32 && inner.bytes().all(|b| b.is_ascii_hexdigit()))
        .then(|| inner.to_ascii_lowercase())
}

/// Maps an `object_store` error on `url` to what a client can act on.
/// Listing errors come back generic, so the S3 error code in the text
/// (`<Code>NoSuchBucket</Code>`, HTTP 403) decides too.
fn classify(bucket: &str, url: &str, e: object_store::Error) -> S3Error {
    let text = e.to_string();
    let reason = s3_reason(&text);
    let has = |needle: &str| text.contains(needle);
    if has("NoSuchBucket") {
        return S3Error::NoSuchBucket(bucket.to_string());
    }
    match e {
        object_store::Error::NotFound { .. } => S3Error::NotFound(url.to_string()),
        object_store::Error::PermissionDenied { .. }
        | object_store::Error::Unauthenticated { .. } => {
            S3Error::AccessDenied(url.to_string(), reason)
        }
        object_store::Error::Precondition { .. } => S3Error::Changed(url.to_string()),
        _ if has("403 Forbidden")
            || has("AccessDenied")
            || has("SignatureDoesNotMatch")
            || has("InvalidAccessKeyId") =>
        {
            S3Error::AccessDenied(url.to_string(), reason)
        }
        _ if has("404 Not Found") => S3Error::NotFound(url.to_string()),
        _ => S3Error::Unavailable(url.to_string(), reason),
    }
}

/// A short reason from an error's text: the S3 error code and message
/// when the body carries them, else the first line.
fn s3_reason(text: &str) -> String {
    let tag = |name: &str| {
        let open = format!("<{name}>");
        let start = text.find(&open)? + open.len();
        let len = text[start..].find(&format!("</{name}>"))?;
        Some(text[start..start + len].trim().to_string())
    };
    let reason = match (tag("Code"), tag("Message")) {
        (Some(code), Some(message)) => format!("{code}: {message}"),
        (Some(code), None) => code,
        _ => text.lines().next().unwrap_or("").to_string(),
    };
    reason.chars().take(300).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_name_a_bucket_and_a_key_never_a_host() {
        assert_eq!(
            S3Url::parse("s3://flights/2026/a.JPG").unwrap(),
            S3Url::Object {
                bucket: "flights".into(),
                key: "2026/a.JPG".into()
            }
        );
        assert_eq!(
            S3Url::parse("s3://flights/2026/").unwrap(),
            S3Url::Prefix {
                bucket: "flights".into(),
                prefix: "2026/".into()
            }
        );
        assert_eq!(
            S3Url::parse("s3://flights").unwrap(),
            S3Url::Prefix {
                bucket: "flights".into(),
                prefix: String::new()
            }
        );
        for bad in [
            "http://flights/a.jpg",
            "s3://evil.com:80@flights/a.jpg",
            "s3://127.0.0.1/a.jpg",
            "s3://Flights/a.jpg",
            "s3://fl/a.jpg",
            "s3://flights/../etc/passwd",
            "s3://flights/a//b.jpg",
            "s3://flights//secret/canary.jpg",
            "s3://flights//",
            "s3://flights/a\n.jpg",
            "/vsis3/flights/a.jpg",
        ] {
            assert!(S3Url::parse(bad).is_err(), "{bad} was accepted");
        }
    }

    #[test]
    fn only_plain_etags_carry_an_md5() {
        assert_eq!(
            plain_md5_etag("\"9E107D9D372BB6826BD81D3542A419D6\"").as_deref(),
            Some("9e107d9d372bb6826bd81d3542a419d6")
        );
        assert_eq!(
            plain_md5_etag("\"9e107d9d372bb6826bd81d3542a419d6-3\""),
            None
        );
    }

    #[test]
    fn reasons_come_from_the_s3_error_body() {
        let text = "Generic S3 error: Error performing list request: 403 Forbidden: \
            <?xml version=\"1.0\"?><Error><Code>SignatureDoesNotMatch</Code>\
            <Message>The request signature we calculated does not match</Message></Error>";
        assert_eq!(
            s3_reason(text),
            "SignatureDoesNotMatch: The request signature we calculated does not match"
        );
        assert_eq!(s3_reason("timed out\nmore"), "timed out");
    }
}
