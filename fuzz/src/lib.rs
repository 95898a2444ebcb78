//! The bodies of brightpix's fuzz targets, one function per target, each
//! taking arbitrary bytes. `fuzz/` runs them under libFuzzer (`cargo fuzz`,
//! nightly); `tests/replay.rs` runs the seed corpus and a few thousand
//! generated inputs through them on stable, in CI. A function returns
//! normally for every input: a panic, a hang or an abort is a finding.
//!
//! | target | what it feeds | the properties checked |
//! |---|---|---|
//! | [`wire_decoder`] | bytes as a link stream into `FrameReader`, every frame into both decoders | no panic; a decoded message re-encodes to a frame that decodes to the same message |
//! | [`device_loop`] | a configuration drawn from the first bytes, then the rest as link traffic (raw bytes and well-formed messages of every kind) into the firmware's device loop | no panic; every byte the device sends is a valid frame; afterwards a fresh session configures and streams a frame whose every result equals the reference's |
//! | [`toml_loader`] | bytes as a configuration file (with real side files beside it) | no panic; an accepted configuration validates and the engine accepts it |
//! | [`npy_reader`] | bytes as a `.npy` file, read as an array and as frames | no panic, no unbounded allocation |
//! | [`fits_reader`] | bytes as a FITS file, likewise | likewise |

pub mod device;
mod files;

pub use device::device_loop;
pub use files::{fits_reader, npy_reader, toml_loader};

use brightpix_protocol::wire::{
    decode, encode, hello_prefix, DeviceMessage, FrameReader, HostMessage, Received, MAX_FRAME_LEN,
};

/// The wire decoder: `data` as bytes arriving on a link.
pub fn wire_decoder(data: &[u8]) {
    let mut reader = FrameReader::new(vec![0u8; MAX_FRAME_LEN]);
    let mut rest = data;
    let mut out = vec![0u8; MAX_FRAME_LEN];
    while !rest.is_empty() {
        let n = reader.push(rest);
        rest = &rest[n..];
        while let Some(received) = reader.next_frame() {
            let Received::Frame(frame) = received else {
                continue;
            };
            let copy = frame.to_vec();
            let mut a = copy.clone();
            if let Ok(m) = decode::<HostMessage>(&mut a) {
                let len = encode(&m, &mut out)
                    .expect("a decoded message encodes")
                    .len();
                let mut again = out[..len - 1].to_vec();
                assert_eq!(decode::<HostMessage>(&mut again).unwrap(), m);
            }
            let mut b = copy.clone();
            if let Ok(m) = decode::<DeviceMessage>(&mut b) {
                let len = encode(&m, &mut out)
                    .expect("a decoded message encodes")
                    .len();
                let mut again = out[..len - 1].to_vec();
                assert_eq!(decode::<DeviceMessage>(&mut again).unwrap(), m);
            }
            let mut c = copy;
            let _ = hello_prefix(&mut c);
        }
    }
}

/// A byte source for the structured targets: reads fixed-width values from
/// the input, zeros once it runs out.
pub(crate) struct Bytes<'a>(pub &'a [u8]);

impl Bytes<'_> {
    pub fn u8(&mut self) -> u8 {
        match self.0.split_first() {
            Some((&b, rest)) => {
                self.0 = rest;
                b
            }
            None => 0,
        }
    }
    pub fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    pub fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }
    /// `0..n` (n > 0).
    pub fn below(&mut self, n: u32) -> u32 {
        (self.u16() as u32) % n.max(1)
    }
    pub fn take(&mut self, n: usize) -> &[u8] {
        let n = n.min(self.0.len());
        let (head, rest) = self.0.split_at(n);
        self.0 = rest;
        head
    }
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}
