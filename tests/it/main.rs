//! Integration tests: one binary, frames rendered with exact truth.

mod support;

mod accuracy;
mod cli;
mod georef;
mod tiling;
