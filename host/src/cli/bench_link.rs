//! `brightpix bench --port PORT --link`: the device's link to the host,
//! timed (PROTOCOL.md §15). The device sends fill bytes as fast as its
//! link takes them; the rate is what its results can use, and what `rig
//! plan --link-rate` takes.

use std::path::Path;

use anyhow::{bail, Context, Result};
use brightpix_protocol::wire::{MAX_LINK_FILL, MAX_LINK_TEST_BYTES};
use serde_json::json;

use crate::link::{Client, LinkTestReport};
use crate::rig::USB_FULL_SPEED;

/// What `bench --port --link` was asked.
pub struct LinkBench<'a> {
    pub port: &'a str,
    pub bytes: u32,
    pub chunk: u16,
    pub json: Option<&'a Path>,
}

/// Checks the request, runs the test, prints what it measured (and writes
/// the JSON).
pub fn run(request: &LinkBench<'_>) -> Result<LinkTestReport> {
    if request.bytes == 0 || request.bytes > MAX_LINK_TEST_BYTES {
        bail!(
            "--link-bytes {}: 1 to {MAX_LINK_TEST_BYTES} fill bytes",
            request.bytes
        );
    }
    if request.chunk == 0 || request.chunk > MAX_LINK_FILL {
        bail!(
            "--link-chunk {}: 1 to {MAX_LINK_FILL} fill bytes a message",
            request.chunk
        );
    }
    let mut client = Client::open(request.port)?;
    let board = client.info().board.clone();
    eprintln!(
        "brightpix bench: the link of {board} on {}: {} fill bytes, {} a message...",
        request.port, request.bytes, request.chunk
    );
    let report = client
        .link_test(request.bytes, request.chunk)
        .with_context(|| format!("the link test on {}", request.port))?;
    print!("{}", describe(&board, request.port, &report));
    if let Some(path) = request.json {
        let value = json!({
            "board": board,
            "port": request.port,
            "link_test": {
                "bytes": report.bytes,
                "chunk": report.chunk,
                "messages": report.messages,
                "link_bytes": report.link_bytes,
                "seconds": report.span.as_secs_f64(),
                "link_mb_per_s": report.link_bytes_per_s.map(|r| r / 1e6),
                "fill_mb_per_s": report.fill_bytes_per_s.map(|r| r / 1e6),
            },
        });
        std::fs::write(path, serde_json::to_string_pretty(&value)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("brightpix bench: wrote {}", path.display());
    }
    Ok(report)
}

/// The report as the command prints it.
pub fn describe(board: &str, port: &str, r: &LinkTestReport) -> String {
    let mut out = format!(
        "link test of {board} on {port}: {} fill bytes in {} messages of up to {} bytes, intact and in order\n",
        r.bytes, r.messages, r.chunk
    );
    match (r.link_bytes_per_s, r.fill_bytes_per_s) {
        (Some(link), Some(fill)) => {
            out.push_str(&format!(
                "  device -> host: {:.3} MB/s on the link ({} bytes framed: COBS, CRC and delimiters), {:.3} MB/s of fill, over {:.2} s\n",
                link / 1e6,
                r.link_bytes,
                fill / 1e6,
                r.span.as_secs_f64()
            ));
            out.push_str(&format!(
                "  a board's results take this link: `brightpix rig plan --link-rate {:.3}` plans with it (without it, an STM32H743 is taken at about {:.1} MB/s, {})\n",
                link / 1e6,
                USB_FULL_SPEED.bytes_per_s / 1e6,
                USB_FULL_SPEED.name
            ));
        }
        _ => out.push_str(&format!(
            "  it all arrived within {:.0} ms, too quickly to time: ask for more (--link-bytes)\n",
            r.span.as_secs_f64() * 1e3
        )),
    }
    out
}
