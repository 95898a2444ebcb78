//! Random configurations and frames: the device against the engine.

use super::*;

fn sizes_for(config: &Config<'_>) -> Sizes {
    let n = config.windows.len();
    let engine = brightpix::engine_runner::EngineBuffers::needed(config).unwrap_or_default();
    Sizes {
        subapertures: n,
        map_pixels: config.camera.pixel_count(),
        open_windows: n,
        pool_entries: engine.pool_entries,
        history_pixels: engine.history_pixels,
        scratch_entries: engine.scratch_entries,
        results_per_row: n,
    }
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 256,
        max_shrink_iters: 500,
        ..ProptestConfig::default()
    })]

    /// Any configuration the differential tests generate, uploaded in
    /// chunks of any size and streamed in messages of any size, gives the
    /// engine's slopes.
    #[test]
    fn device_matches_the_engine_on_random_cases(
        (case, frames, chunks) in case(),
        chunk in 8usize..=960,
        max_read in 1usize..=300,
    ) {
        let config = case.view();
        let expected = direct(config, &frames);
        let (mut storage, mut host, link) = setup(sizes_for(&config), max_read);
        let mut device = Device::new(link, LinkOnly, storage.buffers(), "prop");
        host.hello();
        host.upload(config, 3, chunk);
        for (k, f) in frames.iter().enumerate() {
            host.frame(k as u32, f, chunks[k % chunks.len()]);
        }
        run(&mut device);
        let replies = host.replies();
        prop_assert_eq!(errors(&replies), []);
        for (k, want) in expected.iter().enumerate() {
            // Windows that end in the same camera row may come in another
            // order when pixels arrive in other chunks (the engine emits a
            // pushed run's windows by first column): compare by index.
            let (mut got, _, done) = slopes_of(&replies, k as u32);
            let mut want: Vec<SlopeEntry> = want.iter().map(entry).collect();
            got.sort_by_key(|e| e.index);
            want.sort_by_key(|e| e.index);
            prop_assert_eq!(&got, &want);
            prop_assert_eq!(done, Some(want.len() as u32));
        }
    }
}
