//! Runs the firmware's streaming engine on the host: heap-backed engine memory
//! sized for a configuration, and frame-at-a-time processing into results in
//! sub-aperture order. The same engine code runs on the boards.
//!
//! [`HostEngine`] runs on one core; [`crate::parallel::ParallelEngine`] runs
//! a batch of frames on all cores with bit-identical results.

use brightpix_firmware::engine::select::Entry;
use brightpix_firmware::engine::{
    Engine, EngineMemory, FrameError, MemorySize, OpenWindow, OutputSink, SubapertureResult,
    SubapertureState,
};
use brightpix_protocol::{Config, ConfigError};

/// Engine memory on the host heap, exactly as large as a configuration
/// needs (or as a device's budget, for a simulated device).
pub struct EngineBuffers {
    order: Vec<u16>,
    subapertures: Vec<SubapertureState>,
    open: Vec<OpenWindow>,
    free: Vec<u16>,
    entries: Vec<Entry>,
    history: Vec<u16>,
    scratch: Vec<i32>,
    rescan: Vec<Entry>,
}

impl EngineBuffers {
    /// The memory `config` needs; `config` must be valid
    /// ([`Config::validate`]).
    pub fn for_config(config: &Config<'_>) -> Self {
        Self::with_capacity(Self::needed(config).unwrap_or_default())
    }

    /// What the engine needs for `config` (the engine's own planning, with
    /// unlimited memory).
    pub fn needed(config: &Config<'_>) -> Result<MemorySize, ConfigError> {
        let count = config.windows.len();
        let unlimited = MemorySize {
            subapertures: usize::MAX,
            open_windows: usize::MAX,
            pool_entries: usize::MAX,
            history_pixels: usize::MAX,
            scratch_entries: usize::MAX,
        };
        Engine::check(config, unlimited, &mut vec![0; count], &mut vec![0; count])
    }

    /// Memory of the given sizes (see the engine's `memory` module).
    pub fn with_capacity(size: MemorySize) -> Self {
        EngineBuffers {
            order: vec![0; size.subapertures],
            subapertures: vec![SubapertureState::RESET; size.subapertures],
            // One more: the row kernel's end mark.
            open: vec![OpenWindow::CLOSED; size.open_windows + 1],
            free: vec![0; size.open_windows],
            entries: vec![Entry::ZERO; size.pool_entries],
            history: vec![0; size.history_pixels],
            scratch: vec![0; size.scratch_entries],
            rescan: vec![Entry::ZERO; size.scratch_entries],
        }
    }

    /// An engine for `config` on this memory that keeps the level-filter
    /// state already in it (SPEC.md §4): for a caller that runs batch after
    /// batch of one configuration. `config` must be the one the buffers were
    /// sized and first used for.
    pub fn resume<'c>(&mut self, config: Config<'c>) -> Result<Engine<'c, '_>, ConfigError> {
        Engine::resume(config, self.memory())
    }

    /// An engine for `config` on this memory with fresh level-filter state.
    pub fn start<'c>(&mut self, config: Config<'c>) -> Result<Engine<'c, '_>, ConfigError> {
        Engine::new(config, self.memory())
    }

    /// Forgets the filtered levels (SPEC.md §4) kept in this memory, and
    /// the seeds.
    pub fn reset_level_filters(&mut self) {
        self.subapertures.fill(SubapertureState::RESET);
    }

    pub fn memory(&mut self) -> EngineMemory<'_> {
        EngineMemory {
            order: &mut self.order,
            subapertures: &mut self.subapertures,
            open: &mut self.open,
            free: &mut self.free,
            entries: &mut self.entries,
            history: &mut self.history,
            scratch: &mut self.scratch,
            rescan: &mut self.rescan,
        }
    }
}

/// Results of one frame, indexed by sub-aperture.
pub type FrameResults = Vec<SubapertureResult>;

/// Collects a frame's results by sub-aperture index.
struct Collector {
    results: Vec<Option<SubapertureResult>>,
    completed: Vec<FrameResults>,
}

impl OutputSink for Collector {
    fn subaperture(&mut self, result: SubapertureResult) {
        self.results[result.index as usize] = Some(result);
    }
    fn frame_complete(&mut self, _frame: u32) {
        let frame = self
            .results
            .iter_mut()
            .map(|r| {
                r.take()
                    .expect("the engine emits every sub-aperture once per frame")
            })
            .collect();
        self.completed.push(frame);
    }
}

/// A host-side engine session: configure once, push frames. The level
/// filter state (SPEC.md §4) carries over between calls.
pub struct HostEngine<'c> {
    config: Config<'c>,
    buffers: EngineBuffers,
}

impl<'c> HostEngine<'c> {
    pub fn new(config: Config<'c>) -> Result<Self, ConfigError> {
        config.validate()?;
        let mut buffers = EngineBuffers::for_config(&config);
        buffers.start(config)?;
        Ok(HostEngine { config, buffers })
    }

    /// Processes whole frames, feeding each in chunks of `chunk` pixels (any
    /// size: the result must not depend on it).
    pub fn process<'f>(
        &mut self,
        frames: impl IntoIterator<Item = &'f [u16]>,
        chunk: usize,
    ) -> Result<Vec<FrameResults>, (usize, FrameError)> {
        let mut chunks = std::iter::repeat(chunk.max(1));
        self.process_chunked(frames, &mut chunks)
    }

    /// As [`process`](Self::process), with chunk lengths drawn from `chunks`.
    /// On a frame error, returns the frame's position in `frames` and the
    /// error; results of earlier frames are dropped with it.
    pub fn process_chunked<'f>(
        &mut self,
        frames: impl IntoIterator<Item = &'f [u16]>,
        chunks: &mut dyn Iterator<Item = usize>,
    ) -> Result<Vec<FrameResults>, (usize, FrameError)> {
        let mut engine = self
            .buffers
            .resume(self.config)
            .expect("configuration was validated when the session was made");
        let mut sink = Collector {
            results: vec![None; self.config.windows.len()],
            completed: Vec::new(),
        };
        for (index, frame) in frames.into_iter().enumerate() {
            let mut rest = frame;
            while !rest.is_empty() {
                let take = chunks.next().unwrap_or(rest.len()).clamp(1, rest.len());
                let (chunk, tail) = rest.split_at(take);
                engine.push(chunk, &mut sink).map_err(|e| (index, e))?;
                rest = tail;
            }
        }
        Ok(sink.completed)
    }
}
