//! The semihosting command line, given to QEMU as
//! `-semihosting-config enable=on,target=native,arg=brightpix-qemu,arg=...`
//! (the first `arg` is the program name). QEMU joins the arguments with
//! spaces, so a path must not contain blanks.
//!
//! | argument | effect |
//! |---|---|
//! | `--pixels PATH` | pixels also come from `PATH` (a FIFO or file the host writes, `PixelRows` frames) |
//! | `--camera DIR` | the simulated camera: frames from the host through `DIR` (`camera.rs`) |
//! | `--camera-fps N` | its frame rate (default 10) |
//! | `--camera-sync` | its camera is shared with other boards and has a sync line (`Capture` on the line) |
//! | `--digest PATH` | board check: read `PATH` and log its length and FNV-1a hash |
//! | `selftest=echo` | board check: UART0 echo loop instead of the device (0x04 exits) |
//! | `selftest=panic`, `selftest=udf` | board check: the panic / HardFault exits (101 / 102) |
//! | `--reset-on-fault` | a HardFault resets the board (its record reported after the reboot) instead of exiting 102 |
//! | `selftest=fault-once` | board check: a HardFault at boot (an undefined instruction) unless the last reset was a recorded fault; implies `--reset-on-fault`, so the board reboots and serves, reporting the fault |

use heapless::String;

/// Longest path accepted (bytes).
pub const MAX_PATH: usize = crate::hostfs::MAX_PATH;
/// Room for the whole command line.
const CMDLINE_BYTES: usize = 1024;

/// What the command line asks for.
#[derive(Default)]
pub struct Options {
    pub pixels: Option<String<MAX_PATH>>,
    pub camera: Option<String<MAX_PATH>>,
    pub camera_fps: Option<u32>,
    /// The simulated camera has a sync line shared with other boards.
    pub camera_sync: bool,
    pub digest: Option<String<MAX_PATH>>,
    pub selftest: Option<Selftest>,
    pub reset_on_fault: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum Selftest {
    Echo,
    Panic,
    Udf,
    FaultOnce,
}

impl Options {
    /// Reads and parses the semihosting command line. Unknown or malformed
    /// arguments are logged and ignored; no command line means defaults.
    pub fn from_semihosting() -> Self {
        let mut options = Options::default();
        let Ok(args) = semihosting::experimental::env::args::<CMDLINE_BYTES>() else {
            return options;
        };
        let mut args = (&args).skip(1);
        while let Some(arg) = args.next() {
            let Ok(arg) = arg else {
                defmt::warn!("args: an argument is not UTF-8, ignored");
                continue;
            };
            match arg {
                "--camera-fps" => {
                    let fps = match args.next() {
                        Some(Ok(n)) => n.parse::<u32>().ok().filter(|&n| n > 0),
                        _ => None,
                    };
                    if fps.is_none() {
                        defmt::warn!("args: --camera-fps needs a whole number of frames per second, at least 1");
                    }
                    options.camera_fps = fps;
                }
                "--pixels" | "--digest" | "--camera" => {
                    let path = match args.next() {
                        Some(Ok(p)) => String::try_from(p).ok(),
                        _ => None,
                    };
                    if path.is_none() {
                        defmt::warn!("args: {=str} needs a path (UTF-8, at most 255 bytes)", arg);
                    }
                    match arg {
                        "--pixels" => options.pixels = path,
                        "--camera" => options.camera = path,
                        _ => options.digest = path,
                    }
                }
                "selftest=echo" => options.selftest = Some(Selftest::Echo),
                "selftest=panic" => options.selftest = Some(Selftest::Panic),
                "selftest=udf" => options.selftest = Some(Selftest::Udf),
                "selftest=fault-once" => {
                    options.selftest = Some(Selftest::FaultOnce);
                    options.reset_on_fault = true;
                }
                "--reset-on-fault" => options.reset_on_fault = true,
                "--camera-sync" => options.camera_sync = true,
                other => defmt::warn!("args: unknown argument {=str}, ignored", other),
            }
        }
        options
    }
}
