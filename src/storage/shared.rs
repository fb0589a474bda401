//! The data folder's files in an object store, for replicas that share one
//! queue (`--store postgres://...` with `--shared-files s3://bucket/prefix/`).
//!
//! The bucket holds the truth; each replica's data folder is a cache of it
//! with the same layout (`frames/`, `results/`, `surveys/` under the
//! prefix). Whoever writes a file publishes it; whoever reads one brings it
//! in first: files that never change once written (frames, results,
//! pictures) only when missing locally, files that change (a job's reviews,
//! a flight's survey) on every read. So any replica can run any job and
//! serve any result.

use std::future::Future;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use futures_util::StreamExt;
use object_store::aws::AmazonS3;
use object_store::path::Path as Key;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};

use tokio::sync::Semaphore;

use super::s3::{S3Error, S3Url, S3};
use crate::background::Background;

/// Objects written to the bucket at once by one [`SharedFiles::publish`].
const PUTS_AT_ONCE: usize = 8;

/// Most MiB of files one [`SharedFiles::publish`] holds in memory at once
/// (a larger file alone takes the whole budget).
const PUT_MIB_IN_FLIGHT: u64 = 256;

pub struct SharedFiles {
    client: Arc<AmazonS3>,
    /// Where the files live, shown in messages: `s3://bucket/prefix/`.
    url: String,
    prefix: String,
    /// The calls block, from worker threads and handlers.
    rt: Background,
}

impl std::fmt::Debug for SharedFiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SharedFiles")
            .field("url", &self.url)
            .finish()
    }
}

fn io_error(e: impl std::fmt::Display) -> io::Error {
    io::Error::other(e.to_string())
}

/// Files whose content changes after they are first written.
fn changes(rel: &Path) -> bool {
    rel.starts_with("surveys") || rel.to_string_lossy().ends_with(".review.json")
}

impl SharedFiles {
    /// The files under `url` (`s3://bucket/prefix/`), through the server's
    /// S3 settings.
    pub fn new(s3: &S3, url: &str) -> Result<SharedFiles, S3Error> {
        let (bucket, prefix) = match S3Url::parse(url)? {
            S3Url::Prefix { bucket, prefix } => (bucket, prefix),
            S3Url::Object { .. } => {
                return Err(S3Error::BadUrl(format!(
                    "{url}: shared files need a prefix ending in '/'"
                )))
            }
        };
        let client = s3.client_for(&bucket)?;
        let rt = Background::new("shared-files")
            .map_err(|e| S3Error::BadUrl(format!("shared files: {e}")))?;
        Ok(SharedFiles {
            client,
            url: format!("s3://{bucket}/{prefix}"),
            prefix,
            rt,
        })
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    fn run<T: Send + 'static>(
        &self,
        f: impl Future<Output = io::Result<T>> + Send + 'static,
    ) -> io::Result<T> {
        self.rt
            .run(f)
            .ok_or_else(|| io_error("the shared files' runtime stopped"))?
    }

    fn key(&self, rel: &Path) -> io::Result<Key> {
        let rel = rel
            .to_str()
            .ok_or_else(|| io_error(format!("{}: not UTF-8", rel.display())))?;
        Key::parse(format!("{}{rel}", self.prefix)).map_err(io_error)
    }

    /// Writes the local files (or every file of the folders) at `root/rel`
    /// for each of `rels` to the bucket, several at once: a flight's frames
    /// wait on the object store's latency once, not once per frame. At
    /// most [`PUT_MIB_IN_FLIGHT`] MiB of them are held in memory together.
    pub fn publish(&self, root: &Path, rels: &[&Path]) -> io::Result<()> {
        let mut files = Vec::new();
        for rel in rels {
            let local = root.join(rel);
            if local.is_dir() {
                for e in std::fs::read_dir(&local)? {
                    files.push(rel.join(e?.file_name()));
                }
            } else {
                files.push(rel.to_path_buf());
            }
        }
        let puts = files
            .into_iter()
            .map(|rel| Ok((root.join(&rel), self.key(&rel)?)))
            .collect::<io::Result<Vec<(PathBuf, Key)>>>()?;
        let client = self.client.clone();
        self.run(async move {
            let budget = Arc::new(Semaphore::new(PUT_MIB_IN_FLIGHT as usize));
            futures_util::stream::iter(puts)
                .map(|(local, key)| {
                    let (client, budget) = (client.clone(), budget.clone());
                    async move {
                        let mib = tokio::fs::metadata(&local).await?.len() >> 20;
                        let _held = budget
                            .acquire_many(mib.clamp(1, PUT_MIB_IN_FLIGHT) as u32)
                            .await
                            .map_err(io_error)?;
                        let bytes = tokio::fs::read(&local).await?;
                        client
                            .put(&key, PutPayload::from(bytes))
                            .await
                            .map(|_| ())
                            .map_err(io_error)
                    }
                })
                .buffer_unordered(PUTS_AT_ONCE)
                .collect::<Vec<io::Result<()>>>()
                .await
                .into_iter()
                .collect()
        })
    }

    /// Brings `root/rel` in from the bucket: a file that never changes only
    /// when it is missing here, one that changes every time. No object: no
    /// local file either.
    pub fn bring_in(&self, root: &Path, rel: &Path) -> io::Result<()> {
        let local = root.join(rel);
        if !changes(rel) && local.exists() {
            return Ok(());
        }
        let key = self.key(rel)?;
        let client = self.client.clone();
        let bytes = self.run(async move {
            match client.get(&key).await {
                Ok(got) => got.bytes().await.map(Some).map_err(io_error),
                Err(object_store::Error::NotFound { .. }) => Ok(None),
                Err(e) => Err(io_error(e)),
            }
        })?;
        match bytes {
            Some(bytes) => {
                if let Some(parent) = local.parent() {
                    std::fs::create_dir_all(parent)?;
                }
                // Whole or absent, as every file of the folder.
                let tmp = local.with_extension(format!("{}.part", uuid::Uuid::now_v7()));
                std::fs::write(&tmp, &bytes)?;
                std::fs::rename(&tmp, &local)
            }
            None => match std::fs::remove_file(&local) {
                Err(e) if e.kind() != io::ErrorKind::NotFound => Err(e),
                _ => Ok(()),
            },
        }
    }

    /// Removes the objects of `files` and every object under `folders`
    /// from the bucket; missing ones are fine.
    pub fn remove(&self, files: &[&Path], folders: &[&Path]) -> io::Result<()> {
        let files = files
            .iter()
            .map(|f| self.key(f))
            .collect::<io::Result<Vec<_>>>()?;
        let folders = folders
            .iter()
            .map(|f| self.key(f))
            .collect::<io::Result<Vec<_>>>()?;
        let client = self.client.clone();
        self.run(async move {
            let mut keys = files;
            for folder in &folders {
                let mut listed = client.list(Some(folder));
                while let Some(meta) = listed.next().await {
                    keys.push(meta.map_err(io_error)?.location);
                }
            }
            for key in &keys {
                match client.delete(key).await {
                    Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                    Err(e) => return Err(io_error(e)),
                }
            }
            Ok(())
        })
    }
}
