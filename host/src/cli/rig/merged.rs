//! The arguments `rig stream` and `rig capture` share: whether the boards
//! are configured or only checked, and where the merged results go.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;

use crate::io::{check_result_outputs, write_results, Layout, Provenance, Results};
use crate::link::Client;
use crate::rig::{self, Rig};

#[derive(Args)]
pub(super) struct MergedArgs {
    /// Write the merged slopes, flux, validity and provenance (.npy set, FITS or CSV; NaN where a
    /// board gave nothing).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Slopes layout of --out.
    #[arg(long, value_enum, default_value_t = Layout::Pairs, requires = "out")]
    layout: Layout,
    /// The boards already run their parts: check their digests instead of uploading.
    #[arg(long)]
    no_configure: bool,
}

impl MergedArgs {
    /// Before any work: `--out` must not overwrite an input.
    pub fn check_out(&self, inputs: &[&Path]) -> Result<()> {
        if let Some(out) = &self.out {
            check_result_outputs(inputs, &[out])?;
        }
        Ok(())
    }

    /// Uploads each board's part, or with `--no-configure` checks that
    /// every board already runs it.
    pub fn configure(&self, rig: &Rig, clients: &mut [Client]) -> Result<()> {
        if self.no_configure {
            rig::check_configurations(rig, clients)?;
        } else {
            rig::configure(rig, clients)?;
        }
        Ok(())
    }

    /// Writes the merged results to `--out`, if given, with their
    /// provenance: `tool` made them from `frames_source`.
    pub fn write(
        &self,
        rig: &Rig,
        results: &Results,
        tool: &str,
        frames_source: String,
    ) -> Result<()> {
        let Some(out) = &self.out else {
            return Ok(());
        };
        let mut provenance = Provenance::of(tool, &rig.whole.view(), rig.config_file.as_deref());
        provenance.frames_source = Some(frames_source);
        provenance.rig = Some(rig.describe());
        write_results(out, results, &provenance, self.layout)?;
        eprintln!(
            "brightpix: {} holds {} merged frames (NaN where a board gave nothing)",
            out.display(),
            results.frames()
        );
        Ok(())
    }
}
