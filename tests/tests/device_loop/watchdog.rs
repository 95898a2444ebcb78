//! The device loop feeds its watchdog.

use super::*;

/// A watchdog that is due at every other poll, counting its feeds.
struct CountingWatchdog {
    feeds: Rc<RefCell<u32>>,
    ready: bool,
}

impl brightpix_firmware::device::Watchdog for CountingWatchdog {
    fn timeout_ms(&self) -> Option<u32> {
        Some(1000)
    }
    fn feed(&mut self) {
        *self.feeds.borrow_mut() += 1;
    }
    async fn due(&mut self) {
        std::future::poll_fn(|cx| {
            self.ready = !self.ready;
            if self.ready {
                Poll::Ready(())
            } else {
                cx.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await
    }
}

/// A link whose writes wait a while (a host that reads slowly).
struct SlowLink {
    inner: Link,
    stalls: Rc<RefCell<u32>>,
}

impl ErrorType for SlowLink {
    type Error = Infallible;
}

impl Read for SlowLink {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        self.inner.read(buf).await
    }
}

impl brightpix_firmware::device::embedded_io_async::Write for SlowLink {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        let mut waits = 3;
        std::future::poll_fn(|cx| {
            if waits == 0 {
                Poll::Ready(())
            } else {
                waits -= 1;
                *self.stalls.borrow_mut() += 1;
                cx.waker().wake_by_ref();
                Poll::Pending
            }
        })
        .await;
        self.inner.write(buf).await
    }
    async fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

/// The loop feeds its watchdog as it works and while a slow host makes it
/// wait, and `Status` reports the watchdog and the reset reason.
#[test]
fn the_device_loop_feeds_its_watchdog() {
    let a = config_a();
    let frames = frames(CAMERA, 2, 31);
    let expected = direct(a.view(), &frames);
    let (mut storage, mut host, link) = setup(SIZES, 64);
    let feeds = Rc::new(RefCell::new(0));
    let stalls = Rc::new(RefCell::new(0));
    let slow = SlowLink {
        inner: link,
        stalls: stalls.clone(),
    };
    let mut device =
        Device::new(slow, LinkOnly, storage.buffers(), "t").with_watchdog(CountingWatchdog {
            feeds: feeds.clone(),
            ready: false,
        });
    device.set_reset_reason(ResetReason::Watchdog);
    host.hello();
    host.upload(a.view(), 1, MAX_CHUNK_BYTES);
    for (k, f) in frames.iter().enumerate() {
        host.frame(k as u32, f, 480);
    }
    host.send(&HostMessage::StatusRequest);
    match block_on(device.run()) {
        Err(LinkError::Closed) => {}
        other => panic!("device stopped with {other:?}"),
    }
    let replies = host.replies();
    assert_eq!(errors(&replies), []);
    for (k, want) in expected.iter().enumerate() {
        expect_verified(&replies, k as u32, want);
    }
    let Some(Reply::Status(s)) = replies.last() else {
        panic!("{replies:?}")
    };
    assert_eq!(
        (s.watchdog_ms, s.reset_reason),
        (Some(1000), ResetReason::Watchdog)
    );
    // Every write stalled 3 polls, and the watchdog was due at every other
    // poll: it was fed during the waits as well as once per pass.
    let (feeds, stalls) = (*feeds.borrow(), *stalls.borrow());
    let messages = replies.len() as u32;
    assert!(
        stalls >= 3 * messages,
        "{stalls} stalls for {messages} messages"
    );
    assert!(feeds >= messages, "{feeds} feeds for {messages} messages");
}
