//! `brightpix tune --criterion wfe`: the rule and N that minimise the
//! on-axis residual wavefront error of an end-to-end simulation
//! (`brightpix endtoend`) of the user's sensor and conditions. The run and
//! the files are the library's (`evaluation::tune::wfe`, `output::write_wfe`);
//! here, the progress bar and what is printed.

use super::{Setup, TuneArgs};
use crate::cli::endtoend::{print_written, start};
use crate::endtoend::Conditions;
use crate::evaluation::tune::{output, WfePlan};
use anyhow::Result;

pub(super) fn run(
    args: &TuneArgs,
    setup: &Setup,
    lines: &[String],
    conditions: &Conditions,
) -> Result<()> {
    let plan = WfePlan::new(&setup.config, &setup.prepared, conditions)?;
    let bar = start(&plan.e2e, &plan.options);
    let result = plan.run(&|n| bar.inc(n as u64))?;
    bar.finish_and_clear();
    let written = output::write_wfe(&args.out, &args.name, &result, lines)?;
    print_written(&written.endtoend);
    print!("{}", written.endtoend.summary);
    println!(
        "\ntuned (minimum residual WFE, matched reconstructor): {} N = {}: {:.1} ± {:.1} nm, Strehl {:.3} at {:.0} nm{}; N not resolved from it: {:?}",
        result.method.label(),
        result.pixels,
        result.wfe_nm.value,
        result.wfe_nm.se,
        result.strehl.value,
        result.science_wavelength_m * 1e9,
        result
            .wfe_all_pixels_nm
            .map_or(String::new(), |a| format!(" (all pixels: {a:.1} nm)")),
        result.not_resolved
    );
    if !result.dark.is_empty() {
        println!(
            "dark sub-apertures (lit below {}): windows {:?}, left out of the simulation and of the tuned configuration",
            result.illumination_threshold, result.dark
        );
    }
    eprintln!("brightpix: wrote {}", written.config.display());
    Ok(())
}
