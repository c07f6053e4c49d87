//! `glintd`: Glint's daemon and command-line tool. A thin crate that wires the libraries: each
//! subcommand lives in its own module; `main` prints an error chain once and sets the exit code.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod capture;
mod decode_cmd;
mod info_cmd;

/// Glint: intensity-assisted LiDAR localisation for VLP-16 AGVs.
#[derive(Parser, Debug)]
#[command(name = "glintd", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Print what a capture holds: model, return mode, packets, sweeps, rpm, time span, gaps.
    Info(info_cmd::InfoArgs),
    /// Decode every return of a capture to CSV (or PLY when the name ends in .ply).
    Decode(decode_cmd::DecodeArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("GLINT_LOG")
                .unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let result = match cli.command {
        Command::Info(args) => info_cmd::run(args),
        Command::Decode(args) => decode_cmd::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("glintd: {e:#}");
            ExitCode::FAILURE
        }
    }
}
