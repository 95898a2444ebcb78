//! `prefilter::mask_at_least` (SSE2 on x86-64) against its portable twin,
//! and both against the definition, for every length up to 64 and floors
//! at the edges of the 16-bit range.

use brightpix_firmware::engine::prefilter::{mask_at_least, mask_at_least_portable};
use proptest::prelude::*;

fn definition(raw: &[u16], floor: u16) -> u64 {
    let mut mask = 0;
    for (k, &r) in raw.iter().enumerate() {
        if r >= floor {
            mask |= 1 << k;
        }
    }
    mask
}

#[test]
fn every_length_and_edge_floor() {
    for len in 0..=64usize {
        let raw: Vec<u16> = (0..len)
            .map(|k| [0, 1, 2, 0x7fff, 0x8000, 0x8001, 0xfffe, 0xffff][k % 8])
            .collect();
        for floor in [1, 2, 3, 0x7fff, 0x8000, 0x8001, 0xfffe, 0xffff] {
            let want = definition(&raw, floor);
            assert_eq!(mask_at_least(&raw, floor), want, "len {len} floor {floor}");
            assert_eq!(
                mask_at_least_portable(&raw, floor),
                want,
                "len {len} floor {floor}"
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]
    #[test]
    fn random(raw in prop::collection::vec(any::<u16>(), 0..=64), floor in 1..=u16::MAX) {
        let want = definition(&raw, floor);
        prop_assert_eq!(mask_at_least(&raw, floor), want);
        prop_assert_eq!(mask_at_least_portable(&raw, floor), want);
    }
}
