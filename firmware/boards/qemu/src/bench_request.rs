//! The bench request on the QEMU board (PROTOCOL.md §14): the engine and
//! the honest floor on `brightpix_bench::workloads::ALL`, counted in
//! instructions with timer0 under `-icount` (QEMU's DWT cycle counter reads
//! 0), exactly as the QEMU bench counts them (its `Meter`), so that the
//! whole path of `brightpix bench --port` is tested without a board. QEMU
//! started without `-icount` gives `CountUnit::Uncounted`.

use brightpix_bench::device::{BenchBuffers, BoardBench, BoardCounter};
use brightpix_bench::Counter;
use brightpix_protocol::wire::CountUnit;
use static_cell::{ConstStaticCell, StaticCell};

use crate::meter::Meter;

/// Windows of a workload the bench request measures (the ELT-like grid's
/// 6,400 do not fit: its frame is larger than a gain map anyway).
pub const BENCH_WINDOWS: usize = 256;
/// Frames a bench request measures per workload, at most.
pub const BENCH_FRAMES: usize = 64;

/// The board's bench mode, in the device's engine memory and staging slot,
/// with buffers of its own.
pub type Bench = BoardBench<'static, DeviceMeter, BENCH_WINDOWS, BENCH_FRAMES>;

static BUFFERS: ConstStaticCell<BenchBuffers<BENCH_WINDOWS, BENCH_FRAMES>> =
    ConstStaticCell::new(BenchBuffers::new());
static BENCH: StaticCell<Bench> = StaticCell::new();

/// The bench mode, once.
pub fn bench() -> &'static mut Bench {
    BENCH.init(BoardBench::new(DeviceMeter(None), BUFFERS.take()))
}

/// The QEMU bench's meter, calibrated at the start of every workload:
/// instructions under `-icount`, else uncounted.
pub struct DeviceMeter(Option<Meter>);

/// Interrupts are masked during each timed call (a camera row's push, a
/// floor row: thousands of instructions) and during the calibration, so no
/// handler's instructions (SysTick, UART0) are counted; pending ones run
/// between the calls.
impl Counter for DeviceMeter {
    #[inline(always)]
    fn count<R>(&self, f: impl FnOnce() -> R) -> (f64, R) {
        match &self.0 {
            Some(meter) => cortex_m::interrupt::free(|_| meter.count(f)),
            None => (0.0, f()),
        }
    }
}

impl BoardCounter for DeviceMeter {
    fn start(&mut self) -> (CountUnit, Option<u32>) {
        let (meter, shift) = cortex_m::interrupt::free(|_| Meter::calibrate());
        self.0 = Some(meter);
        let unit = match shift {
            Some(_) => CountUnit::Instructions,
            None => CountUnit::Uncounted,
        };
        (unit, None)
    }
}
