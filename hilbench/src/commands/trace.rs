//! `hilbench trace import|stats|fit`: a real link's delays brought in (ping, irtt, a CSV
//! column; `record` and `echo` are in [`super::record`]), looked at, and fitted, as the `linkfit` crate does it (docs/links.md).

use std::path::{Path, PathBuf};

use anyhow::Context;
use linkfit::{FitOptions, Format, ImportOptions, StatsOptions, Unit};

use super::{Exit, Options};
use crate::cli::{TraceArgs, TraceCommand};
use crate::output::plots::trace::FittedLaw;

/// The largest trace file read, bytes (a million-line import is about 10 MB).
const MAX_FILE_BYTES: u64 = 512 << 20;

pub fn trace(args: TraceArgs, opts: &Options) -> anyhow::Result<Exit> {
    match args.command {
        TraceCommand::Import { file, format, out, column, unit, skip_bad, rate_hz } => {
            let format: Format = format.parse().map_err(|e: String| anyhow::anyhow!("--format: {e}"))?;
            let unit = unit
                .map(|u| u.parse::<Unit>().map_err(|e: String| anyhow::anyhow!("--unit: {e}")))
                .transpose()?;
            // The measurement is never overwritten by its own import.
            let same = |a: &Path, b: &Path| {
                a.canonicalize().ok().zip(b.canonicalize().ok()).is_some_and(|(a, b)| a == b)
            };
            anyhow::ensure!(
                !same(&file, &out),
                "--out {}: is the measurement being imported; name another file",
                out.display()
            );
            let options = ImportOptions { column, unit, skip_bad, rate_hz, ..ImportOptions::new(format) };
            let imported = linkfit::import(&read(&file)?, &options)
                .map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
            let text = delay::write_trace(&imported.trace.delays_s, &imported.trace.provenance)
                .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
            std::fs::write(&out, text).with_context(|| format!("cannot write {}", out.display()))?;
            if !opts.quiet {
                eprintln!(
                    "{}: {} entries ({} lost), {} bad line(s) skipped, {} duplicate(s) left out -> {}",
                    file.display(),
                    imported.trace.delays_s.len(),
                    imported.trace.losses(),
                    imported.skipped,
                    imported.duplicates,
                    out.display()
                );
                for s in &imported.skipped_first {
                    eprintln!("  skipped line {}: {}", s.line, s.reason);
                }
            }
            Ok(Exit::Success)
        }
        TraceCommand::Record { target, rate_hz, duration_s, out, out_directions, probe_bytes, timeout_s } => {
            let spec = super::record::RecordSpec {
                target,
                rate_hz,
                duration_s,
                out,
                out_directions,
                probe_bytes: probe_bytes as usize,
                timeout_s,
            };
            super::record::record(&spec, opts.quiet)
        }
        TraceCommand::Echo { listen } => super::record::echo(&listen, opts.quiet),
        TraceCommand::Stats { file, threshold_s, json, plot } => {
            let trace = read_trace(&file)?;
            let options = StatsOptions { threshold_s, ..StatsOptions::default() };
            let stats = linkfit::trace_stats(&trace.delays_s, &options)
                .map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
            if json {
                println!("{}", serde_json::to_string_pretty(&stats)?);
            } else if !opts.quiet {
                print_stats(&file, &stats);
            }
            if let Some(dir) = plot {
                let paths = crate::output::plots::trace::write(
                    &dir,
                    &stem(&file),
                    &title(&file),
                    &trace.delays_s,
                    &[],
                )?;
                if !opts.quiet {
                    paths.iter().for_each(|p| eprintln!("{}", p.display()));
                }
            }
            Ok(Exit::Success)
        }
        TraceCommand::Fit { file, seed, json, plot, widen } => {
            let trace = read_trace(&file)?;
            let options = FitOptions { seed, rate_hz: trace.provenance.rate_hz, ..FitOptions::default() };
            let report = linkfit::fit(&trace.delays_s, &options)
                .map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else if !opts.quiet {
                eprintln!(
                    "{}: {} entries, {} delivered; by AIC (KS distance beside):",
                    file.display(),
                    report.entries,
                    report.delivered
                );
                for c in &report.candidates {
                    let params: Vec<String> = c
                        .params
                        .iter()
                        .map(|p| format!("{} {} [{}, {}]", p.name, num(p.value), num(p.lower), num(p.upper)))
                        .collect();
                    eprintln!(
                        "  {:>9}: AIC {:.1}, KS {:.4}; {}",
                        c.kind().name(),
                        c.aic,
                        c.ks,
                        params.join(", ")
                    );
                }
            }
            if !json {
                println!("{}\n{}", report.scenario_toml()?, report.sweep_toml_widened(widen.unwrap_or(1.0))?);
            }
            if let Some(dir) = plot {
                let laws: Vec<(String, &linkfit::Model)> =
                    report.candidates.iter().map(|c| (c.kind().name().to_string(), &c.model)).collect();
                let pdfs: Vec<Box<dyn Fn(f64) -> f64>> = laws
                    .iter()
                    .map(|(_, m)| Box::new(move |x| m.pdf(x)) as Box<dyn Fn(f64) -> f64>)
                    .collect();
                let cdfs: Vec<Box<dyn Fn(f64) -> f64>> = laws
                    .iter()
                    .map(|(_, m)| Box::new(move |x| m.cdf(x)) as Box<dyn Fn(f64) -> f64>)
                    .collect();
                let fits: Vec<FittedLaw<'_>> = laws
                    .iter()
                    .zip(pdfs.iter().zip(&cdfs))
                    .map(|((label, _), (pdf, cdf))| FittedLaw {
                        label: label.clone(),
                        pdf: pdf.as_ref(),
                        cdf: cdf.as_ref(),
                    })
                    .collect();
                let paths = crate::output::plots::trace::write(
                    &dir,
                    &stem(&file),
                    &title(&file),
                    &trace.delays_s,
                    &fits,
                )?;
                if !opts.quiet {
                    paths.iter().for_each(|p| eprintln!("{}", p.display()));
                }
            }
            Ok(Exit::Success)
        }
    }
}

/// A regular file's text, at most [`MAX_FILE_BYTES`], named in every error (the bench's one
/// reader of user files, `hilbench_scenario_file::user_file::read_text`).
fn read(path: &Path) -> anyhow::Result<String> {
    Ok(hilbench_scenario_file::user_file::read_text(path, MAX_FILE_BYTES, "a trace or an import")?)
}

/// A trace file (`delay`'s format: losses and provenance included).
fn read_trace(path: &Path) -> anyhow::Result<delay::TraceFile> {
    delay::parse_trace_file(&read(path)?).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Four significant digits, in e-notation when small or large.
fn num(v: f64) -> String {
    if v != 0.0 && !(1e-2..1e4).contains(&v.abs()) { format!("{v:.3e}") } else { format!("{v:.4}") }
}

fn stem(file: &Path) -> String {
    format!("trace-{}", file.file_stem().map_or_else(|| "trace".into(), |s| s.to_string_lossy().to_string()))
}

fn title(file: &Path) -> String {
    PathBuf::from(file).display().to_string()
}

fn print_stats(file: &Path, s: &linkfit::TraceStats) {
    let ms = |v: f64| format!("{:.3} ms", v * 1e3);
    println!("{}", file.display());
    println!(
        "  entries {}, delivered {}, lost {} ({:.2} %)",
        s.count,
        s.delivered,
        s.losses,
        100.0 * s.loss_rate
    );
    println!(
        "  delay: mean {}, median {}, p90 {}, p99 {}, p99.9 {}, max {}",
        ms(s.mean_s),
        ms(s.median_s),
        ms(s.p90_s),
        ms(s.p99_s),
        ms(s.p999_s),
        ms(s.max_s)
    );
    if let (Some(t), Some(above), Some(late)) = (s.threshold_s, s.share_above, s.share_late_or_lost) {
        println!(
            "  above {}: {:.2} % of delays, {:.2} % of entries late or lost",
            ms(t),
            100.0 * above,
            100.0 * late
        );
    }
    match s.lag1_autocorrelation {
        Some(r) => println!("  lag-1 autocorrelation {r:.3}"),
        None => println!("  lag-1 autocorrelation: -"),
    }
    let b = &s.bursts;
    println!(
        "  spikes (above {} or lost): {} in {} runs, mean run {:.2} (independent: {:.2}), longest {}",
        ms(b.threshold_s),
        b.spikes,
        b.runs,
        b.mean_run,
        b.mean_run_if_independent,
        b.max_run
    );
}
