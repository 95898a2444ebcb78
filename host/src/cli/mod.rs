//! The `brightpix` command line: one module per subcommand.

mod process;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "brightpix",
    version,
    about = "Brightest-pixel Shack-Hartmann processing: configure and verify devices, process frames, simulate",
    long_about = None
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    Process(process::ProcessArgs),
}

/// Runs the command line; errors are printed with their causes.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let outcome = match cli.command {
        Command::Process(args) => process::run(args),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("brightpix: error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
