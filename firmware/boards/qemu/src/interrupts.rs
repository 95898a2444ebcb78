//! The device interrupt vector table of the mps2 boards (cortex-m-rt `device`
//! feature), as a device crate would provide it: entries are symbols that
//! device.x `PROVIDE`s as `DefaultHandler` unless a `#[no_mangle]` function of
//! that name exists (UART0_RX/UART0_TX are in `uart`).

/// External interrupt lines of QEMU's mps2-an385/an386/an500 NVIC.
const NUM_IRQS: usize = 32;

unsafe extern "C" {
    fn DefaultHandler();
    fn UART0_RX();
    fn UART0_TX();
}

/// One entry per external interrupt (IRQ n is at index n).
#[unsafe(link_section = ".vector_table.interrupts")]
#[unsafe(no_mangle)]
static __INTERRUPTS: [unsafe extern "C" fn(); NUM_IRQS] = {
    let mut table = [DefaultHandler as unsafe extern "C" fn(); NUM_IRQS];
    table[0] = UART0_RX;
    table[1] = UART0_TX;
    table
};
