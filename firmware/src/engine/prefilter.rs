//! The pre-filter: does any raw pixel of a run reach a value? Most row
//! segments of a window hold no candidate, and this answers for a whole
//! segment before any pixel is calibrated.
//!
//! On Cortex-M4/M7 (ARMv7E-M) it tests two pixels per instruction with
//! `UQSUB16` (two lanes of unsigned saturating subtraction): a lane is
//! non-zero exactly when its pixel is above `floor - 1`. Elsewhere it is the
//! portable loop, which compilers vectorise. [`any_at_least_portable`] is the
//! twin the Cortex-M code is checked against (in QEMU, by the benchmark's
//! self-test, and end to end by the simulation-in-the-loop tests).

/// Whether some `r` in `raw` has `r >= floor`; `floor >= 1`.
#[inline(always)]
pub fn any_at_least(raw: &[u16], floor: u16) -> bool {
    #[cfg(target_arch = "arm")]
    {
        dsp::any_at_least(raw, floor)
    }
    #[cfg(not(target_arch = "arm"))]
    {
        any_at_least_portable(raw, floor)
    }
}

/// The portable definition of [`any_at_least`].
#[inline(always)]
pub fn any_at_least_portable(raw: &[u16], floor: u16) -> bool {
    let below = floor.wrapping_sub(1);
    raw.iter().fold(0, |any, &r| any | r.saturating_sub(below)) != 0
}

/// `UQSUB16`: two lanes of `a - b` saturated at 0.
#[inline(always)]
pub fn uqsub16(a: u32, b: u32) -> u32 {
    #[cfg(target_arch = "arm")]
    {
        dsp::uqsub16(a, b)
    }
    #[cfg(not(target_arch = "arm"))]
    {
        uqsub16_portable(a, b)
    }
}

/// The portable definition of [`uqsub16`].
#[inline(always)]
pub fn uqsub16_portable(a: u32, b: u32) -> u32 {
    let lo = (a as u16).saturating_sub(b as u16) as u32;
    let hi = ((a >> 16) as u16).saturating_sub((b >> 16) as u16) as u32;
    hi << 16 | lo
}

#[cfg(target_arch = "arm")]
mod dsp {
    /// One `UQSUB16` instruction (ARMv7E-M DSP extension).
    #[inline(always)]
    pub fn uqsub16(a: u32, b: u32) -> u32 {
        let r;
        // SAFETY: a register-only arithmetic instruction, present on every
        // ARMv7E-M core (the firmware's target, thumbv7em).
        unsafe {
            core::arch::asm!(
                "uqsub16 {r}, {a}, {b}",
                r = lateout(reg) r,
                a = in(reg) a,
                b = in(reg) b,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        r
    }

    #[inline(always)]
    pub fn any_at_least(raw: &[u16], floor: u16) -> bool {
        let below = floor.wrapping_sub(1);
        let lanes = below as u32 * 0x0001_0001;
        // SAFETY: any pair of u16 is a valid u32; align_to only splits the
        // slice where the words are aligned.
        let (head, words, tail) = unsafe { raw.align_to::<u32>() };
        let mut any = 0u32;
        for &r in head.iter().chain(tail) {
            any |= r.saturating_sub(below) as u32;
        }
        let mut quads = words.chunks_exact(4);
        for q in &mut quads {
            any |= uqsub16(q[0], lanes)
                | uqsub16(q[1], lanes)
                | uqsub16(q[2], lanes)
                | uqsub16(q[3], lanes);
        }
        for &w in quads.remainder() {
            any |= uqsub16(w, lanes);
        }
        any != 0
    }
}
