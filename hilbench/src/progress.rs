//! Progress on stderr for long runs: drawn only when asked (neither `--quiet` nor `--json`)
//! and when stderr is a terminal, so scripts and logs never see it.

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A line about progress on stderr: above the bar on a terminal, or on its own when stderr is
/// not a terminal (a log file, CI), so that a long run is never silent until it ends; nothing
/// when progress is not shown (`--quiet`, `--json`).
pub fn line(bar: &ProgressBar, show: bool, text: &str) {
    if !show {
        return;
    }
    if bar.is_hidden() {
        eprintln!("{text}");
    } else {
        bar.println(text);
    }
}

/// A progress bar of `len` steps of `unit` on stderr, or a hidden one (which prints nothing,
/// `println` included) unless `show` is set and stderr is a terminal.
pub fn bar(len: u64, unit: &str, show: bool) -> ProgressBar {
    if !show || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    let template = format!("{{spinner}} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} {unit}  {{msg}}");
    if let Ok(style) = ProgressStyle::with_template(&template) {
        bar.set_style(style);
    }
    bar.enable_steady_tick(Duration::from_millis(120));
    bar
}

/// [`bar`] with the rate and the time left: for a sweep's many short runs.
pub fn bar_with_eta(len: u64, unit: &str, show: bool) -> ProgressBar {
    let bar = bar(len, unit, show);
    let template = format!(
        "{{spinner}} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} {unit} ({{per_sec}}, {{eta}} left)  {{msg}}"
    );
    if let Ok(style) = ProgressStyle::with_template(&template) {
        bar.set_style(style);
    }
    bar
}

/// A rough duration for an estimate: `40 s`, `12 min`, `3.5 h`.
pub fn duration_text(seconds: f64) -> String {
    match seconds {
        s if !s.is_finite() => "an unknown time".into(),
        s if s < 90.0 => format!("{s:.0} s"),
        s if s < 90.0 * 60.0 => format!("{:.0} min", s / 60.0),
        s => format!("{:.1} h", s / 3600.0),
    }
}
