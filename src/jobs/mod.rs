//! Jobs: records, parameters, the durable store and queue, and the
//! RAM-bounded worker pool that runs the pipeline on them. Nothing here
//! knows about HTTP.

pub mod export;
pub mod fetch;
pub mod gcp;
pub mod isolate;
pub mod model;
pub mod params;
pub mod pool;
pub mod results;
pub mod retention;
pub mod review;
pub mod store;

pub use model::{FlightId, FlightRecord, FlightState, JobError, JobId, JobRecord, JobState};
pub use params::JobParams;
pub use pool::{PoolConfig, WorkerPool};
pub use store::{IdemKey, IdemRecord, JobFilter, JobStore, NewJob, SharedStore, StoreError};
