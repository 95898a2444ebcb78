//! Every message round-trips, fits the limits, and converts without loss.

use super::*;

#[test]
fn every_host_message_round_trips() {
    let payload: Vec<u8> = (0..MAX_CHUNK_BYTES.max(MAX_PIXEL_BYTES))
        .map(|i| (i % 256) as u8)
        .collect();
    for message in host_examples(&payload) {
        let mut buf = Vec::new();
        assert_eq!(round_trip(&message, &mut buf), message);
    }
}

#[test]
fn every_device_message_round_trips() {
    for message in device_examples() {
        let mut buf = Vec::new();
        assert_eq!(round_trip(&message, &mut buf), message);
    }
}

#[test]
fn largest_messages_fit_the_message_limit() {
    let payload = vec![0xFFu8; MAX_CHUNK_BYTES.max(MAX_PIXEL_BYTES)];
    let mut plain = vec![0u8; 4 * MAX_MESSAGE_LEN];
    for message in host_examples(&payload) {
        let len = postcard::to_slice(&message, &mut plain).unwrap().len();
        assert!(len <= MAX_MESSAGE_LEN, "{:?}: {len} bytes", message.kind());
    }
    for message in device_examples() {
        let len = postcard::to_slice(&message, &mut plain).unwrap().len();
        assert!(len <= MAX_MESSAGE_LEN, "{message:?}: {len} bytes");
    }
}

#[test]
fn config_errors_convert_without_loss() {
    let e = ConfigError::MemoryBudget {
        needed: 6400,
        available: 80,
        what: MemoryKind::SelectionEntries,
    };
    let fault = ConfigFault::from(e);
    assert_eq!(ConfigError::from(fault), e);
    assert_eq!(std::format!("{fault}"), std::format!("{e}"));
}
