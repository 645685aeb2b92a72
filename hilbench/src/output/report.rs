//! `report.md` in the output directory: the tables, the verdicts, where the time went, and the
//! plots and logs of every run, linked only when their files exist.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::Context;

use super::plots::{self, Kind, RunFacts};

/// What the report shows besides the runs.
#[derive(Debug, Clone, Copy)]
pub struct ReportText<'a> {
    /// First heading, e.g. "Paper reproduction".
    pub title: &'a str,
    /// One paragraph under it: mode, transport.
    pub header: &'a str,
    /// Preformatted tables (the paper's beside the measured values), if any.
    pub tables: Option<&'a str>,
    /// One sentence per claim, if any.
    pub verdicts: &'a [String],
}

/// Writes `dir/report.md` for `runs` and their `summary.json` (`transport`: `grpc` or
/// `in-process`); returns its path.
pub fn write(
    dir: &Path,
    text: &ReportText<'_>,
    runs: &[RunFacts],
    transport: &str,
    summary: &serde_json::Value,
) -> anyhow::Result<PathBuf> {
    let path = dir.join("report.md");
    std::fs::write(&path, render(dir, text, runs, transport, summary))
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

fn exists(dir: &Path, rel: &str) -> bool {
    dir.join(rel).is_file()
}

/// `![alt](plots/stem.png)` and a link to the SVG, for those of the two files that exist.
fn figure(dir: &Path, stem: &str, alt: &str) -> Option<String> {
    let png = format!("{}/{stem}.png", plots::PLOTS_DIR);
    let svg = format!("{}/{stem}.svg", plots::PLOTS_DIR);
    match (exists(dir, &png), exists(dir, &svg)) {
        (true, true) => Some(format!("![{alt}]({png})\n\n[{alt} (SVG)]({svg})\n")),
        (true, false) => Some(format!("![{alt}]({png})\n")),
        (false, true) => Some(format!("[{alt} (SVG)]({svg})\n")),
        (false, false) => None,
    }
}

fn secs(v: &serde_json::Value) -> String {
    v.as_f64().map_or_else(|| "-".to_string(), |s| format!("{s:.2} s"))
}

/// The text of `report.md` for the files in `dir`.
pub fn render(
    dir: &Path,
    text: &ReportText<'_>,
    runs: &[RunFacts],
    transport: &str,
    summary: &serde_json::Value,
) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# {}\n\n{}\n", text.title, text.header);
    if exists(dir, "summary.json") {
        let _ = writeln!(out, "All numbers: [summary.json](summary.json).\n");
    }

    let _ = writeln!(out, "## Runs\n");
    let _ = writeln!(
        out,
        "| scenario | controller | reached | time to goal [s] | path [m] | min clearance [m] | cycles | solve median [ms] | collided | per-cycle log |"
    );
    let _ = writeln!(out, "|---|---|---|---:|---:|---:|---:|---:|---|---|");
    for r in runs {
        let csv = format!("{}-{}.csv", r.scenario, r.controller);
        let log = if exists(dir, &csv) { format!("[{csv}]({csv})") } else { "-".to_string() };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {:.2} | {:+.3} | {} | {:.2} | {} | {log} |",
            r.scenario,
            r.controller,
            if r.reached { "yes" } else { "no" },
            r.time_to_goal_s.map_or_else(|| "-".to_string(), |t| format!("{t:.2}")),
            r.path_length_m,
            r.min_clearance_m,
            r.cycles,
            r.solve_ms_median,
            if r.collided { "**YES**" } else { "no" },
        );
    }
    let _ = writeln!(out);
    // What flew the runs (the simulated plant, or a vehicle and its firmware behind a gateway).
    let mut plants: Vec<&str> =
        summary["runs"].as_array().into_iter().flatten().filter_map(|r| r["plant"].as_str()).collect();
    plants.dedup();
    if !plants.is_empty() {
        let _ = writeln!(out, "Flown on: {}.\n", plants.join("; "));
    }
    // Commands the network dropped: a loss is an injected fault, counted where the runs are.
    let lost: Vec<String> = runs
        .iter()
        .filter_map(|r| {
            let n = r.commands_lost.filter(|n| *n > 0)?;
            Some(format!("{} {} {n} of {} commands", r.scenario, r.controller, r.cycles))
        })
        .collect();
    if !lost.is_empty() {
        let _ = writeln!(out, "Lost by the network (never applied): {}.\n", lost.join("; "));
    }
    // Every run that did not simply reach its goal with verified commands, explained.
    for r in runs.iter().filter(|r| r.collided || !r.reached || !r.explanation.is_empty()) {
        let what = if r.collided {
            "collided"
        } else if !r.reached {
            &format!("did not reach its goal ({})", r.end_reason.name().replace('_', " "))
        } else {
            "reached its goal, but"
        };
        let _ = writeln!(out, "{} with {} {what}:\n", r.scenario, r.controller);
        for line in r.collisions_described.iter().chain(&r.explanation) {
            let _ = writeln!(out, "- {line}");
        }
        let _ = writeln!(out);
    }
    if let Some(tables) = text.tables {
        let _ = writeln!(out, "```text\n{}```\n", tables);
    }
    if !text.verdicts.is_empty() {
        let _ = writeln!(out, "## What reproduces\n");
        for v in text.verdicts {
            let _ = writeln!(out, "- {v}");
        }
        let _ = writeln!(out);
    }

    let timing = &summary["timing"];
    let _ = writeln!(out, "## Where the time went\n");
    let _ = writeln!(out, "| component | wall time |");
    let _ = writeln!(out, "|---|---:|");
    let _ = writeln!(out, "| solver | {} |", secs(&timing["solver_s"]));
    if transport == "grpc" {
        let _ = writeln!(
            out,
            "| gRPC loop (round trips, netem, plant RK4, telemetry) | {} |",
            secs(&timing["loop_overhead_s"])
        );
        let _ = writeln!(out, "| starting the services | {} |", secs(&timing["setup_s"]));
        let _ = writeln!(out, "| stopping the services | {} |", secs(&timing["teardown_s"]));
    }
    let _ = writeln!(out, "| runs in all | {} |", secs(&timing["wall_time_s"]));
    let _ = writeln!(out, "| plotting | {} |", secs(&timing["plotting_s"]));
    let _ = writeln!(out);

    let mut scenarios: Vec<&str> = Vec::new();
    for r in runs {
        if !scenarios.contains(&r.scenario.as_str()) {
            scenarios.push(&r.scenario);
        }
    }
    let mut any_plot = false;
    for s in scenarios {
        let mut section = String::new();
        for kind in Kind::SCENARIO {
            if let Some(f) = figure(dir, &plots::stem(kind, s, None), &format!("{s}: {}", kind.describe())) {
                let _ = writeln!(section, "{f}");
            }
        }
        for r in runs.iter().filter(|r| r.scenario == s) {
            let mut run = String::new();
            for kind in Kind::RUN {
                let alt = format!("{s}, {}: {}", r.controller, kind.describe());
                if let Some(f) = figure(dir, &plots::stem(kind, s, Some(&r.controller)), &alt) {
                    let _ = writeln!(run, "{f}");
                }
            }
            if !run.is_empty() {
                let _ = writeln!(section, "### {s} with {}\n\n{run}", r.controller);
            }
        }
        if !section.is_empty() {
            any_plot = true;
            let _ = write!(out, "## {s}\n\n{section}");
        }
    }
    if !any_plot {
        let _ = writeln!(out, "No plots (`--no-plots`).");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(scenario: &str, controller: &str) -> RunFacts {
        let mut r = crate::output::plots::tests::facts(scenario, controller);
        r.reached = controller == "multistage";
        r.collided = controller == "nmpc";
        r.time_to_goal_s = r.reached.then_some(12.5);
        r.path_length_m = 6.18;
        r.min_clearance_m = -0.02;
        r.cycles = 70;
        r.solve_ms_median = 0.9;
        r.commands_lost = Some(if r.collided { 2 } else { 0 });
        if r.collided {
            let ground = mpc::record::CollisionSummary {
                kind: "ground".into(),
                obstacle_index: None,
                time_s: 4.25,
                position_m: [1.0, 2.0, -0.02],
                depth_m: 0.02,
            };
            r.collisions_described = vec![ground.describe()];
            r.end_reason = mpc::RunEnd::Collided;
            r.explanation = vec!["3 of 70 cycles sent a command that failed the safety check".to_string()];
        }
        r
    }

    #[test]
    fn report_links_the_plots_and_logs_that_exist_and_no_others() {
        let dir = crate::output::plots::tests::temp_dir("report-md");
        let plots_dir = dir.join(plots::PLOTS_DIR);
        std::fs::create_dir_all(&plots_dir).expect("plots dir");
        let top = plots::stem(Kind::Top, "paper-2", None);
        let inputs = plots::stem(Kind::Inputs, "paper-2", Some("nmpc"));
        for f in [format!("{top}.png"), format!("{top}.svg"), format!("{inputs}.png")] {
            std::fs::write(plots_dir.join(f), b"x").expect("write");
        }
        std::fs::write(dir.join("paper-2-nmpc.csv"), b"x").expect("write");
        std::fs::write(dir.join("summary.json"), b"{}").expect("write");
        let runs = vec![run("paper-2", "nmpc"), run("paper-2", "multistage")];
        let summary = serde_json::json!({
            "timing": { "wall_time_s": 1.5, "solver_s": 0.5, "plotting_s": 0.25 }
        });
        let verdicts = vec!["paper-2 holds.".to_string()];
        let text = ReportText {
            title: "Paper reproduction",
            header: "lockstep",
            tables: Some("T\n"),
            verdicts: &verdicts,
        };
        let path = write(&dir, &text, &runs, "in-process", &summary).expect("report.md");
        let md = std::fs::read_to_string(path).expect("read");
        assert!(md.starts_with("# Paper reproduction"));
        assert!(md.contains(&format!("![paper-2: paths seen from above](plots/{top}.png)")), "{md}");
        assert!(md.contains(&format!("(plots/{top}.svg)")));
        assert!(md.contains(&format!("(plots/{inputs}.png)")));
        assert!(!md.contains(&format!("plots/{inputs}.svg")), "links a missing SVG");
        assert!(!md.contains("paths-3d"), "links a missing 3D view");
        assert!(!md.contains("multistage-inputs"), "links missing run plots");
        assert!(md.contains("[paper-2-nmpc.csv](paper-2-nmpc.csv)"));
        assert!(!md.contains("(paper-2-multistage.csv)"), "links a missing log");
        assert!(md.contains("[summary.json](summary.json)"));
        assert!(md.contains("| paper-2 | nmpc | no | - | 6.18 | -0.020 | 70 | 0.90 | **YES** |"), "{md}");
        assert!(md.contains("Lost by the network (never applied): paper-2 nmpc 2 of 70 commands.\n"), "{md}");
        assert!(
            md.contains(
                "paper-2 with nmpc collided:\n\n- ground, 20.0 mm deep, at 4.25 s, at [1.00, 2.00, -0.02] m"
            ),
            "the report names the collision's kind, depth, time and place: {md}"
        );
        assert!(
            md.contains(
                "at [1.00, 2.00, -0.02] m\n- 3 of 70 cycles sent a command that failed the safety check\n"
            ),
            "the report explains the run: {md}"
        );
        assert!(md.contains("- paper-2 holds."));
        assert!(md.contains("| plotting | 0.25 s |"), "{md}");
        assert!(!md.contains("gRPC loop"), "in-process runs have no gRPC rows");
        assert!(md.contains("```text\nT\n```"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
