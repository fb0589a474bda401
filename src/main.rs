//! `gcp-tagger`: parse the command line, set up logging, run the command.

use std::process::ExitCode;

use clap::Parser;
use gcp_tagger::cli::{self, Cli, Command};
use tracing_subscriber::EnvFilter;

fn main() -> ExitCode {
    let args = Cli::parse();
    let default_level = match args.command {
        Command::Serve(_) => "info",
        _ => "warn",
    };
    let filter = args
        .log
        .as_deref()
        .and_then(|f| EnvFilter::try_new(f).ok())
        .unwrap_or_else(|| EnvFilter::new(default_level));
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
        Command::Serve(a) => serve(a),
        Command::Probe(a) => cli::probe(a),
        Command::RunJob(a) => gcp_tagger::jobs::isolate::child_main(a),
        Command::Openapi => {
            println!("{}", gcp_tagger::api::openapi_json());
            ExitCode::SUCCESS
        }
    }
}

fn serve(args: gcp_tagger::config::ServeArgs) -> ExitCode {
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("http")
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return ExitCode::from(cli::exit::INTERNAL);
        }
    };
    match runtime.block_on(gcp_tagger::server::run(args)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(cli::exit::USAGE)
        }
    }
}
