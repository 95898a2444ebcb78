//! Simulated devices on the desktop, for `brightpix simulate-device`,
//! `brightpix demo` and the simulation-in-loop tests:
//!
//! - [`InProcessDevice`]: the firmware library's device loop
//!   (`brightpix_firmware::device::Device`, the code the boards run) on a
//!   thread of this process, speaking over one end of a pseudo-terminal
//!   pair (or a Unix socket); any serial client opens the other end;
//! - [`QemuDevice`]: the real firmware ELF (`brightpix-qemu`) in
//!   `qemu-system-arm` (mps2-an386 Cortex-M4, or mps2-an500 Cortex-M7: [`QemuCpu`]), its UART0 on a pseudo-terminal or a
//!   Unix socket, its pixels optionally from a FIFO that the host writes
//!   (read by semihosting, much faster than the emulated UART).
//!
//! Both optionally read `PixelRows` frames from a FIFO as well
//! ([`PixelSink::Fifo`](crate::link::PixelSink) on the client side), or
//! have a camera of their own ([`camera`]: simulated Shack-Hartmann frames
//! in the firmware's camera ring, for `brightpix capture`).
//!
//! | file | what |
//! |---|---|
//! | `in_process.rs` | [`InProcessDevice`] and its options |
//! | `qemu.rs` | [`QemuDevice`], and finding or building its ELF |
//! | `camera.rs` | the simulated camera: its frames, the in-process camera thread, the QEMU board's frame server |
//! | `timeline.rs` | [`SharedCamera`]: one camera for several boards, its timeline and sync line |
//! | `link.rs` | the in-process device's transports (pty, Unix socket, pixel FIFO) and executor |
//! | `storage.rs` | [`HeapDeviceStorage`]: a board's statics on the heap |

pub mod camera;
mod in_process;
mod link;
mod qemu;
mod storage;
pub mod timeline;

use std::ffi::CString;
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::{self, JoinHandle};

pub use camera::{CameraFrames, CameraOptions, CameraSpec};
pub use in_process::{InProcessDevice, InProcessOptions, SimLinkKind};
pub use link::{block_on, Stopped};
pub use qemu::{
    build_qemu_elf, build_qemu_elf_for, default_qemu_elf, firmware_dir, qemu_elf, qemu_elf_for,
    QemuCpu, QemuDevice, QemuOptions,
};
pub use storage::{HeapDeviceStorage, SimSizes};
pub use timeline::SharedCamera;

static DIR_COUNTER: AtomicU64 = AtomicU64::new(0);

/// A fresh private directory under the system's temporary directory.
pub fn temp_dir(prefix: &str) -> io::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!(
        "{prefix}-{}-{}",
        std::process::id(),
        DIR_COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

fn spawn(name: &str, f: impl FnOnce() + Send + 'static) -> io::Result<JoinHandle<()>> {
    thread::Builder::new()
        .name(name.into())
        .stack_size(4 << 20)
        .spawn(f)
}

/// Creates a FIFO at `path` unless something is there already.
pub fn make_fifo(path: &Path) -> io::Result<()> {
    if path.exists() {
        return Ok(());
    }
    let c = CString::new(path.as_os_str().as_bytes())
        .map_err(|_| io::Error::other("FIFO path contains a NUL byte"))?;
    // SAFETY: `c` is a valid NUL-terminated path.
    if unsafe { libc::mkfifo(c.as_ptr(), 0o600) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

// --- Ctrl-C -------------------------------------------------------------------------

static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

/// Catches SIGINT and SIGTERM from now on; [`interrupted`] tells whether
/// one arrived.
pub fn catch_interrupts() {
    let handler = on_signal as extern "C" fn(libc::c_int);
    // SAFETY: the handler only stores to an atomic (async-signal-safe).
    unsafe {
        libc::signal(libc::SIGINT, handler as libc::sighandler_t);
        libc::signal(libc::SIGTERM, handler as libc::sighandler_t);
    }
}

/// Whether SIGINT or SIGTERM arrived since [`catch_interrupts`].
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}
