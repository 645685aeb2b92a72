//! `hilbench trace import|stats|fit` on a real ping recording (linkfit/tests/data): the lost
//! probes become `lost` lines, the statistics count them, the fit's tables load as a scenario
//! file's, and a bad line is refused with its number.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn hilbench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hilbench")).args(args).output().expect("hilbench runs")
}

fn fixture(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../linkfit/tests/data").join(name).display().to_string()
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hilbench-trace-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temp dir");
    dir
}

#[test]
fn a_ping_recording_imports_with_its_losses_and_fits_into_tables_the_loader_takes() {
    let dir = temp("ping");
    let trace = dir.join("link.csv");
    let out = hilbench(&[
        "trace",
        "import",
        "--format",
        "ping",
        &fixture("ping-linux-loopback.txt"),
        "--out",
        &trace.display().to_string(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&trace).expect("the trace");
    assert_eq!(text.lines().filter(|l| *l == "lost").count(), 8, "{text}");
    assert!(text.contains("# tool: ping"), "{text}");

    let out = hilbench(&["trace", "stats", &trace.display().to_string(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stats: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!((stats["count"].as_u64(), stats["losses"].as_u64()), (Some(200), Some(8)));

    let out = hilbench(&["trace", "fit", &trace.display().to_string(), "--seed", "1"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let tables = String::from_utf8(out.stdout).expect("UTF-8");
    // The family's loss: the share's Clopper–Pearson interval around 8 of 200.
    assert!(tables.contains("# loss: the trace lost 8 of 200 probes"), "{tables}");
    let json = hilbench(&["trace", "fit", &trace.display().to_string(), "--seed", "1", "--json"]);
    assert!(json.status.success(), "{}", String::from_utf8_lossy(&json.stderr));
    let report: serde_json::Value = serde_json::from_slice(&json.stdout).expect("JSON");
    assert_eq!((report["entries"].as_u64(), report["delivered"].as_u64()), (Some(200), Some(192)));
    assert_eq!(report["loss_probability"].as_f64(), Some(0.04));
    let first = &report["candidates"][0];
    assert!(first["model"]["kind"].is_string() && first["params"][0]["lower"].is_f64(), "{first}");
    let delays = tables.split("[[sweep.families]]").next().expect("the scenario table").to_string();
    // The [scenario.delays] table in a scenario file: the loader takes it.
    let paper_2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml"))
            .expect("paper-2");
    let start = paper_2.find("[scenario.delays]").expect("paper-2's delays");
    let end = paper_2[start + 1..].find("\n[").map_or(paper_2.len(), |i| start + 1 + i);
    let file = dir.join("fitted.toml");
    let text = format!("{}{}{}", &paper_2[..start], delays, &paper_2[end..])
        .replace("name = \"paper-2\"", "name = \"fitted-link\"");
    std::fs::write(&file, text).expect("write");
    hilbench::scenario_file::ScenarioFile::load(&file).unwrap_or_else(|e| panic!("{e}\n{delays}"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bad_line_is_refused_with_its_number_or_skipped_and_counted() {
    let dir = temp("bad");
    let csv = dir.join("rtt.csv");
    std::fs::write(&csv, "rtt_ms\n12.5\n13\nfast\n14\n").expect("write");
    let out_file = dir.join("out.csv").display().to_string();
    let args = ["trace", "import", "--format", "csv", csv.to_str().expect("UTF-8"), "--out", &out_file];
    let out = hilbench(&args);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("line 4"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = hilbench(&[&args[..], &["--skip-bad"]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&out_file).expect("the trace");
    assert_eq!(text.lines().filter(|l| !l.starts_with('#') && *l != "delay_s").count(), 3, "{text}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `trace echo` on a loopback port (a free one, found by binding and letting go), killed on drop.
struct Echo {
    child: std::process::Child,
    addr: String,
}

impl Echo {
    fn start() -> Self {
        let port =
            std::net::UdpSocket::bind("127.0.0.1:0").expect("a port").local_addr().expect("addr").port();
        let addr = format!("127.0.0.1:{port}");
        let child = Command::new(env!("CARGO_BIN_EXE_hilbench"))
            .args(["trace", "echo", "--listen", &addr])
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("echo starts");
        std::thread::sleep(std::time::Duration::from_millis(300));
        Self { child, addr }
    }
}

impl Drop for Echo {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn a_recording_over_loopback_against_trace_echo_loses_nothing_and_splits_the_round_trip() {
    let dir = temp("record");
    let echo = Echo::start();
    let out = dir.join("link.csv");
    let prefix = dir.join("link");
    let result = hilbench(&[
        "trace",
        "record",
        "--target",
        &echo.addr,
        "--rate-hz",
        "200",
        "--duration-s",
        "2",
        "--out",
        &out.display().to_string(),
        "--out-directions",
        &prefix.display().to_string(),
        "--probe-bytes",
        "200",
    ]);
    assert!(result.status.success(), "{}", String::from_utf8_lossy(&result.stderr));
    let rtt = delay::parse_trace_file(&std::fs::read_to_string(&out).expect("the trace")).expect("a trace");
    assert_eq!(rtt.delays_s.len(), 400);
    assert_eq!((rtt.losses(), rtt.provenance.losses), (0, Some(0)));
    assert_eq!((rtt.provenance.rate_hz, rtt.provenance.probe_bytes), (Some(200.0), Some(200)));
    assert_eq!(rtt.provenance.source.as_deref(), Some(echo.addr.as_str()));
    assert!(rtt.delays_s.iter().all(|d| *d > 0.0 && *d < 0.1), "{:?}", rtt.delays_s);
    let read = |name: &str| {
        let path = dir.join(format!("link-{name}.csv"));
        delay::parse_trace_file(&std::fs::read_to_string(&path).expect("a direction")).expect("a trace")
    };
    let (up, down) = (read("up"), read("down"));
    assert_eq!((up.delays_s.len(), down.delays_s.len()), (400, 400));
    // The legs add up to the round trip (to the clamping of a leg below zero, which loopback's
    // microsecond jitter can cause).
    for ((u, d), r) in up.delays_s.iter().zip(&down.delays_s).zip(&rtt.delays_s) {
        assert!((u + d - r).abs() < 50e-6, "{u} + {d} vs {r}");
    }
    // The file is a scenario's trace as it is.
    hilbench::scenario_file::ScenarioFile::load(&write_scenario(&dir, "link.csv")).expect("loads");
    let _ = std::fs::remove_dir_all(&dir);
}

/// paper-2 with its delays replaced by the trace `file`.
fn write_scenario(dir: &Path, file: &str) -> PathBuf {
    let paper_2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml"))
            .expect("paper-2");
    let start = paper_2.find("[scenario.delays]").expect("paper-2's delays");
    let end = paper_2[start + 1..].find("\n[").map_or(paper_2.len(), |i| start + 1 + i);
    let text = format!(
        "{}[scenario.delays]\nkind = \"trace\"\nfile = \"{file}\"\nlooping = true\n{}",
        &paper_2[..start],
        &paper_2[end..]
    )
    .replace("name = \"paper-2\"", "name = \"recorded-link\"");
    let path = dir.join("recorded.toml");
    std::fs::write(&path, text).expect("write");
    path
}

#[test]
fn a_plain_echo_gives_the_round_trips_and_ctrl_c_keeps_what_was_recorded() {
    let dir = temp("plain-echo");
    // A UDP echo that returns every datagram as it is (socat's, a router's).
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("a socket");
    let addr = socket.local_addr().expect("addr").to_string();
    std::thread::spawn(move || {
        let mut buf = [0u8; 2048];
        while let Ok((n, from)) = socket.recv_from(&mut buf) {
            let _ = socket.send_to(&buf[..n], from);
        }
    });
    let out = dir.join("plain.csv");
    let child = Command::new(env!("CARGO_BIN_EXE_hilbench"))
        .args(["trace", "record", "--target", &addr, "--rate-hz", "100", "--duration-s", "60"])
        .args(["--out", &out.display().to_string(), "--out-directions", &dir.join("d").display().to_string()])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("record starts");
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let signal = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill runs");
    assert!(signal.success());
    let result = child.wait_with_output().expect("record ends");
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("does not stamp its replies"), "{stderr}");
    let rtt = delay::parse_trace_file(&std::fs::read_to_string(&out).expect("the trace")).expect("a trace");
    assert!((100..=200).contains(&rtt.delays_s.len()), "{}", rtt.delays_s.len());
    assert_eq!(rtt.losses(), 0);
    assert!(!dir.join("d-up.csv").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ctrl_c_between_slow_ticks_stops_the_recording_without_waiting_out_the_timeout_and_a_bad_out_is_refused_first()
 {
    let dir = temp("slow-ctrl-c");
    // An echo that answers the first probe only: the second is still waiting at Ctrl-C.
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").expect("a socket");
    let addr = socket.local_addr().expect("addr").to_string();
    std::thread::spawn(move || {
        let mut buf = [0u8; 2048];
        if let Ok((n, from)) = socket.recv_from(&mut buf) {
            let _ = socket.send_to(&buf[..n], from);
        }
        while socket.recv_from(&mut buf).is_ok() {}
    });
    let record = |out: &Path| {
        Command::new(env!("CARGO_BIN_EXE_hilbench"))
            .args(["trace", "record", "--target", &addr, "--rate-hz", "0.5", "--duration-s", "600"])
            .args(["--timeout-s", "120", "--out", &out.display().to_string()])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("record starts")
    };
    // A directory that does not exist: refused before a probe is sent.
    let refused = record(&dir.join("no-such-dir/link.csv")).wait_with_output().expect("ends");
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("--out") && stderr.contains("no directory") && !stderr.contains("recording "),
        "{stderr}"
    );

    let out = dir.join("slow.csv");
    let mut child = record(&out);
    // Probes at 0 and 2 s; the next tick is at 4 s, the second probe's timeout at 122 s.
    std::thread::sleep(std::time::Duration::from_millis(3000));
    let signal = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill runs");
    assert!(signal.success());
    // Ended long before the timeout (a bound on a hang, not a measured time).
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while child.try_wait().expect("waits").is_none() {
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            panic!("still recording 60 s after Ctrl-C: it waited out the tick or the timeout");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let result = child.wait_with_output().expect("record ends");
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("1 still waiting left out"), "{stderr}");
    let rtt = delay::parse_trace_file(&std::fs::read_to_string(&out).expect("the trace")).expect("a trace");
    assert_eq!((rtt.delays_s.len(), rtt.losses()), (1, 0), "the answered probe only");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_import_whose_out_is_its_own_measurement_is_refused_and_leaves_it_as_it_was() {
    let dir = temp("import-onto-itself");
    let file = dir.join("link.csv");
    std::fs::write(&file, "rtt_ms\n12\n15\n").expect("the measurement");
    let f = file.display().to_string();
    let same = dir.join(".").join("link.csv").display().to_string();
    let result = hilbench(&["trace", "import", "--format", "csv", &f, "--out", &same]);
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("is the measurement being imported"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&file).expect("still there"), "rtt_ms\n12\n15\n");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_target_where_nothing_answers_writes_nothing_and_says_why() {
    let dir = temp("silent");
    let port = std::net::UdpSocket::bind("127.0.0.1:0").expect("a port").local_addr().expect("addr").port();
    let out = dir.join("none.csv");
    let result = hilbench(&[
        "trace",
        "record",
        "--target",
        &format!("127.0.0.1:{port}"),
        "--rate-hz",
        "50",
        "--duration-s",
        "0.2",
        "--timeout-s",
        "0.2",
        "--out",
        &out.display().to_string(),
    ]);
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("none of 10 probes was answered") && stderr.contains("trace echo"), "{stderr}");
    assert!(!out.exists());
    let _ = std::fs::remove_dir_all(&dir);
}
