//! The DCMI in continuous capture mode, its data streamed by DMA1 stream 0
//! (DMAMUX1 request `dcmi_dma`) into a circular ring in AXI SRAM: the
//! hardware side of `brightpix_firmware::camera::DmaRing`. Register level
//! through embassy-stm32's `unstable-pac` (embassy's own DCMI driver only
//! takes single snapshots).
//!
//! NOT RUN ON HARDWARE: written from RM0433 and built, never tested on a
//! board.
//!
//! # Wiring (NUCLEO-H743ZI, all AF13)
//!
//! | signal | pin | | signal | pin |
//! |---|---|---|---|---|
//! | PIXCLK | PA6 | | D7 | PE6 |
//! | HSYNC | PA4 | | D8 | PC10 |
//! | VSYNC | PG9 | | D9 | PC12 |
//! | D0 | PC6 | | D10 | PD6 |
//! | D1 | PC7 | | D11 | PD2 |
//! | D2 | PC8 | | D12 | PF11 |
//! | D3 | PC9 | | D13 | PG15 |
//! | D4 | PC11 | | | |
//! | D5 | PD3 | | | |
//! | D6 | PE5 | | | |
//!
//! The pins are checked at compile time against the chip's alternate
//! functions (embassy's DCMI pin traits). They avoid what the NUCLEO-H743ZI
//! wires elsewhere by default: Ethernet RMII (PA1, PA2, PA7, PB13, PC1, PC4,
//! PC5, PG11, PG13), USB (PA8-PA12), the LEDs (PB0, PB7 / PE1, PB14), the user
//! button (PC13), the ST-LINK UART (PD8, PD9) and SWD (PA13, PA14). PC8-PC12
//! and PD2 are the SD-card pins of the ST zio connector CN8. All 14 data pins
//! are configured whatever the data width; in 8/10/12-bit modes the upper
//! ones are simply not sampled.
//!
//! # Timing (what the FPGA or camera must drive)
//!
//! - PIXCLK: data sampled on the rising edge (`PCKPOL` = 1).
//! - HSYNC, VSYNC: "line valid" / "frame valid", high while pixels are valid
//!   (`HSPOL` = `VSPOL` = 0: synchronisation, i.e. blanking, is low).
//! - Hardware synchronisation (no embedded codes), continuous grab
//!   (`CM` = 0), no JPEG, every frame (`FCRC` = 0), all bytes.
//! - Crop (`CROP` = 1, `DCMI_CWSTRT`, `DCMI_CWSIZE`) when the configuration
//!   has one (a board of a rig: the camera's bus is fanned out to several
//!   boards, each keeping its rectangle); its rules and register values are
//!   `brightpix_firmware::camera::crop`'s, tested on the host.
//! - Every frame `width * height` pixels of the configured camera (with a
//!   crop: the sensor's, of which the rectangle is captured), a whole
//!   number of 16-byte DMA bursts (4 words: 8 pixels in 10/12/14-bit mode,
//!   16 in 8-bit mode); some vertical blanking between frames (the
//!   frame-end interrupt reads the DMA position in it, once the DCMI and
//!   DMA FIFOs have drained).
//!
//! # Interrupts and the DMA
//!
//! - DMA1 stream 0 in FIFO mode with 4-word bursts to memory (MBURST INCR4,
//!   FIFO threshold full: RM0433 DMA_SxCR bits 24:23, DMA_SxFCR DMDIS bit 2
//!   and FTH bits 1:0): a quarter of the AXI bus transactions of direct
//!   mode, and 16 bytes of buffering against bus stalls before the DCMI's
//!   own FIFO overruns.
//! - One DMA interrupt per ring half (half-transfer and transfer-complete)
//!   and one DCMI interrupt per frame end; no line interrupt (it fired on
//!   every camera line: ~0.5 M interrupts/s at 240 lines x 2 kHz). The ring
//!   is sized so that a half is a few camera rows (`storage::RING_WORDS`):
//!   the camera source is woken every half and at the frame end.
//! - NDTR counts words read from the DCMI, some of which may still sit in
//!   the DMA FIFO: [`progress`] holds back by the FIFO's 4 words unless the
//!   FIFO reads empty (then every counted word is in memory), even behind
//!   the half the interrupt has counted (the half-transfer flag may come
//!   before the last burst lands), so the source never copies a word not
//!   yet written.

use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;

use brightpix_firmware::camera::{
    copy_from_ring, dcmi_check, DataWidth, DcmiCropRegisters, DmaProgress, DmaRing, FrameMarks,
    CACHE_LINE_BYTES,
};
use brightpix_firmware::device::CaptureBegin;
use brightpix_protocol::wire::{CaptureStart, CropFault, SyncFault};
use brightpix_protocol::{Camera, Crop};
use embassy_stm32::dcmi::{
    D0Pin, D10Pin, D11Pin, D12Pin, D13Pin, D1Pin, D2Pin, D3Pin, D4Pin, D5Pin, D6Pin, D7Pin, D8Pin,
    D9Pin, FrameDma, HSyncPin, PixClkPin, VSyncPin,
};
use embassy_stm32::gpio::{AfType, Flex, Pin, Pull};
use embassy_stm32::interrupt::typelevel::{Handler, Interrupt, DCMI as DcmiIrq, DMA1_STREAM0};
use embassy_stm32::interrupt::Priority;
use embassy_stm32::pac;
use embassy_stm32::pac::dma::vals;
use embassy_stm32::peripherals::{DCMI, DMA1_CH0};
use embassy_stm32::Peri;
use embassy_sync::waitqueue::AtomicWaker;

/// DMA1 stream 0; DMAMUX1 channel 0 feeds it.
const STREAM: usize = 0;
/// Words per DMA burst to memory (MBURST INCR4 of 32-bit words).
const BURST_WORDS: usize = 4;
/// DMA_SxFCR.FS (bits 5:3) when the FIFO is empty.
const FIFO_EMPTY: u8 = 0b100;
/// Bound on the wait for the DCMI FIFO to drain at a frame end.
const FIFO_DRAIN_SPINS: u32 = 1000;

/// Half-transfer and transfer-complete events of the stream.
static HALF_EVENTS: AtomicU32 = AtomicU32::new(0);
/// Frame ends, recorded by the DCMI interrupt.
static MARKS: FrameMarks = FrameMarks::new();
static WAKER: AtomicWaker = AtomicWaker::new();
/// Reads of DCMI_CR waiting for CAPTURE to clear when stopping (each a few
/// cycles on the AHB: about 0.2 s in all at 480 MHz).
const CAPTURE_STOP_SPINS: u32 = 20_000_000;

/// The ring's address and length, for the frame-end interrupt.
static RING_LEN: AtomicU32 = AtomicU32::new(0);

/// Hardware events, for the log.
pub static DCMI_OVERRUNS: AtomicU32 = AtomicU32::new(0);
pub static DCMI_SYNC_ERRORS: AtomicU32 = AtomicU32::new(0);
pub static DMA_ERRORS: AtomicU32 = AtomicU32::new(0);
pub static DMA_FIFO_ERRORS: AtomicU32 = AtomicU32::new(0);
pub static FIFO_NOT_DRAINED: AtomicU32 = AtomicU32::new(0);

/// The DCMI interrupt: frame ends (marks and wake-ups), errors.
pub struct DcmiInterrupt;

impl Handler<DcmiIrq> for DcmiInterrupt {
    unsafe fn on_interrupt() {
        let dcmi = pac::DCMI;
        let mis = dcmi.mis().read();
        dcmi.icr().write(|w| {
            w.set_frame_isc(mis.frame_mis());
            w.set_ovr_isc(mis.ovr_mis());
            w.set_err_isc(mis.err_mis());
            w.set_vsync_isc(mis.vsync_mis());
        });
        if mis.ovr_mis() {
            DCMI_OVERRUNS.fetch_add(1, Ordering::Relaxed);
        }
        if mis.err_mis() {
            DCMI_SYNC_ERRORS.fetch_add(1, Ordering::Relaxed);
        }
        if mis.frame_mis() {
            // Vertical blanking: no new data. Let the last words leave the
            // DCMI FIFO and then the DMA FIFO (its last burst; a frame is
            // whole bursts), then record where the DMA is.
            let mut spins = 0;
            while (dcmi.sr().read().fne() || !dma_fifo_empty()) && spins < FIFO_DRAIN_SPINS {
                spins += 1;
            }
            if spins == FIFO_DRAIN_SPINS {
                FIFO_NOT_DRAINED.fetch_add(1, Ordering::Relaxed);
            }
            cortex_m::asm::dsb();
            let len = RING_LEN.load(Ordering::Relaxed) as usize;
            MARKS.record(progress(len));
            WAKER.wake();
        }
    }
}

/// DMA1 stream 0: counts half rings.
pub struct DmaInterrupt;

impl Handler<DMA1_STREAM0> for DmaInterrupt {
    unsafe fn on_interrupt() {
        let dma = pac::DMA1;
        // LISR/LIFCR hold streams 0-3; stream 0 is field 0.
        let isr = dma.isr(STREAM / 4).read();
        let n = STREAM % 4;
        dma.ifcr(STREAM / 4).write(|w| {
            w.set_htif(n, isr.htif(n));
            w.set_tcif(n, isr.tcif(n));
            w.set_teif(n, isr.teif(n));
            w.set_dmeif(n, isr.dmeif(n));
            w.set_feif(n, isr.feif(n));
        });
        // Both at once only if this interrupt ran a half ring late.
        let events = isr.htif(n) as u32 + isr.tcif(n) as u32;
        if events > 0 {
            HALF_EVENTS.fetch_add(events, Ordering::Release);
            WAKER.wake();
        }
        if isr.teif(n) || isr.dmeif(n) {
            // A transfer error disables the stream: the source then sees
            // no more data (and the host no more frames).
            DMA_ERRORS.fetch_add(1, Ordering::Relaxed);
            WAKER.wake();
        }
        if isr.feif(n) {
            // FIFO overrun/underrun (DMA_LISR FEIF0): the DMA did not get
            // the memory bus in time; the DCMI overrun that follows is what
            // loses pixels.
            DMA_FIFO_ERRORS.fetch_add(1, Ordering::Relaxed);
        }
    }
}

fn half_events() -> u32 {
    HALF_EVENTS.load(Ordering::Acquire)
}

fn dma_fifo_empty() -> bool {
    pac::DMA1.st(STREAM).fcr().read().fs().to_bits() == FIFO_EMPTY
}

/// Where the DMA is: words counted by NDTR, held back by the FIFO's
/// 4 words unless the FIFO reads empty after NDTR (then every counted word
/// is in memory). The arithmetic is board independent and tested on the
/// host against a model of the DMA with both timings of the half-transfer
/// flag (`DmaProgress::through_fifo`, `tests/tests/camera_dma_fifo.rs`).
fn progress(len: usize) -> DmaProgress {
    DmaProgress::through_fifo(
        half_events,
        || pac::DMA1.st(STREAM).ndtr().read().ndt() as usize,
        dma_fifo_empty,
        len,
        BURST_WORDS,
    )
}

/// The DCMI pins, kept configured while the camera exists.
pub struct DcmiPins {
    _pins: [Flex<'static>; 17],
}

fn af_input<P: Pin>(pin: Peri<'static, P>, af: u8) -> Flex<'static> {
    let mut flex = Flex::new(pin);
    flex.set_as_af_unchecked(af, AfType::input(Pull::None));
    flex
}

impl DcmiPins {
    /// The NUCLEO-H743ZI pinout of the module documentation.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        pixclk: Peri<'static, impl PixClkPin<DCMI>>,
        hsync: Peri<'static, impl HSyncPin<DCMI>>,
        vsync: Peri<'static, impl VSyncPin<DCMI>>,
        d0: Peri<'static, impl D0Pin<DCMI>>,
        d1: Peri<'static, impl D1Pin<DCMI>>,
        d2: Peri<'static, impl D2Pin<DCMI>>,
        d3: Peri<'static, impl D3Pin<DCMI>>,
        d4: Peri<'static, impl D4Pin<DCMI>>,
        d5: Peri<'static, impl D5Pin<DCMI>>,
        d6: Peri<'static, impl D6Pin<DCMI>>,
        d7: Peri<'static, impl D7Pin<DCMI>>,
        d8: Peri<'static, impl D8Pin<DCMI>>,
        d9: Peri<'static, impl D9Pin<DCMI>>,
        d10: Peri<'static, impl D10Pin<DCMI>>,
        d11: Peri<'static, impl D11Pin<DCMI>>,
        d12: Peri<'static, impl D12Pin<DCMI>>,
        d13: Peri<'static, impl D13Pin<DCMI>>,
    ) -> Self {
        macro_rules! af {
            ($($p:ident),*) => { [$({ let af = $p.af_num(); af_input($p, af) }),*] };
        }
        DcmiPins {
            _pins: af!(
                pixclk, hsync, vsync, d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13
            ),
        }
    }
}

/// The DCMI, its DMA stream and the ring: a [`DmaRing`].
pub struct DcmiRing {
    ring: *mut u32,
    len: usize,
    request: u8,
    width: DataWidth,
    /// The crop the next `start` programs (`None`: the whole frame).
    crop: Option<DcmiCropRegisters>,
    /// How the next `start` begins (`sync.rs`).
    start: CaptureStart,
    _pins: DcmiPins,
    _dcmi: Peri<'static, DCMI>,
    _dma: Peri<'static, DMA1_CH0>,
}

impl DcmiRing {
    /// Takes the DCMI and DMA1 stream 0 and sets up both (stopped); the
    /// DCMI samples `width` bits per pixel. `ring` must be in AXI SRAM,
    /// 32-byte aligned, a multiple of 16 words and at most 65 535 words;
    /// the DMA owns it from now on. `width` must be a DCMI mode (8 to 14
    /// bits).
    pub fn new(
        dcmi: Peri<'static, DCMI>,
        dma: Peri<'static, DMA1_CH0>,
        pins: DcmiPins,
        ring: &'static mut [u32],
        width: DataWidth,
    ) -> Self {
        assert!(width.edm().is_some(), "the DCMI has no 16-bit mode");
        let len = ring.len();
        let ring = ring.as_mut_ptr();
        assert!((ring as usize).is_multiple_of(CACHE_LINE_BYTES));
        assert!((0x2400_0000..0x2408_0000).contains(&(ring as usize)));
        assert!(len.is_multiple_of(16) && len > 0 && len <= 65_535);
        let request = FrameDma::<DCMI>::request(&*dma);
        RING_LEN.store(len as u32, Ordering::Relaxed);
        embassy_stm32::rcc::enable_and_reset::<DCMI>();
        // embassy-stm32's init enables the DMA clocks; make sure of it.
        pac::RCC.ahb1enr().modify(|w| w.set_dma1en(true));
        // The camera interrupt below the DMA's (P0, embassy's default for
        // DMA), so the half events are counted first.
        DcmiIrq::set_priority(Priority::P1);
        DcmiIrq::unpend();
        // SAFETY: the handlers are bound (`bind_interrupts!` in main).
        unsafe {
            DcmiIrq::enable();
            DMA1_STREAM0::enable();
        }
        DcmiRing {
            ring,
            len,
            request,
            width,
            crop: None,
            start: CaptureStart::Immediate,
            _pins: pins,
            _dcmi: dcmi,
            _dma: dma,
        }
    }

    fn halt(&mut self) {
        let dcmi = pac::DCMI;
        // As ST's HAL_DCMI_Stop: CAPTURE cleared first, then, once it reads
        // back 0 (the capture in progress has stopped, at the end of its
        // frame), ENABLE. Bounded: a camera that stopped mid-frame leaves
        // CAPTURE set, and the watchdog must not bite here (~0.2 s at
        // 480 MHz, longer than any frame the board can keep up with).
        dcmi.cr().modify(|w| w.set_capture(false));
        let mut spins: u32 = 0;
        while dcmi.cr().read().capture() && spins < CAPTURE_STOP_SPINS {
            spins += 1;
        }
        dcmi.cr().modify(|w| w.set_enable(false));
        dcmi.ier().write(|_| {});
        let st = pac::DMA1.st(STREAM);
        st.cr().modify(|w| w.set_en(false));
        while st.cr().read().en() {}
        let n = STREAM % 4;
        pac::DMA1.ifcr(STREAM / 4).write(|w| {
            w.set_htif(n, true);
            w.set_tcif(n, true);
            w.set_teif(n, true);
            w.set_dmeif(n, true);
            w.set_feif(n, true);
        });
    }
}

impl DmaRing for DcmiRing {
    fn capacity(&self) -> usize {
        self.len
    }

    fn start(&mut self) -> u32 {
        self.halt();
        HALF_EVENTS.store(0, Ordering::Release);
        // DMAMUX1 channel 0 -> DMA1 stream 0: the DCMI's request.
        pac::DMAMUX1
            .ccr(STREAM)
            .write(|w| w.set_dmareq_id(self.request));
        let st = pac::DMA1.st(STREAM);
        st.par().write_value(pac::DCMI.dr().as_ptr() as u32);
        st.m0ar().write_value(self.ring as u32);
        st.ndtr().write(|w| w.set_ndt(self.len as u16));
        // FIFO mode, threshold full (4 words): memory writes in INCR4 bursts
        // (`write_index` accounts for the words in the FIFO).
        st.fcr().write(|w| {
            w.set_dmdis(vals::Dmdis::DISABLED);
            w.set_fth(vals::Fth::FULL);
            w.set_feie(true);
        });
        st.cr().write(|w| {
            w.set_dir(vals::Dir::PERIPHERAL_TO_MEMORY);
            w.set_circ(true);
            w.set_minc(true);
            w.set_pinc(false);
            w.set_psize(vals::Size::BITS32);
            w.set_msize(vals::Size::BITS32);
            w.set_mburst(vals::Burst::INCR4);
            w.set_pburst(vals::Burst::SINGLE);
            w.set_pl(vals::Pl::VERY_HIGH);
            w.set_htie(true);
            w.set_tcie(true);
            w.set_teie(true);
            w.set_dmeie(true);
        });
        // `storage::take` zeroed the ring before the D-cache was enabled,
        // so no dirty line of it exists; invalidate all of it anyway, so no
        // line filled since (speculative reads, a previous capture) can be
        // read in place of what the DMA writes, nor evicted over it.
        self.invalidate_lines(0, self.len * 4 / CACHE_LINE_BYTES);
        st.cr().modify(|w| w.set_en(true));

        let dcmi = pac::DCMI;
        if let Some(crop) = self.crop {
            dcmi.cwstrt().write(|w| {
                w.set_hoffcnt(crop.hoffcnt);
                w.set_vst(crop.vst);
            });
            dcmi.cwsize().write(|w| {
                w.set_capcnt(crop.capcnt);
                w.set_vline(crop.vline);
            });
        }
        dcmi.cr().write(|w| {
            w.set_cm(false); // continuous grab
            w.set_crop(self.crop.is_some());
            w.set_jpeg(false);
            w.set_ess(false); // hardware HSYNC/VSYNC
            w.set_pckpol(true); // rising edge
            w.set_hspol(false); // HSYNC low = blanking
            w.set_vspol(false); // VSYNC low = blanking
            w.set_fcrc(0); // every frame
            w.set_edm(self.width.edm().unwrap_or(0)); // checked in `new`
        });
        dcmi.icr().write(|w| {
            w.set_frame_isc(true);
            w.set_ovr_isc(true);
            w.set_err_isc(true);
            w.set_vsync_isc(true);
            w.set_line_isc(true);
        });
        // No line interrupt: the DMA's half events and the frame end wake
        // the source.
        dcmi.ier().write(|w| {
            w.set_frame_ie(true);
            w.set_ovr_ie(true);
            w.set_err_ie(true);
        });
        dcmi.cr().modify(|w| w.set_enable(true));
        // Capture begins at the next frame start (VSYNC): now, or from the
        // sync line's interrupt (`sync.rs`).
        if crate::sync::arm(self.start) {
            dcmi.cr().modify(|w| w.set_capture(true));
        }
        0
    }

    fn stop(&mut self) {
        crate::sync::disarm();
        self.halt();
    }

    fn set_start(&mut self, start: CaptureStart) -> Result<(), SyncFault> {
        crate::sync::check(start)?;
        self.start = start;
        Ok(())
    }

    fn began(&self) -> CaptureBegin {
        crate::sync::began()
    }

    fn half_events(&self) -> u32 {
        half_events()
    }

    /// Only with the event count it was read with: [`Self::progress`].
    fn write_index(&self) -> usize {
        progress(self.len).write_index as usize
    }

    fn progress(&self) -> DmaProgress {
        progress(self.len)
    }

    fn marks(&self) -> &FrameMarks {
        &MARKS
    }

    fn invalidate_lines(&mut self, first_line: usize, count: usize) {
        debug_assert!((first_line + count) * CACHE_LINE_BYTES <= self.len * 4);
        let base = self.ring as usize + first_line * CACHE_LINE_BYTES;
        // The DMA position that says these words are written was read
        // before; complete that before touching the cache.
        cortex_m::asm::dsb();
        // SAFETY: DCIMVAC on lines of the ring only, which the CPU never
        // writes (no dirty data is lost) and no other variable shares.
        unsafe {
            let cbp = &*cortex_m::peripheral::CBP::PTR;
            for line in 0..count {
                cbp.dcimvac.write((base + line * CACHE_LINE_BYTES) as u32);
            }
        }
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
    }

    fn copy(&mut self, start: usize, out: &mut [u32]) {
        assert!(start + out.len() <= self.len);
        // SAFETY: inside the ring (checked above), which is word-aligned.
        unsafe { copy_from_ring(self.ring.add(start), out) }
    }

    fn register_waker(&mut self, waker: &Waker) {
        WAKER.register(waker);
    }

    fn check_crop(&self, camera: Camera, crop: Crop) -> Result<(), CropFault> {
        dcmi_check(self.width, camera, crop)
    }

    fn set_crop(&mut self, camera: Camera, crop: Option<Crop>) {
        self.crop = crop.and_then(|c| DcmiCropRegisters::of(camera, c));
    }
}

/// Hardware event counts: DCMI FIFO overruns, synchronisation errors, DMA
/// transfer errors, DMA FIFO errors, frame ends whose FIFOs did not drain.
pub fn hardware_events() -> (u32, u32, u32, u32, u32) {
    (
        DCMI_OVERRUNS.load(Ordering::Relaxed),
        DCMI_SYNC_ERRORS.load(Ordering::Relaxed),
        DMA_ERRORS.load(Ordering::Relaxed),
        DMA_FIFO_ERRORS.load(Ordering::Relaxed),
        FIFO_NOT_DRAINED.load(Ordering::Relaxed),
    )
}
