//! Files on disk: the data folder's layout and the upload spool.

pub mod header;
pub mod s3;
pub mod shared;
pub mod spool;

pub use spool::{DataDir, StoredFileError};
