//! Import a measurement, look at it, fit it: what `hilbench trace import|stats|fit` do, in one
//! short program.
//!
//! ```sh
//! cargo run --release -p linkfit --example fit_trace -- ping linkfit/tests/data/ping-linux-loopback.txt
//! cargo run --release -p linkfit --example fit_trace -- trace link.csv     # a trace file as it is
//! ```

use linkfit::{FitOptions, Format, ImportOptions, StatsOptions, fit, import, trace_stats};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [format, file] = args.as_slice() else {
        return Err("usage: fit_trace ping|irtt|csv|trace FILE".into());
    };
    let text = std::fs::read_to_string(file)?;
    let trace = if format == "trace" {
        delay::parse_trace_file(&text)?
    } else {
        let imported = import(&text, &ImportOptions::new(format.parse::<Format>()?))?;
        eprintln!(
            "imported: {} entries, {} skipped, {} duplicates",
            imported.trace.delays_s.len(),
            imported.skipped,
            imported.duplicates
        );
        imported.trace
    };
    let stats =
        trace_stats(&trace.delays_s, &StatsOptions { threshold_s: Some(0.33), ..StatsOptions::default() })?;
    eprintln!("{}", serde_json::to_string_pretty(&stats)?);
    let started = std::time::Instant::now();
    let report =
        fit(&trace.delays_s, &FitOptions { rate_hz: trace.provenance.rate_hz, ..FitOptions::default() })?;
    eprintln!("fitted in {:.3} s", started.elapsed().as_secs_f64());
    for c in &report.candidates {
        eprintln!("{:>9}: AIC {:.1}, KS {:.4}, {:?}", c.kind().name(), c.aic, c.ks, c.params);
    }
    println!("{}\n{}", report.scenario_toml()?, report.sweep_toml()?);
    Ok(())
}
