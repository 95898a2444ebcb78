//! How the DCMI packs pixels into the 32-bit words its DMA writes.
//!
//! The DCMI collects the pixels it samples into 32-bit words, first pixel in
//! the least significant bits (RM0433 "DCMI data register"):
//!
//! | mode (`DCMI_CR.EDM`) | pixels per word | layout of one word                         |
//! |----------------------|-----------------|--------------------------------------------|
//! | 8-bit (`0b00`)       | 4               | `p0` bits 7:0, `p1` 15:8, `p2` 23:16, `p3` 31:24 |
//! | 10-bit (`0b01`)      | 2               | `p0` bits 9:0, `p1` bits 25:16, others 0   |
//! | 12-bit (`0b10`)      | 2               | `p0` bits 11:0, `p1` bits 27:16, others 0  |
//! | 14-bit (`0b11`)      | 2               | `p0` bits 13:0, `p1` bits 29:16, others 0  |
//!
//! | 16-bit (no DCMI mode) | 2              | `p0` bits 15:0, `p1` bits 31:16            |
//!
//! The 16-bit bus is the simulated camera's (`soft`): the DCMI's widest
//! mode is 14 bits. In the extended modes each pixel takes one 16-bit halfword. The halfword
//! is taken whole: nothing is masked, so a bit that should be 0 and is not
//! shows up as a value above the camera's bit depth, which the engine
//! refuses (`PixelOutOfRange`), instead of being silently cut off.

/// The DCMI's data width (`DCMI_CR.EDM`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataWidth {
    Bits8,
    Bits10,
    Bits12,
    Bits14,
    /// A 16-bit bus: the simulated camera's (`super::soft`); not a DCMI mode.
    Bits16,
}

impl DataWidth {
    /// Bits per pixel on the parallel bus.
    pub const fn bits(self) -> u8 {
        match self {
            DataWidth::Bits8 => 8,
            DataWidth::Bits10 => 10,
            DataWidth::Bits12 => 12,
            DataWidth::Bits14 => 14,
            DataWidth::Bits16 => 16,
        }
    }

    /// The narrowest bus that carries `bit_depth`-bit pixels (a DCMI mode up
    /// to 14 bits, the 16-bit bus above).
    pub const fn holding(bit_depth: u8) -> DataWidth {
        match bit_depth {
            0..=8 => DataWidth::Bits8,
            9..=10 => DataWidth::Bits10,
            11..=12 => DataWidth::Bits12,
            13..=14 => DataWidth::Bits14,
            _ => DataWidth::Bits16,
        }
    }

    /// Pixels in one 32-bit word.
    pub const fn pixels_per_word(self) -> usize {
        match self {
            DataWidth::Bits8 => 4,
            _ => 2,
        }
    }

    /// The value of `DCMI_CR.EDM` for this width (`None`: the DCMI has no
    /// 16-bit mode).
    pub const fn edm(self) -> Option<u8> {
        match self {
            DataWidth::Bits8 => Some(0b00),
            DataWidth::Bits10 => Some(0b01),
            DataWidth::Bits12 => Some(0b10),
            DataWidth::Bits14 => Some(0b11),
            DataWidth::Bits16 => None,
        }
    }
}

/// The pixels of whole words in the order the camera sent them, read in
/// place: two to a word (10 to 16 bits), first pixel in the low half, is
/// how `u16` pixels lie in little-endian memory, so the words already are
/// the pixels (unpacking them cost the STM32H743's camera path 2.27
/// instructions a pixel on Cortex-M4, the bench's `canary-12bit-dcmi`:
/// 15.93 against 13.66). `None` where they are not: 8-bit words (four
/// pixels each: [`unpack`]), a big-endian target.
pub fn as_pixels(width: DataWidth, words: &[u32]) -> Option<&[u16]> {
    if width.pixels_per_word() != 2 || cfg!(target_endian = "big") {
        return None;
    }
    // SAFETY: `words.len()` words are `2 words.len()` halfwords, aligned
    // (a word's alignment is a halfword's at least), any bits a u16; the
    // shared borrow lasts as long as `words`'.
    Some(unsafe { core::slice::from_raw_parts(words.as_ptr() as *const u16, 2 * words.len()) })
}

/// Unpacks whole words into pixels in the order the camera sent them:
/// `words.len() * pixels_per_word` pixels are written to the start of
/// `out`, and their count returned. `out` must be long enough.
pub fn unpack(width: DataWidth, words: &[u32], out: &mut [u16]) -> usize {
    match width {
        DataWidth::Bits8 => {
            let out = &mut out[..words.len() * 4];
            for (w, p) in words.iter().zip(out.chunks_exact_mut(4)) {
                let b = w.to_le_bytes();
                p[0] = b[0] as u16;
                p[1] = b[1] as u16;
                p[2] = b[2] as u16;
                p[3] = b[3] as u16;
            }
            out.len()
        }
        _ => {
            let out = &mut out[..words.len() * 2];
            for (w, p) in words.iter().zip(out.chunks_exact_mut(2)) {
                p[0] = *w as u16;
                p[1] = (*w >> 16) as u16;
            }
            out.len()
        }
    }
}

/// Packs pixels into words as the DCMI does (the inverse of [`unpack`]);
/// for simulations and tests. `pixels.len()` must be a multiple of the
/// pixels per word; returns the number of words written.
pub fn pack(width: DataWidth, pixels: &[u16], out: &mut [u32]) -> usize {
    let per_word = width.pixels_per_word();
    let n = pixels.len() / per_word;
    for (w, p) in out[..n].iter_mut().zip(pixels.chunks_exact(per_word)) {
        *w = match width {
            DataWidth::Bits8 => {
                u32::from_le_bytes([p[0] as u8, p[1] as u8, p[2] as u8, p[3] as u8])
            }
            _ => p[0] as u32 | (p[1] as u32) << 16,
        };
    }
    n
}
