//! The rig's sync line: one GPIO wired to every board of a rig, so that
//! all of them start counting frames on the same camera frame (PROTOCOL.md
//! §9, `CaptureStart`). Thin glue beside the DCMI: it only decides *when*
//! the DCMI's CAPTURE bit is set; the camera source and the engine do not
//! know it exists.
//!
//! NOT RUN ON HARDWARE: written from RM0433 and built, never tested on a
//! board.
//!
//! # Wiring
//!
//! **PF13** (NUCLEO-H743ZI zio connector CN10, pin D7) on every board, one
//! wire and a common ground between the boards; no other wiring. It avoids
//! every pin the DCMI and the NUCLEO use (`dcmi.rs`). On a board that is
//! not capturing it is an input with a pull-down, so any board can become
//! the leader and an idle line reads low.
//!
//! # Follower (`OnSync`)
//!
//! `Capture` arms: the DMA and the DCMI are set up and enabled as for an
//! immediate start, but CAPTURE is left clear; EXTI line 13 (port F) on a
//! rising edge is unmasked. Its interrupt sets CAPTURE, and the DCMI then
//! begins with the next frame start (VSYNC): frame 0. A line already high
//! when arming is refused (`SyncFault::LineHigh`): no edge could come.
//!
//! # Leader (`DriveSync`)
//!
//! `Capture` arms the same way and unmasks EXTI line 9 (port G: PG9, the
//! DCMI's VSYNC, rising = frame valid = a frame start with `VSPOL` = 0;
//! the pin's input path still feeds the EXTI in alternate-function mode).
//! At that frame start, frame `j`, its interrupt drives PF13 high and sets
//! its own CAPTURE: every board, leader included, begins with frame
//! `j + 1`, and the followers had almost all of frame `j` (less their
//! interrupt latency, a few microseconds) to see the edge. The line goes
//! low again, an input again, when the leader's capture stops.
//!
//! The host arms every follower first and releases the leader only when
//! all have acknowledged (`brightpix rig capture`); a follower armed after
//! the edge waits for ever (the host times out and says so).

use core::sync::atomic::{AtomicBool, AtomicU8, Ordering};

use brightpix_firmware::device::CaptureBegin;
use brightpix_protocol::wire::{CaptureStart, SyncFault};
use embassy_stm32::interrupt::typelevel::{Handler, Interrupt, EXTI15_10, EXTI9_5};
use embassy_stm32::interrupt::Priority;
use embassy_stm32::pac;
use embassy_stm32::pac::gpio::vals;

/// The sync line: PF13.
const LINE_PORT: u8 = 5; // F
const LINE_PIN: usize = 13;
/// The DCMI's VSYNC: PG9.
const VSYNC_PORT: u8 = 6; // G
const VSYNC_PIN: usize = 9;

const IDLE: u8 = 0;
const FOLLOWER: u8 = 1;
const LEADER: u8 = 2;

/// What the armed capture waits for.
static ROLE: AtomicU8 = AtomicU8::new(IDLE);
/// The running capture's frame 0 follows a sync edge.
static SYNCED: AtomicBool = AtomicBool::new(false);

/// The line's port (GPIOF).
fn line_port() -> pac::gpio::Gpio {
    pac::GPIOF
}

/// Sets the line's pin up as an input with a pull-down and the EXTI's
/// clock on (once, at start-up), both EXTI lines masked.
pub fn init() {
    pac::RCC.apb4enr().modify(|w| w.set_syscfgen(true));
    pac::RCC.ahb4enr().modify(|w| w.set_gpiofen(true));
    release_line();
    let exti = pac::EXTI;
    exti.imr(0).modify(|w| {
        w.set_line(LINE_PIN, false);
        w.set_line(VSYNC_PIN, false);
    });
    pac::SYSCFG
        .exticr(LINE_PIN / 4)
        .modify(|w| w.set_exti(LINE_PIN % 4, LINE_PORT));
    pac::SYSCFG
        .exticr(VSYNC_PIN / 4)
        .modify(|w| w.set_exti(VSYNC_PIN % 4, VSYNC_PORT));
    exti.rtsr(0).modify(|w| {
        w.set_line(LINE_PIN, true);
        w.set_line(VSYNC_PIN, true);
    });
    exti.ftsr(0).modify(|w| {
        w.set_line(LINE_PIN, false);
        w.set_line(VSYNC_PIN, false);
    });
    // Above the DCMI's frame end (P1), below nothing: a few register
    // writes.
    EXTI9_5::set_priority(Priority::P0);
    EXTI15_10::set_priority(Priority::P0);
    // SAFETY: the handlers are bound (`bind_interrupts!` in main).
    unsafe {
        EXTI9_5::enable();
        EXTI15_10::enable();
    }
}

/// PF13 an input with a pull-down (not driven).
fn release_line() {
    let port = line_port();
    port.bsrr().write(|w| w.set_br(LINE_PIN, true));
    port.pupdr()
        .modify(|w| w.set_pupdr(LINE_PIN, vals::Pupdr::PULL_DOWN));
    port.moder()
        .modify(|w| w.set_moder(LINE_PIN, vals::Moder::INPUT));
}

fn line_high() -> bool {
    line_port().idr().read().idr(LINE_PIN) == vals::Idr::HIGH
}

/// Whether `start` can be armed now; nothing changes yet.
pub fn check(start: CaptureStart) -> Result<(), SyncFault> {
    match start {
        CaptureStart::OnSync if line_high() => Err(SyncFault::LineHigh),
        _ => Ok(()),
    }
}

/// Arms the capture the DCMI was just set up for (CAPTURE still clear).
/// Returns whether the DCMI should capture at once (`Immediate`).
pub fn arm(start: CaptureStart) -> bool {
    SYNCED.store(false, Ordering::Release);
    let (role, line) = match start {
        CaptureStart::Immediate => return true,
        CaptureStart::OnSync => (FOLLOWER, LINE_PIN),
        CaptureStart::DriveSync => (LEADER, VSYNC_PIN),
    };
    ROLE.store(role, Ordering::Release);
    let exti = pac::EXTI;
    exti.pr(0).write(|w| w.set_line(line, true));
    exti.imr(0).modify(|w| w.set_line(line, true));
    false
}

/// The capture stopped: both lines masked, the line released.
pub fn disarm() {
    ROLE.store(IDLE, Ordering::Release);
    pac::EXTI.imr(0).modify(|w| {
        w.set_line(LINE_PIN, false);
        w.set_line(VSYNC_PIN, false);
    });
    release_line();
}

/// How the running capture began (the DCMI gives no frame number).
pub fn began() -> CaptureBegin {
    CaptureBegin {
        synced: SYNCED.load(Ordering::Acquire),
        camera_frame: None,
    }
}

/// Sets the DCMI's CAPTURE: it begins with the next frame start.
fn capture_now() {
    pac::DCMI.cr().modify(|w| w.set_capture(true));
    SYNCED.store(true, Ordering::Release);
}

/// EXTI 10-15: the follower's edge on PF13.
pub struct FollowerInterrupt;

impl Handler<EXTI15_10> for FollowerInterrupt {
    unsafe fn on_interrupt() {
        let exti = pac::EXTI;
        if !exti.pr(0).read().line(LINE_PIN) {
            return;
        }
        exti.imr(0).modify(|w| w.set_line(LINE_PIN, false));
        exti.pr(0).write(|w| w.set_line(LINE_PIN, true));
        if ROLE.load(Ordering::Acquire) == FOLLOWER {
            capture_now();
        }
    }
}

/// EXTI 5-9: the leader's frame start on PG9 (VSYNC).
pub struct LeaderInterrupt;

impl Handler<EXTI9_5> for LeaderInterrupt {
    unsafe fn on_interrupt() {
        let exti = pac::EXTI;
        if !exti.pr(0).read().line(VSYNC_PIN) {
            return;
        }
        exti.imr(0).modify(|w| w.set_line(VSYNC_PIN, false));
        exti.pr(0).write(|w| w.set_line(VSYNC_PIN, true));
        if ROLE.load(Ordering::Acquire) == LEADER {
            // Frame `j` has just started: drive the line high, then capture
            // from frame `j + 1`, as every follower does.
            let port = line_port();
            port.bsrr().write(|w| w.set_bs(LINE_PIN, true));
            port.otyper()
                .modify(|w| w.set_ot(LINE_PIN, vals::Ot::PUSH_PULL));
            port.moder()
                .modify(|w| w.set_moder(LINE_PIN, vals::Moder::OUTPUT));
            capture_now();
        }
    }
}
