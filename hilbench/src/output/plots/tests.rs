use super::*;

/// A fresh directory under the system's temporary directory.
pub(crate) fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hilbench-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temporary directory");
    dir
}

pub(crate) fn facts(scenario: &str, controller: &str) -> RunFacts {
    RunFacts {
        scenario: scenario.to_string(),
        controller: controller.to_string(),
        reached: true,
        collided: false,
        time_to_goal_s: Some(11.8),
        path_length_m: 6.0,
        min_clearance_m: 0.2,
        cycles: 60,
        solve_ms_median: 1.0,
        final_position_m: [0.0, 9.0, 1.0],
        collisions_m: Vec::new(),
        collisions_described: Vec::new(),
        end_reason: mpc::RunEnd::Reached { time_ns: 0 },
        explanation: Vec::new(),
        commands_lost: None,
    }
}

/// A straight flight from the start to the goal with Gamma-like delays.
fn rows(scenario: &Scenario, m: usize) -> Vec<CycleRow> {
    let n = 60;
    let records: Vec<mpc::CycleRecord> = (0..n)
        .map(|k| {
            let f = k as f64 / (n - 1) as f64;
            let p: Vec<f64> =
                (0..3).map(|i| scenario.start[i] + f * (scenario.goal_m[i] - scenario.start[i])).collect();
            mpc::CycleRecord {
                cycle: k as u64,
                sample_time_ns: k as u64 * 200_000_000,
                state: [p[0], p[1], p[2], 0.5, 0.5, 0.0, 0.01, -0.02],
                watchdog_hover: false,
                command: [9.81 + (k as f64).sin(), 0.05 * (k as f64 * 0.3).cos(), -0.05],
                command_seq: k as u64 + 1,
                known_delay_s: (k > 0).then(|| 0.15 + 0.05 * ((k * 7 % 11) as f64 / 11.0)),
                injected_delay_s: Some(0.15 + 0.05 * (((k + 1) * 7 % 11) as f64 / 11.0)),
                command_lost: false,
                weights: (0..m)
                    .map(|i| if i == k % m { 0.6 } else { 0.4 / (m as f64 - 1.0).max(1.0) })
                    .collect(),
                solve: mpc::SolveStats {
                    status: mpc::SolveStatus::Converged,
                    iterations: 10,
                    solve_ms: 0.2,
                    cost: 1.0,
                    constraint_violation: 0.0,
                    min_clearance_m: 0.3,
                },
                decision: None,
                best_effort: false,
                reason: String::new(),
                cost_gap: None,
                predictions: Vec::new(),
            }
        })
        .collect();
    crate::run::rows_of(&records)
}

fn is_png(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x89, b'P', b'N', b'G', b'\r', b'\n', 0x1a, b'\n'])
}

#[test]
fn plots_of_two_runs_are_written_as_png_and_svg_with_their_titles() {
    let scenario = Scenario::by_name("paper-2").expect("paper-2");
    let nmpc_rows = rows(&scenario, 1);
    let ms_rows = rows(&scenario, 5);
    let mut nmpc = facts("paper-2", "nmpc");
    nmpc.final_position_m = scenario.goal_m;
    let mut ms = facts("paper-2", "multistage");
    ms.final_position_m = scenario.goal_m;
    let runs = [
        RunData { scenario: &scenario, summary: nmpc, rows: &nmpc_rows },
        RunData { scenario: &scenario, summary: ms, rows: &ms_rows },
    ];
    let dir = temp_dir("plots");
    let written = write_all(&dir, &runs).expect("plots");
    // Two scenario figures, inputs and delays of both runs, weights of the multi-stage one.
    assert_eq!(written.len(), 2 * 7, "{written:?}");
    let expect = [
        (stem(Kind::Top, "paper-2", None), "paper-2: paths seen from above"),
        (stem(Kind::ThreeD, "paper-2", None), "paper-2: paths in 3D"),
        (stem(Kind::Inputs, "paper-2", Some("nmpc")), "inputs against time"),
        (stem(Kind::Delays, "paper-2", Some("multistage")), "Gamma fitted by moments"),
        (stem(Kind::Weights, "paper-2", Some("multistage")), "scenario weights"),
    ];
    for (stem, title) in expect {
        let png = std::fs::read(dir.join(PLOTS_DIR).join(format!("{stem}.png"))).expect("png");
        assert!(png.len() > 10_000 && is_png(&png), "{stem}.png: {} bytes", png.len());
        let svg = std::fs::read_to_string(dir.join(PLOTS_DIR).join(format!("{stem}.svg"))).expect("svg");
        assert!(svg.trim_start().starts_with("<svg") && svg.trim_end().ends_with("</svg>"), "{stem}.svg");
        assert!(svg.contains(title), "{stem}.svg lacks {title:?}");
    }
    // The top view holds both controllers' legends and the cylinders.
    let top = std::fs::read_to_string(
        dir.join(PLOTS_DIR).join(format!("{}.svg", stem(Kind::Top, "paper-2", None))),
    )
    .expect("svg");
    for label in ["standard NMPC", "multi-stage NMPC", "cylinder (to scale)", "x [m]", "y [m]"] {
        assert!(top.contains(label), "top view lacks {label:?}");
    }
    assert!(
        !dir.join(PLOTS_DIR).join(format!("{}.png", stem(Kind::Weights, "paper-2", Some("nmpc")))).exists()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_moment_fit_recovers_a_gamma() {
    // Mean 0.18 s, variance 0.0027 s²: shape 12, scale 15 ms.
    let (mean, sd) = (0.18f64, 0.0027f64.sqrt());
    let delays: Vec<f64> = (0..1000).map(|i| mean + sd * if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
    let (k, theta) = gamma_fit(&delays).expect("a fit");
    assert!((k - 12.0).abs() < 0.05 && (theta - 0.015).abs() < 1e-4, "{k} {theta}");
    assert!(gamma_fit(&[0.1]).is_none());
    // The controller's own fit of the same delays, to the bit.
    let mut window = mpc::DelayWindow::new(delays.len());
    delays.iter().for_each(|&d| {
        window.push(d);
    });
    let controller = window.fit(2).expect("the controller's fit");
    assert_eq!((k.to_bits(), theta.to_bits()), (controller.shape.to_bits(), controller.scale_s.to_bits()));
    let rows = rows(&Scenario::by_name("paper-1").expect("paper-1"), 1);
    let d = delays_of(&rows);
    assert_eq!(d.len(), rows.len() - 1);
    assert_eq!(d[0], (rows[0].t_s, rows[1].known_delay_s));
}

fn delays_of(rows: &[CycleRow]) -> Vec<(f64, f64)> {
    delays(rows)
}

/// `n` delays, s: the quantiles `(i + 0.5) / n` of Gamma(shape, scale_s) (a sample with no
/// sampling noise).
fn gamma_quantiles(n: usize, shape: f64, scale_s: f64) -> Vec<f64> {
    use statrs::distribution::{ContinuousCDF, Gamma};
    let g = Gamma::new(shape, 1.0 / scale_s).expect("a Gamma");
    (0..n).map(|i| g.inverse_cdf((i as f64 + 0.5) / n as f64)).collect()
}

/// A link's ordinary delays, 20-60 ms, with one in 25 a spike of 300-800 ms.
fn spiky_delays_s(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| {
            if i % 25 == 7 {
                0.3 + 0.5 * (i % 11) as f64 / 10.0
            } else {
                0.02 + 0.04 * (i % 13) as f64 / 12.0
            }
        })
        .collect()
}

#[test]
fn spikes_far_beyond_the_bulk_are_a_tail_bar_that_counts_them() {
    let delays = spiky_delays_s(1000);
    let ms: Vec<f64> = delays.iter().map(|d| d * 1e3).collect();
    let h = delays::Histogram::of(&ms);
    let spikes = delays.iter().filter(|d| **d >= 0.3).count();
    let tail = h.tail.expect("a tail");
    assert_eq!(tail.count, spikes);
    assert!(tail.beyond_ms > 60.0 && tail.beyond_ms < 300.0, "{tail:?}");
    assert!((tail.max_ms - 800.0).abs() < 1e-9, "{tail:?}");
    // The bins cover the bulk, 20-60 ms, finely (not 800 ms in 25 bins of 32 ms).
    assert!(h.width <= 3.0, "{h:?}");
    assert_eq!(h.counts.iter().sum::<usize>() + tail.count, delays.len());
    // Gamma delays have no such tail.
    let gamma: Vec<f64> = gamma_quantiles(1000, 12.0, 0.015).iter().map(|d| d * 1e3).collect();
    assert_eq!(delays::Histogram::of(&gamma).tail, None);
}

#[test]
fn a_gamma_fitted_to_a_mixture_is_called_a_poor_fit_and_to_gamma_delays_not() {
    let mixture = spiky_delays_s(1000);
    let fit = gamma_fit(&mixture).expect("a fit");
    let quality = delays::FitQuality::of(&mixture, fit);
    assert!(quality.poor(), "{quality:?}");
    let gamma = gamma_quantiles(1000, 12.0, 0.015);
    let quality = delays::FitQuality::of(&gamma, gamma_fit(&gamma).expect("a fit"));
    assert!(!quality.poor(), "{quality:?}");
}
