//! The `brightpix` command line: one module per subcommand.

mod all_invalid;
mod bench;
mod bench_link;
pub mod bench_port;
mod capture;
mod check_config;
mod configure;
mod demo;
mod devices;
pub mod doctor;
mod endtoend;
mod paper;
mod process;
mod progress;
mod rig;
mod simulate_device;
mod simulate_rig;
mod soak;
mod status;
mod stream;
mod tune;
mod view;

use clap::{ArgMatches, CommandFactory, FromArgMatches, Parser, Subcommand};
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
    Bench(bench::BenchArgs),
    Paper(paper::PaperArgs),
    Endtoend(endtoend::EndToEndArgs),
    Tune(tune::TuneArgs),
    Demo(demo::DemoArgs),
    Devices(devices::DevicesArgs),
    Configure(configure::ConfigureArgs),
    CheckConfig(check_config::CheckConfigArgs),
    Status(status::StatusArgs),
    Doctor(doctor::DoctorArgs),
    Stream(stream::StreamArgs),
    Capture(capture::CaptureArgs),
    SimulateDevice(simulate_device::SimulateDeviceArgs),
    Soak(soak::SoakArgs),
    Rig(rig::RigArgs),
    View(view::ViewArgs),
}

/// A count or size argument that must be at least 1 (`--chunk 0` would
/// feed the engine nothing, for ever).
pub(crate) fn at_least_one(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(e.to_string()),
    }
}

/// Runs the command line; errors are printed with their causes.
pub fn main() -> ExitCode {
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    match dispatch(cli.command, &matches) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("brightpix: error: {error:#}");
            ExitCode::FAILURE
        }
    }
}

/// Runs one command line as `main` does (`args` begins with the program
/// name) and returns its outcome: for tests of whole commands.
pub fn run_from<I, T>(args: I) -> anyhow::Result<()>
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let matches = Cli::command().try_get_matches_from(args)?;
    dispatch(Cli::from_arg_matches(&matches)?.command, &matches)
}

/// The ids of the options given on the command line (not defaulted) of
/// subcommand `name`: for commands whose options apply in some modes only,
/// so that one given in another mode is refused, not ignored.
fn given(matches: &ArgMatches, name: &str) -> Vec<String> {
    let Some(sub) = matches.subcommand_matches(name) else {
        return Vec::new();
    };
    sub.ids()
        .filter(|id| sub.value_source(id.as_str()) == Some(clap::parser::ValueSource::CommandLine))
        .map(|id| id.as_str().to_string())
        .collect()
}

fn dispatch(command: Command, matches: &ArgMatches) -> anyhow::Result<()> {
    match command {
        Command::Process(args) => process::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Paper(args) => paper::run(args),
        Command::Endtoend(args) => endtoend::run(args),
        Command::Tune(args) => tune::run(args, &given(matches, "tune")),
        Command::Demo(args) => demo::run(args),
        Command::Devices(args) => devices::run(args),
        Command::Configure(args) => configure::run(args),
        Command::CheckConfig(args) => check_config::run(args),
        Command::Status(args) => status::run(args),
        Command::Doctor(args) => doctor::run(args),
        Command::Stream(args) => stream::run(args),
        Command::Capture(args) => capture::run(args),
        Command::SimulateDevice(args) => simulate_device::run(args),
        Command::Soak(args) => soak::run(args),
        Command::Rig(args) => rig::run(args),
        Command::View(args) => view::run(args),
    }
}
