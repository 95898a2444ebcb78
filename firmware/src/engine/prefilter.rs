//! The pre-filter: does any raw pixel of a run reach a value? Most row
//! segments of a window hold no candidate, and this answers for a whole
//! segment before any pixel is calibrated. Also the other word-at-a-time
//! loops of the engine's hot path, each with its portable twin.
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

/// [`any_at_least`] with `floor - 1` given in both 16-bit lanes of `lanes`
/// (as an open window keeps it, so the row loop does not form it again).
#[inline(always)]
pub fn any_above_lanes(raw: &[u16], lanes: u32) -> bool {
    #[cfg(target_arch = "arm")]
    {
        dsp::any_above_lanes(raw, lanes)
    }
    #[cfg(not(target_arch = "arm"))]
    {
        any_at_least_portable(raw, (lanes as u16).wrapping_add(1))
    }
}

/// The portable definition of [`any_at_least`].
#[inline(always)]
pub fn any_at_least_portable(raw: &[u16], floor: u16) -> bool {
    let below = floor.wrapping_sub(1);
    raw.iter().fold(0, |any, &r| any | r.saturating_sub(below)) != 0
}

/// The pixels of `raw` (at most 64) at or above `floor` as a bit mask: bit
/// `k` for `raw[k] >= floor`; `floor >= 1`. The host's hot loop visits only
/// those bits (`scan::row_portable`).
///
/// On x86-64, sixteen pixels per SSE2 step (`PSUBUSW` against `floor - 1`
/// and `PCMPEQW` on each half, `PACKSSWB`, `PMOVMSKB`): about twenty-five
/// instructions for a 16-pixel segment, setup included (about forty in
/// steps of eight, four a pixel in the compiler's scalar loop);
/// [`mask_at_least_portable`] is its twin (tests/tests/prefilter_mask.rs
/// compares them).
#[inline(always)]
pub fn mask_at_least(raw: &[u16], floor: u16) -> u64 {
    #[cfg(target_arch = "x86_64")]
    {
        sse2::mask_at_least(raw, floor)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        mask_at_least_portable(raw, floor)
    }
}

/// The portable definition of [`mask_at_least`].
#[inline(always)]
pub fn mask_at_least_portable(raw: &[u16], floor: u16) -> u64 {
    debug_assert!(raw.len() <= 64);
    raw.iter()
        .take(64)
        .enumerate()
        .fold(0, |mask, (k, &r)| mask | ((r >= floor) as u64) << k)
}

#[cfg(target_arch = "x86_64")]
mod sse2 {
    use core::arch::x86_64::{
        _mm_cmpeq_epi16, _mm_loadu_si128, _mm_movemask_epi8, _mm_packs_epi16, _mm_set1_epi16,
        _mm_setzero_si128, _mm_subs_epu16,
    };

    #[inline(always)]
    pub fn mask_at_least(raw: &[u16], floor: u16) -> u64 {
        let raw = &raw[..raw.len().min(64)];
        // SAFETY: SSE2 is part of x86-64; each load reads 8 pixels of
        // `raw` (`chunks_exact(16)`, then at least 8 left).
        unsafe {
            let below = _mm_set1_epi16(floor.wrapping_sub(1) as i16);
            let zero = _mm_setzero_si128();
            // A lane is 0xffff where the pixel is at most floor - 1.
            let low = |p: *const u16| {
                _mm_cmpeq_epi16(_mm_subs_epu16(_mm_loadu_si128(p.cast()), below), zero)
            };
            let mut mask = 0u64;
            let mut done = 0;
            // Sixteen pixels a step: both halves packed to one byte a
            // lane, one bit a byte (a 16-pixel segment, the usual
            // window, in one step).
            let mut sixteens = raw.chunks_exact(16);
            for chunk in &mut sixteens {
                let p = chunk.as_ptr();
                let bits = _mm_movemask_epi8(_mm_packs_epi16(low(p), low(p.add(8)))) as u64;
                mask |= (bits ^ 0xffff) << done;
                done += 16;
            }
            let rest = sixteens.remainder();
            if rest.len() >= 8 {
                let bits = _mm_movemask_epi8(_mm_packs_epi16(low(rest.as_ptr()), zero)) as u64;
                mask |= ((bits & 0xff) ^ 0xff) << done;
                done += 8;
            }
            for (k, &r) in raw[done..].iter().enumerate() {
                mask |= ((r >= floor) as u64) << (done + k);
            }
            mask
        }
    }
}

/// `to.copy_from_slice(from)` for words (the engine's row history). On
/// Cortex-M with `LDM`/`STM` of eight registers, sixteen words (32
/// pixels) per six instructions, then eight, then four, then the last words
/// one at a time, all in one routine: with the tail left to a Rust loop the
/// compiler unrolled it and computed its trip counts at the start of every
/// push (CANARY on Cortex-M4 15.11 against 15.00 instructions a pixel); four
/// registers a transfer instead of eight cost CANARY 0.13 instructions a
/// pixel more (13.37 against 13.22), every row-pushed workload alike.
/// [`copy_words_portable`] is its twin, which the QEMU benchmark's
/// self-test compares it with on every length up to 70 words.
#[inline(always)]
pub fn copy_words(from: &[u32], to: &mut [u32]) {
    assert_eq!(from.len(), to.len());
    #[cfg(target_arch = "arm")]
    // SAFETY: both slices hold `to.len()` words (asserted).
    unsafe {
        copy_words_asm(from.as_ptr(), to.as_mut_ptr(), to.len())
    };
    #[cfg(not(target_arch = "arm"))]
    copy_words_portable(from, to);
}

/// [`copy_words`] out of memory that the program does not own as a slice:
/// a DMA buffer, which a DMA may write at any time (the camera source's
/// ring, `camera::copy_from_ring`). The assembly reads each word once,
/// when it runs, and the compiler cannot move memory accesses across it;
/// elsewhere, volatile reads.
///
/// # Safety
/// `from` is aligned and valid for reads of `to.len()` words.
#[inline(always)]
pub unsafe fn copy_words_from(from: *const u32, to: &mut [u32]) {
    #[cfg(target_arch = "arm")]
    // SAFETY: the caller's contract for `from`; `to` is a slice.
    unsafe {
        copy_words_asm(from, to.as_mut_ptr(), to.len())
    };
    #[cfg(not(target_arch = "arm"))]
    for (k, w) in to.iter_mut().enumerate() {
        // SAFETY: the caller's contract.
        *w = unsafe { from.add(k).read_volatile() };
    }
}

/// The assembly of [`copy_words`]: `n / 16` rounds of sixteen words, eight
/// if bit 3 of `n` is set, four if bit 2 is, then `n % 4` single words;
/// r2-r5, r8, r10-r12 are clobbered.
///
/// # Safety
/// `from` and `to` are aligned, valid for `n` words each (reads, writes).
#[cfg(target_arch = "arm")]
#[inline(always)]
unsafe fn copy_words_asm(from: *const u32, to: *mut u32, n: usize) {
    // SAFETY: the caller's contract: exactly `n` words read from `from`
    // and written to `to`.
    unsafe {
        core::arch::asm!(
            "lsrs {o}, {n}, #4",
            "beq 3f",
            "2:",
            "ldm {f}!, {{r2, r3, r4, r5, r8, r10, r11, r12}}",
            "stm {t}!, {{r2, r3, r4, r5, r8, r10, r11, r12}}",
            "ldm {f}!, {{r2, r3, r4, r5, r8, r10, r11, r12}}",
            "stm {t}!, {{r2, r3, r4, r5, r8, r10, r11, r12}}",
            "subs {o}, {o}, #1",
            "bne 2b",
            "3:",
            "tst {n}, #8",
            "beq 7f",
            "ldm {f}!, {{r2, r3, r4, r5, r8, r10, r11, r12}}",
            "stm {t}!, {{r2, r3, r4, r5, r8, r10, r11, r12}}",
            "7:",
            "tst {n}, #4",
            "beq 4f",
            "ldm {f}!, {{r2, r3, r4, r5}}",
            "stm {t}!, {{r2, r3, r4, r5}}",
            "4:",
            "ands {n}, {n}, #3",
            "beq 6f",
            "5:",
            "ldr r2, [{f}], #4",
            "str r2, [{t}], #4",
            "subs {n}, {n}, #1",
            "bne 5b",
            "6:",
            f = inout(reg) from => _,
            t = inout(reg) to => _,
            n = inout(reg) n => _,
            o = out(reg) _,
            out("r2") _, out("r3") _, out("r4") _, out("r5") _,
            out("r8") _, out("r10") _, out("r11") _, out("r12") _,
            options(nostack),
        );
    }
}

/// The portable definition of [`copy_words`].
#[inline(always)]
pub fn copy_words_portable(from: &[u32], to: &mut [u32]) {
    to.copy_from_slice(from);
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
        any_above(raw, below, below as u32 * 0x0001_0001)
    }

    #[inline(always)]
    pub fn any_above_lanes(raw: &[u16], lanes: u32) -> bool {
        any_above(raw, lanes as u16, lanes)
    }

    /// Whether some pixel is above `below` (`lanes`: it in both lanes).
    #[inline(always)]
    fn any_above(raw: &[u16], below: u16, lanes: u32) -> bool {
        // The usual run: word-aligned, a whole number of words (a window's
        // row segment of even width at an even column).
        if (raw.as_ptr() as usize | raw.len()) & 1 == 0 && raw.as_ptr() as usize & 2 == 0 {
            // SAFETY: aligned to 4 and `2 * (len / 2)` u16 long (checked).
            return unsafe { any_word_above(raw.as_ptr() as *const u32, raw.len() / 2, lanes) };
        }
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

    /// Whether a lane of the `n` words from `words` is above its lane of
    /// `lanes`: four words per `LDM` and seven instructions, stopping at the
    /// first quad that has one (the compiler's version of this loop, merged
    /// with the unaligned path, spent about twenty instructions on set-up).
    ///
    /// # Safety
    /// `words` points to `n` readable, aligned words.
    #[inline(always)]
    unsafe fn any_word_above(words: *const u32, n: usize, lanes: u32) -> bool {
        let any: u32;
        // SAFETY: reads the `n` words only (the caller's contract); r2-r5
        // are clobbered.
        unsafe {
            core::arch::asm!(
                "movs {any}, #0",
                "lsrs {q}, {n}, #2",
                "beq 2f",
                "1:",
                "ldm {p}!, {{r2, r3, r4, r5}}",
                "uqsub16 r2, r2, {lanes}",
                "uqsub16 r3, r3, {lanes}",
                "orr r2, r2, r3",
                "uqsub16 r4, r4, {lanes}",
                "uqsub16 r5, r5, {lanes}",
                "orr r4, r4, r5",
                "orrs r2, r2, r4",
                "bne 8f",
                "subs {q}, {q}, #1",
                "bne 1b",
                "2:",
                "ands {n}, {n}, #3",
                "beq 9f",
                "3:",
                "ldr r2, [{p}], #4",
                "uqsub16 r2, r2, {lanes}",
                "cmp r2, #0",
                "bne 8f",
                "subs {n}, {n}, #1",
                "bne 3b",
                "b 9f",
                "8:",
                "movs {any}, #1",
                "9:",
                any = out(reg) any,
                q = out(reg) _,
                p = inout(reg) words => _,
                n = inout(reg) n => _,
                lanes = in(reg) lanes,
                out("r2") _, out("r3") _, out("r4") _, out("r5") _,
                options(nostack, readonly),
            );
        }
        any != 0
    }
}
