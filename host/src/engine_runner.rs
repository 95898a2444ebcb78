//! Runs the firmware's streaming engine on the host: heap-backed engine memory
//! sized for a configuration, and frame-at-a-time processing into results in
//! sub-aperture order. The same engine code runs on the boards.
//!
//! [`HostEngine`] runs on one core; [`crate::parallel::ParallelEngine`] runs
//! a batch of frames on all cores with bit-identical results.

use brightpix_firmware::engine::select::{below_capacity, heap_capacity};
use brightpix_firmware::engine::{
    Engine, EngineMemory, FrameError, LevelFilterState, OpenWindow, OutputSink, SubapertureResult,
};
use brightpix_protocol::{Config, ConfigError};

/// Engine memory on the host heap, big enough for any layout of a
/// configuration's windows (every window open at once).
pub struct EngineBuffers {
    order: Vec<u16>,
    level_filters: Vec<LevelFilterState>,
    open: Vec<OpenWindow>,
    active: Vec<u16>,
    free: Vec<u16>,
    values: Vec<i32>,
    positions: Vec<u16>,
}

impl EngineBuffers {
    /// `config` must be valid ([`Config::validate`]).
    pub fn for_config(config: &Config<'_>) -> Self {
        let count = config.windows.len();
        let stride = (0..count)
            .map(|k| {
                let c = heap_capacity(
                    config.selection.rule,
                    config.pixel_count(k),
                    config.windows[k].pixel_count(),
                );
                c as usize + below_capacity(config.selection.rule, c) as usize
            })
            .max()
            .unwrap_or(0);
        Self::with_capacity(count, count, count * stride)
    }

    /// Memory for `subapertures`, `open_windows` open at once and
    /// `pool_entries` selection entries (see the engine's `memory` module).
    pub fn with_capacity(subapertures: usize, open_windows: usize, pool_entries: usize) -> Self {
        EngineBuffers {
            order: vec![0; subapertures],
            level_filters: vec![LevelFilterState::RESET; subapertures],
            open: vec![OpenWindow::CLOSED; open_windows],
            active: vec![0; open_windows],
            free: vec![0; open_windows],
            values: vec![0; pool_entries],
            positions: vec![0; pool_entries],
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

    /// Forgets the filtered levels (SPEC.md §4) kept in this memory.
    pub fn reset_level_filters(&mut self) {
        self.level_filters.fill(LevelFilterState::RESET);
    }

    pub fn memory(&mut self) -> EngineMemory<'_> {
        EngineMemory {
            order: &mut self.order,
            level_filters: &mut self.level_filters,
            open: &mut self.open,
            active: &mut self.active,
            free: &mut self.free,
            values: &mut self.values,
            positions: &mut self.positions,
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
