//! The configuration's header and its digest.

use super::*;

#[test]
fn largest_header_encoding_fits() {
    let mut out = [0u8; ConfigHeader::MAX_ENCODED_LEN];
    let encoded = header().encode(&mut out);
    let mut big = [0u8; 256];
    assert_eq!(encoded, &*postcard::to_slice(&header(), &mut big).unwrap());
    assert!(
        encoded.len() < ConfigHeader::MAX_ENCODED_LEN,
        "{}",
        encoded.len()
    );
}

#[test]
fn uniform_background_travels_as_one_value() {
    let camera = crate::Camera {
        width: 4,
        height: 2,
        bit_depth: 12,
    };
    let windows = [SubapertureWindow {
        x: 0,
        y: 0,
        width: 2,
        height: 2,
    }];
    let uniform = [-48i32; 8];
    let mut varied = uniform;
    varied[7] = 0;
    let config = |background: Option<&'static [i32]>| Config {
        camera,
        windows: &windows,
        calibration: Calibration {
            background,
            gain: None,
            threshold: None,
        },
        selection: Selection {
            rule: crate::SelectionRule::SubtractNext,
            count: PixelCount::All(2),
            level_filter: None,
        },
        centroid: Centroid {
            min_flux: 0,
            reference_slopes: None,
        },
        crop: None,
    };
    let uniform: &'static [i32] = std::vec![-48i32; 8].leak();
    let varied: &'static [i32] = varied.to_vec().leak();
    assert_eq!(ConfigHeader::of(&config(None)).background, Background::None);
    let constant = ConfigHeader::of(&config(Some(uniform)));
    assert_eq!(constant.background, Background::Constant(-48));
    assert_eq!(constant.table_elements(Table::Background), None);
    let map = ConfigHeader::of(&config(Some(varied)));
    assert_eq!(map.background, Background::Map);
    assert_eq!(map.table_elements(Table::Background), Some(8));
    // The digest tells the three apart although the tables are the same size.
    let digests = [
        config_digest(&config(None)),
        config_digest(&config(Some(uniform))),
        config_digest(&config(Some(varied))),
    ];
    assert_ne!(digests[0], digests[1]);
    assert_ne!(digests[1], digests[2]);
}
