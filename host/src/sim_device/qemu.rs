//! [`QemuDevice`]: the firmware ELF in `qemu-system-arm`, and how it is
//! found or built ([`QemuCpu`], [`qemu_elf`]). Its pixels come on UART0,
//! from a FIFO the host writes (`--pixels`), or from its own simulated
//! camera (`--camera`: `camera.rs` serves the frames).

use std::fs::File;
use std::io::{self, Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _};

use super::camera::{CameraOptions, QemuCameraHost};
use super::{make_fifo, spawn, temp_dir, SimLinkKind};

/// The firmware workspace (`firmware/` beside `host/`).
pub fn firmware_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map_or_else(|| PathBuf::from("firmware"), |root| root.join("firmware"))
}

/// The core QEMU emulates, and the code generation the firmware is built
/// for: the same ELF contract on both (firmware/boards/qemu/README.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum QemuCpu {
    /// Cortex-M4F on `mps2-an386`: the firmware's default build.
    #[default]
    M4,
    /// Cortex-M7 on `mps2-an500`, built with `-C target-cpu=cortex-m7` into
    /// `firmware/target/cortex-m7` (the STM32H743's code generation; a
    /// separate target directory keeps the M4 build valid).
    M7,
}

impl QemuCpu {
    /// QEMU's `-cpu`.
    pub fn cpu(self) -> &'static str {
        match self {
            QemuCpu::M4 => "cortex-m4",
            QemuCpu::M7 => "cortex-m7",
        }
    }

    /// QEMU's `-machine`.
    pub fn machine(self) -> &'static str {
        match self {
            QemuCpu::M4 => "mps2-an386",
            QemuCpu::M7 => "mps2-an500",
        }
    }

    /// The firmware's target directory.
    fn target_dir(self) -> PathBuf {
        match self {
            QemuCpu::M4 => firmware_dir().join("target"),
            QemuCpu::M7 => firmware_dir().join("target/cortex-m7"),
        }
    }

    /// Extra `cargo --config` of its build.
    fn cargo_config(self) -> Option<&'static str> {
        match self {
            QemuCpu::M4 => None,
            QemuCpu::M7 => {
                Some(r#"target.thumbv7em-none-eabihf.rustflags=["-C","target-cpu=cortex-m7"]"#)
            }
        }
    }

    /// Where [`build_qemu_elf_for`] puts the ELF.
    pub fn default_elf(self) -> PathBuf {
        self.target_dir()
            .join("thumbv7em-none-eabihf/release/brightpix-qemu")
    }
}

/// Where `cargo build --release -p brightpix-board-qemu` puts the ELF.
pub fn default_qemu_elf() -> PathBuf {
    QemuCpu::M4.default_elf()
}

/// Builds the QEMU firmware (`cargo build --release -p brightpix-board-qemu`
/// in `firmware/`, with the calling cargo's `CARGO_*` variables removed so
/// that they do not leak into the thumb build). Output goes to stderr.
pub fn build_qemu_elf() -> anyhow::Result<PathBuf> {
    build_qemu_elf_for(QemuCpu::M4)
}

/// [`build_qemu_elf`] for `cpu`: the M7 build is `cargo build --release -p
/// brightpix-board-qemu --bin brightpix-qemu --target-dir target/cortex-m7
/// --config 'target.thumbv7em-none-eabihf.rustflags=["-C","target-cpu=cortex-m7"]'`
/// (the pattern of `boards/qemu/scripts/run-bench m7`).
pub fn build_qemu_elf_for(cpu: QemuCpu) -> anyhow::Result<PathBuf> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut command = Command::new(cargo);
    command
        .args(["build", "--release", "-p", "brightpix-board-qemu"])
        .current_dir(firmware_dir());
    if let Some(config) = cpu.cargo_config() {
        command
            .args(["--bin", "brightpix-qemu", "--target-dir"])
            .arg(cpu.target_dir())
            .args(["--config", config]);
    }
    for (key, _) in std::env::vars_os() {
        let key_str = key.to_string_lossy();
        if (key_str.starts_with("CARGO_") && key_str != "CARGO_HOME")
            || key_str == "RUSTFLAGS"
            || key_str == "CARGO_ENCODED_RUSTFLAGS"
        {
            command.env_remove(&key);
        }
    }
    let status = command
        .stdout(Stdio::null())
        .status()
        .context("running cargo to build the QEMU firmware")?;
    if !status.success() {
        bail!(
            "building the QEMU firmware ({}) failed ({status}); try: cd {} && cargo build --release -p brightpix-board-qemu",
            cpu.cpu(),
            firmware_dir().display()
        );
    }
    let elf = cpu.default_elf();
    if !elf.exists() {
        bail!("the firmware build did not produce {}", elf.display());
    }
    Ok(elf)
}

/// The QEMU firmware ELF: `elf` if given, else the default one, built if missing.
pub fn qemu_elf(elf: Option<&Path>) -> anyhow::Result<PathBuf> {
    qemu_elf_for(elf, QemuCpu::M4)
}

/// [`qemu_elf`] for `cpu`.
pub fn qemu_elf_for(elf: Option<&Path>, cpu: QemuCpu) -> anyhow::Result<PathBuf> {
    match elf {
        Some(e) if e.exists() => Ok(e.to_path_buf()),
        Some(e) => bail!("firmware ELF {} does not exist", e.display()),
        None if cpu.default_elf().exists() => Ok(cpu.default_elf()),
        None => {
            eprintln!(
                "brightpix: building the QEMU firmware ({} is missing; about a minute)",
                cpu.default_elf().display()
            );
            build_qemu_elf_for(cpu)
        }
    }
}

/// Options of a [`QemuDevice`].
#[derive(Clone, Debug, Default)]
pub struct QemuOptions {
    /// The firmware ELF (default: [`qemu_elf`]`(None)`).
    pub elf: Option<PathBuf>,
    pub link: SimLinkKind,
    /// Give the board a FIFO to read pixels from (`--pixels PATH`).
    pub pixels_fifo: bool,
    /// Where QEMU's stdout (the raw defmt log) goes (default: a file in the
    /// device's temporary directory).
    pub log: Option<PathBuf>,
    /// `qemu-system-arm` (default: from PATH).
    pub qemu: Option<PathBuf>,
    /// The core and machine (the ELF must be built for it).
    pub cpu: QemuCpu,
    /// The board's own simulated camera (`capture`); not with `pixels_fifo`.
    pub camera: Option<CameraOptions>,
    /// More semihosting arguments, for board checks (firmware/boards/qemu
    /// `args.rs`: e.g. `selftest=fault-once`).
    pub board_args: Vec<String>,
    /// `-icount shift=S`: every instruction takes 2^S ns of virtual time, so
    /// the board's bench request counts instructions exactly (idle time
    /// still follows the host's clock: `sleep=on`).
    pub icount: Option<u32>,
}

/// The firmware in `qemu-system-arm`. Stops (kills QEMU) when dropped, and
/// QEMU dies with this process even if it is killed (`PR_SET_PDEATHSIG`;
/// strictly, with the thread that launched it: launch from a thread that
/// lives as long as the device).
pub struct QemuDevice {
    child: Child,
    port: String,
    fifo: Option<PathBuf>,
    log: PathBuf,
    elf: PathBuf,
    cpu: QemuCpu,
    dir: PathBuf,
    stdout: Option<JoinHandle<()>>,
    camera: Option<QemuCameraHost>,
}

impl QemuDevice {
    pub fn launch(options: QemuOptions) -> anyhow::Result<QemuDevice> {
        if options.camera.is_some() && options.pixels_fifo {
            bail!("a simulated device has either a camera or a pixel FIFO, not both");
        }
        let elf = qemu_elf_for(options.elf.as_deref(), options.cpu)?;
        let dir = temp_dir("brightpix-qemu")?;
        let log = options.log.clone().unwrap_or_else(|| dir.join("defmt.log"));
        let qemu = options
            .qemu
            .clone()
            .unwrap_or_else(|| PathBuf::from("qemu-system-arm"));
        let mut command = Command::new(&qemu);
        command.args([
            "-cpu",
            options.cpu.cpu(),
            "-machine",
            options.cpu.machine(),
            "-display",
            "none",
            "-monitor",
            "none",
            "-serial",
        ]);
        let socket = match &options.link {
            SimLinkKind::Pty => {
                command.arg("pty");
                None
            }
            SimLinkKind::Unix(path) => {
                let _ = std::fs::remove_file(path);
                command.arg(format!("unix:{},server=on,wait=on", path.display()));
                Some(path.clone())
            }
        };
        let fifo = if options.pixels_fifo {
            let path = dir.join("pixels.fifo");
            make_fifo(&path)?;
            if path.to_string_lossy().contains(char::is_whitespace) {
                bail!("the FIFO path {} contains blanks", path.display());
            }
            Some(path)
        } else {
            None
        };
        let mut board_args = Vec::new();
        if let Some(path) = &fifo {
            board_args.extend(["--pixels".to_string(), path.display().to_string()]);
        }
        let camera = match options.camera.clone() {
            Some(camera) => {
                let (fps, sync) = (camera.fps.max(1), camera.has_sync_line());
                let host = QemuCameraHost::start(&dir.join("camera"), camera)
                    .context("starting the simulated camera's frame server")?;
                board_args.extend([
                    "--camera".to_string(),
                    host.dir().display().to_string(),
                    "--camera-fps".to_string(),
                    fps.to_string(),
                ]);
                if sync {
                    board_args.push("--camera-sync".to_string());
                }
                Some(host)
            }
            None => None,
        };
        board_args.extend(options.board_args.iter().cloned());
        if board_args
            .iter()
            .any(|a| a.contains(|c: char| c.is_whitespace() || c == ','))
        {
            bail!(
                "the temporary directory {} contains blanks or commas, which QEMU's semihosting command line cannot carry",
                dir.display()
            );
        }
        let mut semihosting = String::from("enable=on,target=native");
        if !board_args.is_empty() {
            semihosting.push_str(",arg=brightpix-qemu");
            for a in &board_args {
                semihosting.push_str(",arg=");
                semihosting.push_str(a);
            }
        }
        if let Some(shift) = options.icount {
            command.args(["-icount", &format!("shift={shift}")]);
        }
        command
            .args(["-semihosting-config", &semihosting, "-kernel"])
            .arg(&elf)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        // Its own process group: Ctrl-C in a terminal reaches this process,
        // which then stops QEMU, rather than QEMU directly.
        std::os::unix::process::CommandExt::process_group(&mut command, 0);
        // And QEMU dies with this process, however it ends (SIGKILL too):
        // the kernel sends it SIGKILL when the thread that started it exits.
        let parent = std::process::id() as libc::pid_t;
        // SAFETY: between fork and exec the closure calls only
        // async-signal-safe functions (prctl, getppid, _exit).
        unsafe {
            std::os::unix::process::CommandExt::pre_exec(&mut command, move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                    return Err(io::Error::last_os_error());
                }
                // The parent may have died before the prctl took effect.
                if libc::getppid() != parent {
                    libc::_exit(1);
                }
                Ok(())
            });
        }
        let mut child = command.spawn().with_context(|| {
            format!(
                "cannot start {} (install it: apt-get install qemu-system-arm)",
                qemu.display()
            )
        })?;
        let (tx, rx) = mpsc::channel::<String>();
        let stdout = child.stdout.take().expect("piped stdout");
        let log_file = File::create(&log).with_context(|| format!("creating {}", log.display()))?;
        let tx = socket.is_none().then_some(tx);
        let stdout_thread = spawn("brightpix-qemu-stdout", move || {
            copy_qemu_stdout(stdout, log_file, tx)
        })?;
        let stderr = child.stderr.take().expect("piped stderr");
        let (err_tx, err_rx) = mpsc::channel::<String>();
        spawn("brightpix-qemu-stderr", move || {
            let mut text = String::new();
            let _ = io::BufReader::new(stderr).read_to_string(&mut text);
            let _ = err_tx.send(text);
        })?;
        let mut device = QemuDevice {
            child,
            port: String::new(),
            fifo,
            log,
            elf,
            cpu: options.cpu,
            dir,
            stdout: Some(stdout_thread),
            camera,
        };
        let started = Instant::now();
        device.port = match socket {
            None => loop {
                match rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(path) => break path,
                    Err(_) => {
                        if let Some(status) = device.child.try_wait()? {
                            let err = err_rx
                                .recv_timeout(Duration::from_millis(500))
                                .unwrap_or_default();
                            bail!("QEMU exited at start ({status}): {}", err.trim());
                        }
                        if started.elapsed() > Duration::from_secs(10) {
                            bail!("QEMU did not report its pseudo-terminal within 10 s");
                        }
                    }
                }
            },
            Some(path) => {
                while !path.exists() {
                    if let Some(status) = device.child.try_wait()? {
                        let err = err_rx
                            .recv_timeout(Duration::from_millis(500))
                            .unwrap_or_default();
                        bail!("QEMU exited at start ({status}): {}", err.trim());
                    }
                    if started.elapsed() > Duration::from_secs(10) {
                        bail!("QEMU did not create {} within 10 s", path.display());
                    }
                    thread::sleep(Duration::from_millis(10));
                }
                format!("unix:{}", path.display())
            }
        };
        Ok(device)
    }

    /// Opens the pixel FIFO once and closes it: the board's semihosting open
    /// of a FIFO returns only when a writer has opened it.
    pub fn release_fifo(&self, wait: Duration) -> anyhow::Result<()> {
        if let Some(path) = &self.fifo {
            crate::link::FifoWriter::open(path, wait).with_context(|| {
                format!(
                    "the firmware did not open its pixel FIFO {}",
                    path.display()
                )
            })?;
        }
        Ok(())
    }

    /// [`QemuDevice::release_fifo`] on a thread, for when the board opens
    /// the FIFO only later (with `-serial unix:..,wait=on` QEMU starts the
    /// firmware only once a client has connected).
    pub fn release_fifo_in_background(&self, wait: Duration) {
        if let Some(path) = self.fifo.clone() {
            let _ = spawn("brightpix-qemu-fifo", move || {
                let _ = crate::link::FifoWriter::open(&path, wait);
            });
        }
    }

    /// The port a client opens: `/dev/pts/N` or `unix:PATH`.
    pub fn port(&self) -> &str {
        &self.port
    }

    pub fn pixels_fifo(&self) -> Option<&Path> {
        self.fifo.as_deref()
    }

    /// QEMU's stdout: the firmware's raw defmt frames.
    pub fn log_path(&self) -> &Path {
        &self.log
    }

    pub fn elf(&self) -> &Path {
        &self.elf
    }

    /// The core and machine QEMU emulates.
    pub fn cpu(&self) -> QemuCpu {
        self.cpu
    }

    /// QEMU's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// QEMU's exit status, if it has exited.
    pub fn exit_status(&mut self) -> Option<ExitStatus> {
        self.child.try_wait().ok().flatten()
    }

    /// What an exit status means for the firmware.
    pub fn describe_exit(status: ExitStatus) -> String {
        match status.code() {
            Some(0) => "exited normally (0)".into(),
            Some(101) => "panicked (exit code 101)".into(),
            Some(102) => "HardFault (exit code 102)".into(),
            Some(c) => format!("exited with code {c}"),
            None => format!("ended by a signal ({status})"),
        }
    }

    /// The defmt log decoded by `defmt-print`, if it is installed.
    pub fn decoded_log(&self) -> Option<String> {
        let log = File::open(&self.log).ok()?;
        let out = Command::new("defmt-print")
            .arg("-e")
            .arg(&self.elf)
            .stdin(log)
            .stderr(Stdio::null())
            .output()
            .ok()?;
        Some(String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// Kills QEMU and removes its temporary files (the log too, unless it
    /// was given in the options).
    pub fn stop(mut self) {
        self.shutdown();
    }

    /// Whether the board has its own (simulated) camera.
    pub fn has_camera(&self) -> bool {
        self.camera.is_some()
    }

    fn shutdown(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        self.camera = None;
        if let Some(t) = self.stdout.take() {
            let _ = t.join();
        }
        if let Some(path) = self.port.strip_prefix("unix:") {
            let _ = std::fs::remove_file(path);
        }
        if !self.log.starts_with(&self.dir) || std::env::var_os("BRIGHTPIX_KEEP_QEMU_LOG").is_some()
        {
            if let Some(f) = &self.fifo {
                let _ = std::fs::remove_file(f);
            }
        } else {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

impl Drop for QemuDevice {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Finds `char device redirected to /dev/pts/N (label serial0)` in QEMU's
/// stdout, sends the path, and copies everything else (defmt frames) to `log`.
/// (With `tx` `None`, QEMU prints no such line: everything is log.)
fn copy_qemu_stdout(mut stdout: impl io::Read, mut log: File, tx: Option<mpsc::Sender<String>>) {
    const MARK: &[u8] = b"char device redirected to ";
    let mut head = Vec::new();
    let mut buf = [0u8; 4096];
    let mut found = tx.is_none();
    loop {
        let n = match stdout.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        if found {
            let _ = log.write_all(&buf[..n]);
            continue;
        }
        head.extend_from_slice(&buf[..n]);
        if let Some(at) = find(&head, MARK) {
            if let Some(end) = head[at..].iter().position(|&b| b == b'\n') {
                let line = String::from_utf8_lossy(&head[at + MARK.len()..at + end]).into_owned();
                let path = line.split_whitespace().next().unwrap_or("").to_string();
                if let Some(tx) = &tx {
                    let _ = tx.send(path);
                }
                let _ = log.write_all(&head[..at]);
                let _ = log.write_all(&head[at + end + 1..]);
                found = true;
            }
        }
    }
    if !found {
        let _ = log.write_all(&head);
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}
