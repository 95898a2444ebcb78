//! The bench request (PROTOCOL.md §14).

use super::*;

/// A board's bench mode that scribbles over all the memory the device lends
/// it (the engine's, the staging slot's tables), as a real bench does.
struct ScribblingBench {
    runs: Vec<(usize, u32)>,
}

impl brightpix_firmware::device::BenchRunner for ScribblingBench {
    fn workloads(&self) -> usize {
        2
    }

    fn name(&self, index: usize) -> &'static str {
        ["first", "second"][index]
    }

    fn max_frames(&self) -> u32 {
        8
    }

    fn run(
        &mut self,
        index: usize,
        frames: u32,
        memory: brightpix_firmware::device::BenchMemory<'_>,
    ) -> brightpix_protocol::wire::BenchReport<'static> {
        use brightpix_protocol::wire::{BenchLimit, BenchReport, BenchResult, CountUnit};
        self.runs.push((index, frames));
        memory.windows.fill(SubapertureWindow {
            x: 9999,
            y: 9999,
            width: 1,
            height: 1,
        });
        memory.background.fill(i32::MIN);
        memory.gain.fill(0xABCD);
        memory.engine.order.fill(u16::MAX);
        memory.engine.free.fill(u16::MAX);
        memory.engine.history.fill(0x5555);
        memory.engine.scratch.fill(-7);
        BenchReport {
            workload: self.name(index),
            unit: CountUnit::Cycles,
            clock_hz: Some(400_000_000),
            pixels: 100,
            frames,
            result: BenchResult::DoesNotFit {
                limit: BenchLimit::Pixels,
            },
        }
    }
}

/// The bench request: refused (and nothing changes) while a frame is in
/// progress, while an upload is, for an unknown workload or too many
/// frames, and by a device without a bench mode; otherwise one report per
/// workload and `Ack(BenchDone)`. A bench that overwrote every byte lent to
/// it leaves the configuration and its digest as they were, and the next
/// frames verify as after a fresh configuration (the level filters start
/// again, as PROTOCOL.md §14 says).
#[test]
fn a_bench_is_refused_while_streaming_and_keeps_the_configuration() {
    use brightpix_protocol::wire::BenchFault;
    let owned = config_filtered();
    let config = owned.view();
    let frames = frames(CAMERA, 6, 21);
    let mut bench = ScribblingBench { runs: Vec::new() };
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    device.set_bench(&mut bench);
    host.hello();
    configure(&mut host, &mut device, config, 1);
    let before = status(&mut host, &mut device);
    let bench_request = |workload, frames| HostMessage::Bench { workload, frames };

    // A frame in progress: refused, and the frame completes as if nothing
    // had been asked.
    let expected = direct(config, &frames[..2]);
    host.frame(0, &frames[0], 480);
    host.frame_from(1, &frames[1][..500], 0, 100);
    host.send(&bench_request("all", 0));
    host.frame_from(1, &frames[1], 500, 100);
    // An upload in progress: refused.
    let b = config_b();
    let mut plan = UploadPlan::new(b.view(), 2, 64);
    let mut scratch = vec![0u8; MAX_CHUNK_BYTES];
    let begin = plan.next(&mut scratch).unwrap();
    host.send(&begin);
    host.send(&bench_request("all", 0));
    host.send(&HostMessage::ConfigAbort);
    // Unknown workload, too many frames.
    host.send(&bench_request("third", 0));
    host.send(&bench_request("first", 9));
    run(&mut device);
    let replies = host.replies();
    expect_verified(&replies, 0, &expected[0]);
    expect_verified(&replies, 1, &expected[1]);
    assert_eq!(
        errors(&replies),
        [
            DeviceError::Bench(BenchFault::Streaming),
            DeviceError::Bench(BenchFault::UploadInProgress),
            DeviceError::Bench(BenchFault::UnknownWorkload),
            DeviceError::Bench(BenchFault::TooManyFrames { max: 8 }),
        ]
    );
    assert!(replies.iter().all(|r| !matches!(r, Reply::Bench(_))));

    // Every workload, then one by name.
    host.send(&bench_request("all", 0));
    host.send(&bench_request("second", 5));
    host.send(&HostMessage::StatusRequest);
    run(&mut device);
    let replies = host.replies();
    let names: Vec<(&str, u32)> = replies
        .iter()
        .filter_map(|r| match r {
            Reply::Bench(row) => Some((row.workload.as_str(), row.frames)),
            _ => None,
        })
        .collect();
    assert_eq!(names, [("first", 0), ("second", 0), ("second", 5)]);
    assert_eq!(
        acks(&replies),
        [
            Ack::BenchDone { workloads: 2 },
            Ack::BenchDone { workloads: 1 }
        ]
    );
    let Some(Reply::Status(after)) = replies.last() else {
        panic!("{replies:?}")
    };
    assert_eq!(after.config_id, before.config_id);
    assert_eq!(after.config_digest, before.config_digest);
    assert_eq!(after.frames_dropped, before.frames_dropped);

    // Streaming goes on, from a fresh engine.
    let expected = direct(config, &frames[2..]);
    for (k, f) in frames[2..].iter().enumerate() {
        host.frame(10 + k as u32, f, 480);
    }
    run(&mut device);
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, 10 + k as u32, want);
    }
    drop(device);
    assert_eq!(bench.runs, [(0, 0), (1, 0), (1, 5)]);

    // A device without a bench mode says so.
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let mut device = Device::new(link, LinkOnly, storage.buffers(), "t");
    host.hello();
    host.send(&bench_request("all", 0));
    run(&mut device);
    assert_eq!(
        errors(&host.replies()),
        [DeviceError::Bench(BenchFault::NotSupported)]
    );
}
