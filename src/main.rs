//! `gcp-tagger`: parse the command line, set up logging, run the command.

use std::process::ExitCode;

use clap::Parser;
use gcp_tagger::cli::{self, Cli, Command};
use tracing_subscriber::EnvFilter;

fn main() -> ExitCode {
    let args = Cli::parse();
    let filter = EnvFilter::try_new(&args.log).unwrap_or_else(|_| EnvFilter::new("warn"));
    let logs = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    if args.log_json {
        logs.json().init();
    } else {
        logs.init();
    }
    match args.command {
        Command::Detect(a) => cli::detect(a),
        Command::Sample(a) => cli::sample(a),
    }
}
