//! Progress with rate and ETA on stderr (indicatif), hidden when stderr is
//! not a terminal (logs and tests stay clean).

use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

pub(crate) struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// A bar of `total` `unit`s (0: a spinner with a count and rate).
    pub(crate) fn new(total: u64, unit: &str) -> Self {
        let bar = if total > 0 {
            ProgressBar::new(total)
        } else {
            ProgressBar::new_spinner()
        };
        bar.set_draw_target(ProgressDrawTarget::stderr_with_hz(4));
        let template = if total > 0 {
            format!("{{bar:30}} {{pos}}/{{len}} {unit} {{per_sec}} ETA {{eta}}")
        } else {
            format!("{{spinner}} {{pos}} {unit} {{per_sec}}")
        };
        if let Ok(style) = ProgressStyle::with_template(&template) {
            bar.set_style(style);
        }
        bar.enable_steady_tick(Duration::from_millis(250));
        Progress { bar }
    }

    pub(crate) fn inc(&self, n: u64) {
        self.bar.inc(n);
    }

    pub(crate) fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}
