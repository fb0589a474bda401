//! Integration tests: one binary, frames rendered with exact truth.

mod moto;
mod postgres;
mod server;
mod support;

mod accuracy;
mod browser;
mod cli;
mod durability;
mod fuzz;
mod gcp;
mod georef;
mod hostile;
mod pictures;
mod printed;
mod real;
mod replicas;
mod s3;
mod service;
mod store_contract;
mod tiling;
