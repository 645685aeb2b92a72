//! What the commands print on the terminal: the table of a command's runs, where the time
//! went, the files written, a sweep's counts.

use mpc::RunSummary;

/// A scenario's network in a few words, as a run's header gives it: each direction's kind (a
/// trace by its file, a regime by its states), its loss, and the seed its draws come from.
pub fn delays_text(scenario: &mav::Scenario) -> String {
    fn one(t: &delay::DelaysTable, on: &str) -> String {
        let mut text = match (t.kind.as_deref().unwrap_or("none"), &t.file) {
            ("none", _) => "no delay".to_string(),
            ("trace", Some(file)) => format!("trace {file}"),
            ("trace", None) => format!("a trace of {} delays", t.delays_s.as_ref().map_or(0, Vec::len)),
            ("regime", _) => format!("a regime of {} states", t.states.as_ref().map_or(0, Vec::len)),
            (kind, _) => kind.to_string(),
        };
        text.push_str(&format!(" on {on}"));
        if let Some(p) = t.loss_probability.filter(|p| *p > 0.0) {
            text.push_str(&format!(" (loss {p})"));
        }
        text
    }
    let Some(table) = &scenario.delays else { return "no delays".to_string() };
    let text = match (&table.to_plant, &table.to_controller) {
        (None, None) => one(table, "commands"),
        (to_plant, to_controller) => {
            let parts = [
                to_plant.as_deref().map(|t| one(t, "commands")),
                to_controller.as_deref().map(|t| one(t, "samples")),
            ];
            parts.into_iter().flatten().collect::<Vec<_>>().join(", ")
        }
    };
    format!("delays: {text}, seed {}", scenario.seed)
}

/// A short table of the runs of one scenario file.
pub fn run_table(runs: &[RunSummary]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<16} {:<11} {:>8} {:>9} {:>9} {:>12} {:>7} {:>9} {:>9}",
        "scenario",
        "controller",
        "reached",
        "time [s]",
        "path [m]",
        "clearance",
        "cycles",
        "solve ms",
        "collided"
    );
    // A number that does not exist prints as "-": no goal reached (time), no obstacle
    // (clearance +inf), no solver the bench can see (an external controller's solve time).
    let finite = |v: f64, text: String| if v.is_finite() { text } else { "-".to_string() };
    for r in runs {
        let time = r.time_to_goal_s.map_or_else(|| "-".to_string(), |t| format!("{t:.2}"));
        let _ = writeln!(
            out,
            "{:<16} {:<11} {:>8} {:>9} {:>9.2} {:>12} {:>7} {:>9} {:>9}",
            r.scenario,
            r.controller,
            if r.reached { "yes" } else { "no" },
            time,
            r.path_length_m,
            finite(r.min_clearance_m, format!("{:+}", mpc::record::Millimetres(r.min_clearance_m))),
            r.cycles,
            finite(r.solve_ms_median, format!("{:.2}", r.solve_ms_median)),
            if r.collided { "YES" } else { "no" },
        );
    }
    for r in runs.iter().filter(|r| r.collided) {
        let _ = writeln!(out, "  {} {} collided: {}", r.scenario, r.controller, r.collisions_text());
    }
    for r in runs {
        for line in &r.explanation {
            let _ = writeln!(out, "  {} {}: {line}", r.scenario, r.controller);
        }
    }
    out
}

/// Where the wall time went: the runs (solver, gRPC, services), the plots, and the command.
pub fn print_time(summary: &serde_json::Value, plots: bool, mcap: bool, started: std::time::Instant) {
    let timing = &summary["timing"];
    let secs = |key: &str| timing[key].as_f64().map_or_else(|| "-".to_string(), |s| format!("{s:.2} s"));
    let runs = if summary["transport"] == "grpc" {
        format!(
            "runs {} (solver {}, gRPC loop: round trips, netem, plant RK4, telemetry {}, service start {}, stop {})",
            secs("wall_time_s"),
            secs("solver_s"),
            secs("loop_overhead_s"),
            secs("setup_s"),
            secs("teardown_s"),
        )
    } else if summary["transport"] == "external" {
        // The bench sees the user's controller's commands, not its solver.
        format!("runs {} (the external controller's solve time is its own, not seen)", secs("wall_time_s"))
    } else {
        format!("runs {} (solver {})", secs("wall_time_s"), secs("solver_s"))
    };
    let plots = if plots { format!(", plotting {}", secs("plotting_s")) } else { String::new() };
    let mcap = if mcap { format!(", MCAP files {}", secs("mcap_s")) } else { String::new() };
    println!("Time: {:.2} s wall in all; {runs}{plots}{mcap}", started.elapsed().as_secs_f64());
}

/// The files a command wrote.
pub fn print_outputs(dir: &std::path::Path) {
    println!("Report: {}", dir.join("report.md").display());
    println!("Summary: {}", dir.join("summary.json").display());
}

/// A sweep's numbers by controller: `sweep.json` itself for a sweep of one controller (the
/// name `None`), else each controller's entry of `by_controller`, in the order it flew. A
/// sweep of several controllers is never reported pooled: runs of different controllers are
/// different experiments.
pub fn sweep_sections(v: &serde_json::Value) -> Vec<(Option<&str>, &serde_json::Value)> {
    let names: Vec<&str> =
        v["controllers"].as_array().into_iter().flatten().filter_map(|c| c.as_str()).collect();
    match v["by_controller"].as_object() {
        Some(by) if names.len() > 1 => {
            names.into_iter().filter_map(|c| by.get(c).map(|a| (Some(c), a))).collect()
        }
        _ => vec![(None, v)],
    }
}

/// The number of runs of a sweep, each flown by every controller (`sweep.json`'s `runs` counts
/// the (run, controller) pairs).
pub fn sweep_runs(v: &serde_json::Value) -> u64 {
    let flights = v["runs"].as_u64().unwrap_or(0);
    match sweep_sections(v).first() {
        Some((Some(_), a)) => a["runs"].as_u64().unwrap_or(flights),
        _ => flights,
    }
}

/// The counts of `a` (an entry of [`sweep_sections`]) in words.
fn sweep_counts(a: &serde_json::Value) -> String {
    format!(
        "{} reached, {} collided ({} with the ground), {} missed, {}{} errors",
        a["reached"],
        a["collided"],
        a["collided_ground"],
        a["missed"],
        aborted_text(a),
        a["errors"]
    )
}

/// "N aborted, " when the controller stopped some runs (a failure of it), else nothing.
pub fn aborted_text(a: &serde_json::Value) -> String {
    match a["aborted"].as_u64() {
        Some(n) if n > 0 => format!("{n} aborted (the controller stopped), "),
        _ => String::new(),
    }
}

/// The sweep's counts and distributions, per controller and family, on stdout.
pub fn print_sweep(v: &serde_json::Value, dir: &std::path::Path) {
    print!("{}", sweep_text(v, dir));
}

/// What [`print_sweep`] prints.
pub fn sweep_text(v: &serde_json::Value, dir: &std::path::Path) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let f = |x: &serde_json::Value| x.as_f64().map_or_else(|| "-".to_string(), |x| format!("{x:.3}"));
    let sections = sweep_sections(v);
    let several = sections.len() > 1;
    let _ = writeln!(out);
    let head = format!(
        "{} runs of {} ({}), seed {}",
        sweep_runs(v),
        v["scenario"].as_str().unwrap_or(""),
        v["file"].as_str().unwrap_or(""),
        v["seed"]
    );
    if several {
        let _ = writeln!(out, "{head}, each flown by every controller:");
        for (name, a) in &sections {
            let _ = writeln!(out, "  {}: {}", name.unwrap_or(""), sweep_counts(a));
        }
    } else {
        let _ = writeln!(out, "{head}: {}", sweep_counts(v));
    }
    let _ = writeln!(out);
    let controller =
        |name: Option<&str>| if several { format!("{:<12} ", name.unwrap_or("")) } else { String::new() };
    let _ = writeln!(
        out,
        "{}{:<16} {:>6} {:>8} {:>9} {:>7} {:>7} {:>22} {:>16}",
        controller(several.then_some("controller")),
        "family",
        "runs",
        "reached",
        "collided",
        "missed",
        "errors",
        "clearance p1/p5/p50 m",
        "path p50/p95 m"
    );
    let families = v["family_order"].as_array().cloned().unwrap_or_default();
    for (name, section) in &sections {
        for family in families.iter().filter_map(|n| n.as_str()) {
            let a = &section["families"][family];
            let _ = writeln!(
                out,
                "{}{:<16} {:>6} {:>8} {:>9} {:>7} {:>7} {:>22} {:>16}",
                controller(*name),
                family,
                a["runs"].to_string(),
                a["reached"].to_string(),
                a["collided"].to_string(),
                a["missed"].to_string(),
                a["errors"].to_string(),
                format!(
                    "{}/{}/{}",
                    f(&a["min_clearance_m"]["p1"]),
                    f(&a["min_clearance_m"]["p5"]),
                    f(&a["min_clearance_m"]["p50"])
                ),
                format!("{}/{}", f(&a["path_length_m"]["p50"]), f(&a["path_length_m"]["p95"])),
            );
        }
    }
    for (name, section) in &sections {
        let _ = writeln!(out);
        if let Some(name) = name {
            let _ = writeln!(out, "{name}:");
        }
        let p = &section["failure_probability"];
        for (what, key) in [("collisions", "collision"), ("missed goals", "missed"), ("any failure", "any")] {
            let _ = writeln!(out, "{}", failure_text(what, &p[key]));
        }
        if section["aborted"].as_u64().is_some_and(|n| n > 0) {
            let _ = writeln!(out, "{}", failure_text("runs the controller stopped", &p["aborted"]));
        }
        for family in families.iter().filter_map(|n| n.as_str()) {
            let p = &section["families"][family]["failure_probability"];
            let _ = writeln!(out, "  {family}: {}", failure_text("any failure", &p["any"]));
        }
    }
    let t = &v["timing"];
    if let (Some(wall), Some(rate)) = (t["wall_time_s"].as_f64(), t["runs_per_s"].as_f64()) {
        let _ = writeln!(out);
        let run_wall_s = t["run_wall_s"].as_f64().unwrap_or(0.0);
        let solver = if v["controller_cmd"].is_string() {
            format!("{run_wall_s:.1} s in runs; the external controller's solve time is its own, not seen")
        } else {
            format!("solver {:.1} s of {run_wall_s:.1} s in runs", t["solver_s"].as_f64().unwrap_or(0.0))
        };
        let _ = writeln!(out, "Time: {wall:.1} s wall, {rate:.1} runs/s with {} jobs ({solver})", t["jobs"]);
    }
    let _ = writeln!(out, "Report: {}", dir.join("report.md").display());
    let _ = writeln!(out, "Summary: {}", dir.join("sweep.json").display());
    out
}

/// One failure probability in words, e.g. "collisions: 0 of 1,600 runs, P < 0.19 % (95 %)"
/// (`what`: "collisions"; `p`: an entry of a sweep's `failure_probability`).
pub fn failure_text(what: &str, p: &serde_json::Value) -> String {
    let (Some(k), Some(n), Some(lower), Some(upper), Some(level)) = (
        p["failures"].as_u64(),
        p["runs"].as_u64(),
        p["lower"].as_f64(),
        p["upper"].as_f64(),
        p["level"].as_f64(),
    ) else {
        return format!("{what}: no run flew");
    };
    let percent = |x: f64| format!("{:.2} %", 100.0 * x);
    let level = format!("{:.0} %", 100.0 * level);
    if k == 0 {
        format!("{what}: 0 of {n} runs, P < {} ({level})", percent(upper))
    } else {
        format!("{what}: {k} of {n} runs, P in [{}, {}] ({level})", percent(lower), percent(upper))
    }
}

/// The table of `hilbench falsify` (from falsify.json's value) and where its files are.
pub fn print_falsify(v: &serde_json::Value, dir: &std::path::Path) {
    println!();
    println!(
        "{} ({}) with {}, property {}, budget {}, seed {}:",
        v["scenario"].as_str().unwrap_or(""),
        v["file"].as_str().unwrap_or(""),
        v["controller"].as_str().unwrap_or(""),
        v["property"].as_str().unwrap_or(""),
        v["budget"],
        v["seed"]
    );
    println!();
    println!(
        "{:<12} {:<7} {:>6} {:>14} {:>14} {:>7}  worst run's trace",
        "space", "method", "runs", "first failure", "best [m]", "errors"
    );
    for s in v["searches"].as_array().into_iter().flatten() {
        let first = s["first_failure_run"].as_u64().map_or("none".to_string(), |r| format!("run {r}"));
        // JSON has no infinity: a best run with no obstacle near and no miss scores +inf.
        let best = match (s["best"]["score_m"].as_f64(), s["best"]["outcome"].as_str()) {
            (Some(b), _) => format!("{b:+.4}"),
            // A failure outright: the controller stopped the run, or it timed out.
            (None, Some(o @ ("aborted" | "timeout"))) => format!("-inf ({o})"),
            (None, Some(_)) => "+inf".to_string(),
            (None, None) => "-".to_string(),
        };
        let trace = s["worst_trace"]["file"].as_str().unwrap_or("-");
        println!(
            "{:<12} {:<7} {:>6} {:>14} {:>14} {:>7}  {trace}",
            s["space"].as_str().unwrap_or(""),
            s["method"].as_str().unwrap_or(""),
            s["runs"].to_string(),
            first,
            best,
            s["errors"].to_string(),
        );
    }
    println!();
    if v["found"].as_bool() == Some(true) {
        println!("A run failed the property: replay its trace with the command in its header.");
    } else {
        println!("No run failed the property within the budget.");
    }
    println!("falsify.json, runs.csv, report.md and the traces are in {}", dir.display());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_runs_header_names_each_directions_delays_their_loss_and_the_seed() {
        let mut s = mav::Scenario::by_name("paper-2").expect("paper-2");
        s.seed = 7;
        assert_eq!(delays_text(&s), "delays: gamma on commands, seed 7");
        s.delays.as_mut().expect("delays").loss_probability = Some(0.02);
        assert_eq!(delays_text(&s), "delays: gamma on commands (loss 0.02), seed 7");
        s.delays = Some(delay::DelaysTable {
            to_controller: Some(Box::new(delay::DelaysTable::trace("wifi.csv", vec![0.1], false))),
            ..delay::DelaysTable::default()
        });
        assert_eq!(delays_text(&s), "delays: trace wifi.csv on samples, seed 7");
        s.delays = Some(delay::DelaysTable {
            kind: Some("none".into()),
            loss_probability: Some(0.1),
            ..delay::DelaysTable::default()
        });
        assert_eq!(delays_text(&s), "delays: no delay on commands (loss 0.1), seed 7");
        s.delays = None;
        assert_eq!(delays_text(&s), "no delays");
    }

    #[test]
    fn an_external_controllers_sweep_claims_no_solver_time_and_ours_states_it() {
        let timing = serde_json::json!({ "wall_time_s": 12.0, "runs_per_s": 2.0, "jobs": 2, "solver_s": 0.0, "run_wall_s": 20.0 });
        let mut v = serde_json::json!({ "runs": 24, "timing": timing, "controller_cmd": "python3 pd.py" });
        let external = sweep_text(&v, std::path::Path::new("out"));
        assert!(
            external.contains("(20.0 s in runs; the external controller's solve time is its own, not seen)"),
            "{external}"
        );
        assert!(!external.contains("solver 0.0 s"), "{external}");
        v["controller_cmd"] = serde_json::Value::Null;
        let ours = sweep_text(&v, std::path::Path::new("out"));
        assert!(ours.contains("(solver 0.0 s of 20.0 s in runs)"), "{ours}");
    }
}
