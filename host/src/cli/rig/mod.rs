//! `brightpix rig`: several boards on one camera.
//!
//! | module    | holds                                                              |
//! |-----------|--------------------------------------------------------------------|
//! | this file | the subcommands' arguments, `check` and `configure`, the printed rig |
//! | `plan`    | `rig plan`: split a whole-camera configuration, write `rig.toml`    |
//! | `stream`  | `rig stream`: recorded frames to the boards, merged and reported    |
//! | `capture` | `rig capture`: every board's own camera, merged by frame number     |
//! | `merged`  | what `stream` and `capture` share: configure or check, `--out`      |
//! | `view`    | `view --rig`: the boards' merged results in the live view           |
//! | `demo`    | `demo --boards K`: `rig stream` on simulated devices                |

mod capture;
mod demo;
mod merged;
mod plan;
mod stream;
mod view;

pub(super) use demo::demo;
pub(super) use view::view_rig;

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};

use crate::link::Client;
use crate::rig::{self, describe_load, CostModel, Rig, DCMI_MAX_PIXEL_CLOCK_HZ};

#[derive(Args)]
#[command(
    about = "Several boards on one camera: plan the split, configure the boards, stream and merge their results",
    after_help = "Examples:\n  \
brightpix rig plan --config examples/canary.toml --boards 3 --camera-rate 1000 --out rig.toml\n  \
brightpix rig check --rig rig.toml --board-configs boards/   # also boards/board-K.toml, one board's part each\n  \
brightpix configure --port /dev/ttyACM0 --config boards/board-0.toml   # one board alone\n  \
brightpix rig configure --rig rig.toml\n  \
brightpix rig stream --rig rig.toml --frames frames.npy --verify --out slopes.npy\n  \
brightpix rig capture --rig rig.toml --count 1000 --out slopes.npy   # each board's own camera\n  \
brightpix demo --boards 3            # three simulated devices on one simulated camera\n\n\
Each board captures a rectangle of the sensor and runs an ordinary configuration whose camera is\n\
that rectangle; results are merged by frame number into the whole camera's sub-aperture order.\n\
`rig stream` numbers the frames it sends, so they agree on every board. `rig capture` starts the\n\
boards on one camera frame only with a sync line wired to every board ([sync] leader = \"NAME\" in\n\
rig.toml; STM32H743: PF13): followers are armed first, then the leader raises the line after a\n\
frame start. Without one it warns: boards may begin frames apart. With `rig plan --shared-rows`\n\
neighbouring bands share a camera row, and `rig capture` refuses a capture in which their\n\
checksums of it disagree (a check without wiring)."
)]
pub struct RigArgs {
    #[command(subcommand)]
    command: RigCommand,
}

#[derive(Subcommand)]
enum RigCommand {
    /// Split a whole-camera configuration over K boards and write rig.toml.
    Plan(plan::PlanArgs),
    /// Load a rig file, check it and print each board's part and predicted load.
    Check(CheckCommandArgs),
    /// Upload each board's part of the rig and check that every board runs it.
    Configure(CheckArgs),
    /// Stream recorded frames to the rig's boards and merge their results.
    Stream(stream::StreamArgs),
    /// Capture with every board's own camera (one camera's bus fanned out, each board cropping
    /// its rectangle) and merge their results by frame number; on the rig's sync line if it has
    /// one.
    Capture(capture::CaptureArgs),
}

#[derive(Args)]
struct CheckCommandArgs {
    #[command(flatten)]
    rig: CheckArgs,
    /// Also write each board's own configuration, DIR/<board name>.toml (its rectangle as
    /// [camera.crop]), which `brightpix configure --config` takes for that board alone.
    #[arg(long, value_name = "DIR")]
    board_configs: Option<PathBuf>,
}

#[derive(Args)]
pub(super) struct CheckArgs {
    /// The rig file (brightpix rig plan writes one).
    #[arg(long, value_name = "rig.toml")]
    pub(super) rig: PathBuf,
    /// Ports of the boards, in the file's board order, instead of the file's `port`s.
    #[arg(long, value_name = "P1,P2,..", value_delimiter = ',')]
    pub(super) ports: Vec<String>,
}

pub fn run(args: RigArgs) -> Result<()> {
    match args.command {
        RigCommand::Plan(a) => plan::run(a),
        RigCommand::Check(a) => {
            let rig = Rig::load(&a.rig.rig)?;
            print_rig(&rig, &rig.cost_model(), None);
            if let Some(dir) = &a.board_configs {
                plan::write_board_configs(&rig, dir, &[&a.rig.rig])?;
            }
            Ok(())
        }
        RigCommand::Configure(a) => {
            let rig = Rig::load(&a.rig)?;
            let mut clients = open_clients(&rig, &a.ports)?;
            rig::configure(&rig, &mut clients)?;
            for (b, c) in rig.boards.iter().zip(&clients) {
                println!(
                    "{}: configured on {} ({} sub-apertures)",
                    b.name,
                    c.port_name(),
                    b.windows.len()
                );
            }
            Ok(())
        }
        RigCommand::Stream(a) => stream::run(a),
        RigCommand::Capture(a) => capture::run(a),
    }
}

/// How `rig capture` will start the boards on one camera frame, and check it.
fn describe_alignment(rig: &Rig) -> String {
    let start = match rig.sync {
        Some(sync) => format!(
            "sync line led by {} (rig capture starts every board on one camera frame)",
            rig.boards[sync.leader].name
        ),
        None => "no sync line ([sync] in rig.toml): rig capture warns that boards may begin frames apart".into(),
    };
    let pairs = rig.shared_rows();
    if pairs.is_empty() {
        return format!("alignment: {start}");
    }
    let names: Vec<String> = pairs
        .iter()
        .map(|&(a, b)| format!("{}/{}", rig.boards[a].name, rig.boards[b].name))
        .collect();
    format!(
        "alignment: {start}; shared rows checked every frame: {}",
        names.join(", ")
    )
}

/// The boards, their parts and predicted loads, and the limits of a board
/// that sees only its rectangle. `model`: what the loads were computed with (`rig.cost_model()` unless
/// the plan was given another).
pub(super) fn print_rig(rig: &Rig, model: &CostModel, loads: Option<&[rig::BoardLoad]>) {
    let computed;
    let loads = match loads {
        Some(l) => l,
        None => {
            computed = rig::loads(
                &rig.whole,
                &rig.shares(),
                rig.kind,
                model,
                rig.camera_rate_hz,
                !rig.shared_rows().is_empty(),
            );
            &computed
        }
    };
    for (b, load) in rig.boards.iter().zip(loads) {
        println!(
            "  {}{}: {}",
            b.name,
            b.port.as_ref().map_or(String::new(), |p| format!(" ({p})")),
            describe_load(load, b)
        );
    }
    println!("  {}", describe_alignment(rig));
    if let Some(rate) = rig.camera_rate_hz {
        let pixel_rate = rig.whole.camera.pixel_count() as f64 * rate;
        let link = model.link.map_or(String::new(), |l| {
            format!(
                "; results on its {} link: about {:.2} MB/s a board",
                l.name,
                l.bytes_per_s / 1e6
            )
        });
        println!(
            "  limits: every board on the fanned-out bus sees the camera's whole pixel clock, >= {:.1} MHz at {rate} Hz (the STM32H743's DCMI: {:.0} MHz at most){link}",
            pixel_rate / 1e6,
            DCMI_MAX_PIXEL_CLOCK_HZ / 1e6,
        );
        if pixel_rate > DCMI_MAX_PIXEL_CLOCK_HZ {
            println!("  warning: the camera's pixel clock exceeds what a DCMI can sample: split the camera's taps over boards");
        }
        if loads.iter().any(|l| l.link_load.is_some_and(|x| x > 1.0)) {
            println!(
                "  warning: {}: plan more boards or a lower rate",
                rig::busiest(loads, rig.kind, model)
            );
        }
    }
}

/// One client per board: `--ports` in board order, else the file's ports.
pub(super) fn open_clients(rig: &Rig, ports: &[String]) -> Result<Vec<Client>> {
    if !ports.is_empty() && ports.len() != rig.boards.len() {
        bail!(
            "--ports gives {} ports for {} boards",
            ports.len(),
            rig.boards.len()
        );
    }
    rig.boards
        .iter()
        .enumerate()
        .map(|(k, b)| {
            let port = ports.get(k).or(b.port.as_ref()).with_context(|| {
                format!(
                    "board {:?} has no port: add port = \"...\" to the rig file or give --ports",
                    b.name
                )
            })?;
            Client::open(port).with_context(|| format!("board {:?} on {port}", b.name))
        })
        .collect()
}
