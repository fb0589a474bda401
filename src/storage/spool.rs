//! The data folder and the upload spool. Uploads stream into a temporary
//! file in `spool/`, are checked to be an image by their first bytes, and
//! are renamed into `frames/` only once their job is recorded, so a half
//! written upload never looks like a frame.
//!
//! Layout: `jobs.sqlite` (the store), `frames/{job}.{ext}`,
//! `results/{job}.json`, `results/{job}.pictures/` (chips and preview),
//! `results/{job}.review.json` (accepted/rejected targets), `spool/` (uploads in flight), `owner.lock` (held
//! by the one server using the folder).

use std::fs::{File, TryLockError};
use std::io::{self, Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::shared::SharedFiles;

use uuid::Uuid;

/// A file the service stored that cannot be used: the data folder was
/// changed behind its back, or the disk failed.
#[derive(Debug, thiserror::Error)]
pub enum StoredFileError {
    #[error("cannot read the stored file {path}: {source}")]
    Read { path: PathBuf, source: io::Error },
    #[error("the stored file {path} is not what this version wrote: {source}")]
    Parse {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("the stored file {0} is missing")]
    Missing(PathBuf),
}

/// Longest image name kept, in bytes; longer names are cut.
const MAX_NAME_BYTES: usize = 200;

/// The service's data folder.
#[derive(Debug, Clone)]
pub struct DataDir {
    root: PathBuf,
    /// The folder's owner lock, held while any clone lives.
    _owner: Arc<File>,
    /// With replicas sharing one queue: the bucket this folder caches.
    shared: Option<Arc<SharedFiles>>,
}

/// Why a data folder cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// Another process holds the folder's owner lock.
    #[error("data folder {folder} is in use by another gcp-tagger ({holder}); stop it first or choose another --data-dir")]
    InUse { folder: String, holder: String },
    #[error("data folder {folder}: {source}")]
    Io { folder: String, source: io::Error },
}

impl DataDir {
    /// Takes the folder's owner lock (an advisory lock on `owner.lock`,
    /// held for the process's life and released by the kernel however it
    /// ends), creates the folder layout if missing and empties the spool
    /// (uploads that were in flight when the process stopped were never
    /// acknowledged). A folder another process holds is refused: two
    /// servers on one folder would each requeue and run the other's jobs.
    pub fn open(root: &Path) -> Result<DataDir, OpenError> {
        let io_err = |source| OpenError::Io {
            folder: root.display().to_string(),
            source,
        };
        std::fs::create_dir_all(root).map_err(io_err)?;
        let owner = lock_owner(&root.join("owner.lock")).map_err(|e| match e {
            Locked::Io(e) => io_err(e),
            Locked::Held(holder) => OpenError::InUse {
                folder: root.display().to_string(),
                holder,
            },
        })?;
        let dir = DataDir {
            root: root.to_path_buf(),
            _owner: Arc::new(owner),
            shared: None,
        };
        dir.make_layout().map_err(io_err)?;
        Ok(dir)
    }

    fn make_layout(&self) -> io::Result<()> {
        let root = &self.root;
        for sub in ["frames", "results", "spool", "surveys"] {
            std::fs::create_dir_all(root.join(sub))?;
        }
        for entry in std::fs::read_dir(root.join("spool"))? {
            let _ = std::fs::remove_file(entry?.path());
        }
        Ok(())
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// This folder as a cache of files shared by replicas in a bucket.
    pub fn with_shared(mut self, shared: Arc<SharedFiles>) -> DataDir {
        self.shared = Some(shared);
        self
    }

    /// Writes the file (or folder) at `path` to the shared bucket, if any.
    pub fn publish(&self, path: &Path) -> io::Result<()> {
        self.publish_all(&[path])
    }

    /// Writes the files (or folders) at `paths`, all in this folder, to the
    /// shared bucket, if any, several at once.
    pub fn publish_all(&self, paths: &[&Path]) -> io::Result<()> {
        match &self.shared {
            Some(shared) => shared.publish(&self.root, &self.relative(paths)),
            None => Ok(()),
        }
    }

    /// Brings the file at `path` in from the shared bucket, if any (see
    /// [`SharedFiles::bring_in`]).
    pub fn bring_in(&self, path: &Path) -> io::Result<()> {
        match (&self.shared, path.strip_prefix(&self.root)) {
            (Some(shared), Ok(rel)) => shared.bring_in(&self.root, rel),
            _ => Ok(()),
        }
    }

    /// `paths` (all in this folder) relative to it.
    fn relative<'a>(&self, paths: &[&'a Path]) -> Vec<&'a Path> {
        paths
            .iter()
            .filter_map(|p| p.strip_prefix(&self.root).ok())
            .collect()
    }

    /// Removes `files` and the `folders`' files from the shared bucket,
    /// if any (all in this folder); a failure is logged.
    fn unpublish(&self, files: &[&Path], folders: &[&Path]) {
        let Some(shared) = &self.shared else { return };
        let (files, folders) = (self.relative(files), self.relative(folders));
        if let Err(e) = shared.remove(&files, &folders) {
            tracing::warn!(bucket = shared.url(), error = %e, "cannot remove shared files");
        }
    }

    pub fn db_path(&self) -> PathBuf {
        self.root.join("jobs.sqlite")
    }

    pub fn frame_path(&self, job: Uuid, ext: &str) -> PathBuf {
        self.root.join("frames").join(format!("{job}.{ext}"))
    }

    pub fn result_path(&self, job: Uuid) -> PathBuf {
        self.root.join("results").join(format!("{job}.json"))
    }

    /// A job's pictures: `N.png` per target (its place in the result) and
    /// `preview.jpg`; written by the worker before the result.
    pub fn pictures_dir(&self, job: Uuid) -> PathBuf {
        self.root.join("results").join(format!("{job}.pictures"))
    }

    /// A job's reviews of its targets (accepted / rejected).
    pub fn review_path(&self, job: Uuid) -> PathBuf {
        self.root.join("results").join(format!("{job}.review.json"))
    }

    /// Bytes free for unprivileged writers on the data folder's filesystem.
    pub fn free_bytes(&self) -> io::Result<u64> {
        use std::os::unix::ffi::OsStrExt;
        let path = std::ffi::CString::new(self.root.as_os_str().as_bytes())
            .map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
        let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
        // SAFETY: statvfs fills `st` for a NUL-terminated path.
        if unsafe { libc::statvfs(path.as_ptr(), &mut st) } != 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(st.f_bavail as u64 * st.f_frsize as u64)
    }

    /// A flight's survey of ground control points.
    pub fn survey_path(&self, flight: Uuid) -> PathBuf {
        self.root.join("surveys").join(format!("{flight}.json"))
    }

    /// A fresh temporary path in the spool.
    pub fn spool_path(&self) -> PathBuf {
        self.root
            .join("spool")
            .join(format!("{}.part", Uuid::now_v7()))
    }

    /// The JSON file at `path` (one of this folder's: a result, a review, a
    /// survey), or None when there is none.
    pub fn read_json<T: serde::de::DeserializeOwned>(
        &self,
        path: &Path,
    ) -> Result<Option<T>, StoredFileError> {
        self.bring_in(path)
            .map_err(|source| StoredFileError::Read {
                path: path.to_path_buf(),
                source,
            })?;
        let bytes = match std::fs::read(path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(source) => {
                return Err(StoredFileError::Read {
                    path: path.to_path_buf(),
                    source,
                })
            }
        };
        serde_json::from_slice(&bytes)
            .map(Some)
            .map_err(|source| StoredFileError::Parse {
                path: path.to_path_buf(),
                source,
            })
    }

    /// Writes `bytes` to `path` through a temporary file and a rename, so the
    /// file is either whole or absent.
    pub fn write_atomic(&self, path: &Path, bytes: &[u8]) -> io::Result<()> {
        let tmp = self.spool_path();
        std::fs::write(&tmp, bytes)?;
        std::fs::File::open(&tmp)?.sync_all()?;
        std::fs::rename(&tmp, path)?;
        self.publish(path)
    }

    /// Removes a job's frame, result, pictures and reviews; missing files
    /// are fine.
    pub fn remove_job_files(&self, job: Uuid, ext: &str) {
        self.unpublish(
            &[
                &self.frame_path(job, ext),
                &self.result_path(job),
                &self.review_path(job),
            ],
            &[&self.pictures_dir(job)],
        );
        remove_quietly(&self.frame_path(job, ext));
        remove_quietly(&self.result_path(job));
        remove_quietly(&self.review_path(job));
        let pictures = self.pictures_dir(job);
        if let Err(e) = std::fs::remove_dir_all(&pictures) {
            if e.kind() != io::ErrorKind::NotFound {
                tracing::warn!(path = %pictures.display(), error = %e, "cannot remove a job's pictures");
            }
        }
    }

    /// Removes a job's frame only; a missing file is fine.
    pub fn remove_frame(&self, job: Uuid, ext: &str) {
        self.unpublish(&[&self.frame_path(job, ext)], &[]);
        remove_quietly(&self.frame_path(job, ext));
    }

    /// Removes a flight's survey; a missing one is fine.
    pub fn remove_survey(&self, flight: Uuid) {
        self.unpublish(&[&self.survey_path(flight)], &[]);
        remove_quietly(&self.survey_path(flight));
    }
}

fn remove_quietly(path: &Path) {
    match std::fs::remove_file(path) {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => tracing::warn!(path = %path.display(), error = %e, "cannot remove"),
    }
}

/// Recognises a supported image by its first bytes.
pub fn sniff_image(head: &[u8]) -> Option<&'static str> {
    if head.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some("jpg")
    } else if head.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some("png")
    } else if head.starts_with(b"II*\0")
        || head.starts_with(b"MM\0*")
        || head.starts_with(b"II+\0")
        || head.starts_with(b"MM\0+")
    {
        Some("tif")
    } else {
        None
    }
}

/// The first bytes of a file, in hex, for error messages.
pub fn magic_hex(head: &[u8]) -> String {
    head.iter()
        .take(8)
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// A client's file name made safe to show and store: the last path
/// component only, control characters dropped, at most 200 bytes. The name
/// never becomes a path on disk (frames are stored by job id).
pub fn sanitize_name(raw: &str) -> Option<String> {
    let base = raw.rsplit(['/', '\\']).next().unwrap_or("");
    let mut name: String = base.chars().filter(|c| !c.is_control()).collect();
    name = name.trim().to_string();
    if name.is_empty() || name == "." || name == ".." {
        return None;
    }
    if name.len() > MAX_NAME_BYTES {
        let mut cut = MAX_NAME_BYTES;
        while !name.is_char_boundary(cut) {
            cut -= 1;
        }
        name.truncate(cut);
    }
    Some(name)
}

enum Locked {
    Io(io::Error),
    /// Held by another process: who, as it wrote itself into the file.
    Held(String),
}

/// Takes the exclusive lock on `path` without waiting and writes this
/// process's id into it, for the message another process gets.
fn lock_owner(path: &Path) -> Result<File, Locked> {
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .map_err(Locked::Io)?;
    match file.try_lock() {
        Ok(()) => {}
        Err(TryLockError::WouldBlock) => {
            let mut holder = String::new();
            let _ = file.read_to_string(&mut holder);
            let holder = holder.trim();
            return Err(Locked::Held(if holder.is_empty() {
                "its process id not yet written".to_string()
            } else {
                holder.to_string()
            }));
        }
        Err(TryLockError::Error(e)) => return Err(Locked::Io(e)),
    }
    file.set_len(0).map_err(Locked::Io)?;
    file.rewind().map_err(Locked::Io)?;
    writeln!(file, "pid {}", std::process::id()).map_err(Locked::Io)?;
    file.sync_all().map_err(Locked::Io)?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_lose_paths_and_control_characters() {
        assert_eq!(sanitize_name("../../etc/passwd").as_deref(), Some("passwd"));
        assert_eq!(
            sanitize_name("C:\\x\\DJI_0001.JPG").as_deref(),
            Some("DJI_0001.JPG")
        );
        assert_eq!(sanitize_name("a\nb.tif").as_deref(), Some("ab.tif"));
        assert_eq!(sanitize_name("/vsicurl/"), None);
        assert_eq!(sanitize_name(".."), None);
        assert_eq!(sanitize_name(&"é".repeat(150)).unwrap().len(), 200);
    }

    #[test]
    fn images_are_recognised_by_content() {
        assert_eq!(sniff_image(&[0xFF, 0xD8, 0xFF, 0xE0]), Some("jpg"));
        assert_eq!(sniff_image(b"II*\0\x08"), Some("tif"));
        assert_eq!(sniff_image(b"\x89PNG\r\n\x1a\n"), Some("png"));
        assert_eq!(sniff_image(b"<VRTDataset>"), None);
        assert_eq!(sniff_image(b""), None);
    }

    #[test]
    fn a_data_folder_has_one_owner_at_a_time() {
        let dir = tempfile::tempdir().unwrap();
        let first = DataDir::open(dir.path()).unwrap();
        let err = DataDir::open(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains(&format!("pid {}", std::process::id()))
                && err.contains("in use by another gcp-tagger"),
            "{err}"
        );
        // Clones share the lock; it goes with the last of them.
        let clone = first.clone();
        drop(first);
        assert!(DataDir::open(dir.path()).is_err());
        drop(clone);
        DataDir::open(dir.path()).unwrap();
    }
}
