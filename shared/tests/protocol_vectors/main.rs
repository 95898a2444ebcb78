//! `shared/protocol-vectors.json`: one test vector for every message, every
//! variant of every enum in a message, and every error text, for other
//! implementations of PROTOCOL.md to test themselves against.
//!
//! This test rebuilds the file's content from the Rust types and fails on
//! any difference; `BRIGHTPIX_BLESS=1 cargo test -p brightpix-protocol
//! --test protocol_vectors` rewrites it (after a deliberate protocol change).
//! Each vector is checked both ways: the message encodes to the file's bytes,
//! and the file's frame decodes to the message.

use brightpix_protocol::wire::*;
use messages::{device_messages, host_messages};
use serde_json::{json, Value};

mod messages;

const FILE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/protocol-vectors.json");

fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn unhex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// `{"A": {"B": ...}}` → `A.B`: the variant path of a message's JSON.
fn name_of(value: &Value) -> String {
    let mut parts = Vec::new();
    let mut v = value;
    loop {
        match v {
            Value::Object(map) if map.len() == 1 => {
                let (k, inner) = map.iter().next().unwrap();
                if k.chars().next().is_some_and(char::is_uppercase) {
                    parts.push(k.clone());
                    v = inner;
                    continue;
                }
                break;
            }
            Value::Object(map) => {
                // A struct: follow its one enum-valued field, if any.
                let enums: Vec<&Value> = map
                    .values()
                    .filter(|x| {
                        matches!(x, Value::Object(m) if m.len() == 1
                            && m.keys().next().unwrap().chars().next().is_some_and(char::is_uppercase))
                    })
                    .collect();
                if enums.len() == 1 && parts.len() < 3 {
                    v = enums[0];
                    continue;
                }
                // A unit variant inside an error (`Frame { fault: "Stopped" }`).
                let units: Vec<&str> = map
                    .values()
                    .filter_map(|x| x.as_str())
                    .filter(|x| x.chars().next().is_some_and(char::is_uppercase))
                    .collect();
                if parts.first().map(String::as_str) == Some("Error") && units.len() == 1 {
                    parts.push(units[0].to_string());
                }
                break;
            }
            Value::String(s) if s.chars().next().is_some_and(char::is_uppercase) => {
                parts.push(s.clone());
                break;
            }
            _ => break,
        }
    }
    parts.join(".")
}

fn vector<M: serde::Serialize>(
    direction: &str,
    note: &str,
    message: &M,
    text: Option<String>,
) -> Value {
    let mut frame = vec![0u8; MAX_FRAME_LEN];
    let len = encode(message, &mut frame).unwrap().len();
    let frame = &frame[..len];
    let mut copy = frame[..len - 1].to_vec();
    let body = unstuff(&mut copy).unwrap().to_vec();
    let value = serde_json::to_value(message).unwrap();
    let mut v = json!({
        "direction": direction,
        "name": name_of(&value),
        "message": value,
        "body": hex(&body),
        "frame": hex(frame),
    });
    if !note.is_empty() {
        v["note"] = json!(note);
    }
    if let Some(text) = text {
        v["text"] = json!(text);
    }
    v
}

fn vectors() -> Value {
    let payload: Vec<u8> = vec![0x00, 0x00, 0x10, 0x00, 0x10, 0x00, 0x10, 0x00];
    let mut list = Vec::new();
    for (note, m) in host_messages(&payload) {
        list.push(vector("host", note, &m, None));
    }
    for (note, m) in device_messages() {
        let text = match &m {
            DeviceMessage::Error(e) => Some(e.to_string()),
            _ => None,
        };
        list.push(vector("device", note, &m, text));
    }
    json!({
        "about": "Test vectors of the brightpix wire protocol (shared/PROTOCOL.md). Each vector: \
                  the message as JSON (serde's externally tagged form: an enum variant is \
                  {\"Variant\": fields} or \"Variant\"; byte strings are arrays of numbers), its \
                  postcard body and its whole frame (COBS of body ++ CRC-32 LE, then 0x00), in hex; \
                  `text` is the device error's English text (Display). \
                  Checked by shared/tests/protocol_vectors/.",
        "protocol_version": PROTOCOL_VERSION,
        "schema_hash": format!("{SCHEMA_HASH:#018x}"),
        "limits": {
            "MAX_MESSAGE_LEN": MAX_MESSAGE_LEN,
            "MAX_FRAME_LEN": MAX_FRAME_LEN,
            "MAX_CHUNK_BYTES": MAX_CHUNK_BYTES,
            "MAX_PIXEL_BYTES": MAX_PIXEL_BYTES,
            "SLOPES_PER_MESSAGE": SLOPES_PER_MESSAGE,
            "MAX_BOARD_NAME_LEN": MAX_BOARD_NAME_LEN,
        },
        "vectors": list,
    })
}

#[test]
fn the_vectors_file_matches_the_protocol() {
    let expected = serde_json::to_string_pretty(&vectors()).unwrap() + "\n";
    if std::env::var_os("BRIGHTPIX_BLESS").is_some() {
        std::fs::write(FILE, &expected).unwrap();
    }
    let found = std::fs::read_to_string(FILE).unwrap_or_default();
    assert!(
        found == expected,
        "{FILE} is out of date with the protocol; if the change is deliberate, run \
         BRIGHTPIX_BLESS=1 cargo test -p brightpix-protocol --test protocol_vectors"
    );
}

/// The file's frames decode to its messages (what an independent decoder
/// would check), and its bodies are the frames' contents.
#[test]
fn every_vector_decodes_to_its_message() {
    let file: Value = serde_json::from_str(&std::fs::read_to_string(FILE).unwrap()).unwrap();
    let vectors = file["vectors"].as_array().unwrap();
    assert!(vectors.len() > 80, "{} vectors", vectors.len());
    for v in vectors {
        let mut frame = unhex(v["frame"].as_str().unwrap());
        assert_eq!(frame.pop(), Some(0), "{v}");
        let mut copy = frame.clone();
        assert_eq!(
            hex(unstuff(&mut copy).unwrap()),
            v["body"].as_str().unwrap()
        );
        let decoded = match v["direction"].as_str().unwrap() {
            "host" => serde_json::to_value(decode::<HostMessage>(&mut frame).unwrap()),
            _ => serde_json::to_value(decode::<DeviceMessage>(&mut frame).unwrap()),
        }
        .unwrap();
        assert_eq!(decoded, v["message"], "{}", v["name"]);
    }
    // Every variant of both message enums is there.
    let names: Vec<&str> = vectors
        .iter()
        .map(|v| v["name"].as_str().unwrap())
        .collect();
    for name in [
        "Hello",
        "ConfigBegin",
        "ConfigChunk",
        "ConfigCommit",
        "ConfigAbort",
        "StatusRequest",
        "ResetLevelFilters",
        "PixelRows",
        "Capture",
        "StopCapture",
        "Bench",
        "LinkTest",
        "HelloReply",
        "Ack",
        "Error",
        "Status",
        "Slopes",
        "FrameDone",
        "CaptureBegan",
        "EdgeRows",
        "BenchReport",
        "LinkFill",
    ] {
        assert!(
            names.iter().any(|n| n.split('.').next() == Some(name)),
            "no vector of {name}"
        );
    }
}

/// The project's independent Python implementation of PROTOCOL.md
/// (`firmware/boards/qemu/scripts/check_device.py`, standard library only)
/// decodes every device vector and encodes the Hello as the file says.
#[test]
fn the_python_client_agrees_with_the_vectors() {
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../firmware/boards/qemu/scripts/check_device.py"
    );
    let Ok(out) = std::process::Command::new("python3")
        .args([script, "--vectors"])
        .output()
    else {
        eprintln!("python3 is not installed: the Python client was not checked");
        return;
    };
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
