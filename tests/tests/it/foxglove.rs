//! What Foxglove gets from a run, read by implementations independent of the Rust SDK that
//! wrote it: a run's MCAP file through the Python `mcap` package, and the live WebSocket view
//! through a Python client of the protocol (tests/python/).

use std::path::Path;
use std::process::{Command, Stdio};

use hilbench_tests::python::run_script;
use hilbench_tests::{TempDir, free_loopback_address, service_binary};
use mav::Scenario;

fn hilbench(args: &[&str]) -> std::process::Output {
    Command::new(service_binary("hilbench")).args(args).output().expect("hilbench runs")
}

fn utf8(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 path")
}

const CHANNELS: [(&str, &str, &str); 8] = [
    ("/scene", "foxglove.SceneUpdate", "protobuf"),
    ("/plan", "foxglove.SceneUpdate", "protobuf"),
    ("/tf", "foxglove.FrameTransform", "protobuf"),
    ("/pose", "foxglove.PoseInFrame", "protobuf"),
    ("/state", "hilbench.State", "json"),
    ("/command", "hilbench.Command", "json"),
    ("/delays", "hilbench.Delays", "json"),
    ("/safety", "hilbench.Safety", "json"),
];

#[test]
fn the_mcap_file_of_a_paper_2_run_reads_back_in_python_with_a_pose_and_a_plan_per_cycle_ending_at_the_final_position()
 {
    let out = TempDir::new("mcap-paper-2");
    let ran = hilbench(&["reproduce", "--scenario", "paper-2", "--out", utf8(&out), "--no-plots", "--quiet"]);
    assert!(ran.status.success(), "{ran:?}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json"))
            .expect("summary.json is JSON");
    let scenario = Scenario::paper_2();
    let runs = summary["runs"].as_array().expect("runs");
    assert_eq!(runs.len(), 2);
    for run in runs {
        let controller = run["controller"].as_str().expect("controller");
        let path = out.join(format!("paper-2-{controller}.mcap"));
        let read: serde_json::Value = serde_json::from_str(run_script("read_mcap.py", &[utf8(&path)]).trim())
            .expect("the script's JSON");
        let what = format!("paper-2 {controller}");
        for (topic, schema, encoding) in CHANNELS {
            let ch = &read["channels"][topic];
            assert_eq!(ch["schema"], schema, "{what}: {topic}");
            assert_eq!(ch["message_encoding"], encoding, "{what}: {topic}");
        }
        assert_eq!(read["channels"].as_object().map(|c| c.len()), Some(CHANNELS.len()), "{what}");
        assert_eq!(read["metadata"]["hilbench"]["scenario"], "paper-2");
        assert_eq!(read["metadata"]["hilbench"]["controller"], controller);
        assert_eq!(read["log_times_monotonic"], true, "{what}: log time goes back");
        // One pose and one plan per cycle, and the pose where the run ended.
        let cycles = run["cycles"].as_u64().expect("cycles");
        assert!(cycles > 10, "{what}: {cycles} cycles");
        assert_eq!(read["messages"]["/plan"].as_u64(), Some(cycles), "{what}");
        assert_eq!(read["messages"]["/pose"].as_u64(), Some(cycles + 1), "{what}");
        assert_eq!(read["messages"]["/tf"].as_u64(), Some(cycles + 1), "{what}");
        assert_eq!(read["messages"]["/scene"].as_u64(), Some(1), "{what}");
        for topic in ["/state", "/command", "/delays", "/safety"] {
            let seen: Vec<u64> = read["cycles"][topic]
                .as_array()
                .expect("cycles per topic")
                .iter()
                .filter_map(serde_json::Value::as_u64)
                .collect();
            assert_eq!(seen, (0..cycles).collect::<Vec<_>>(), "{what}: {topic}");
        }
        // A line per sampling-time scenario, every cycle.
        let scenarios = if controller == "nmpc" { 1 } else { scenario.sampling_times_s.len() as u64 };
        let lines = read["plan_lines"].as_array().expect("plan_lines");
        assert!(lines.iter().all(|n| n.as_u64() == Some(scenarios)), "{what}: {lines:?}");
        // The last pose is the summary's final position, to the bit (protobuf doubles).
        let last = read["last_pose"]["position"].as_array().expect("the last pose");
        let final_m = run["final_position_m"].as_array().expect("final_position_m");
        for k in 0..3 {
            let (a, b) = (last[k].as_f64().expect("x"), final_m[k].as_f64().expect("x"));
            assert_eq!(a.to_bits(), b.to_bits(), "{what}: axis {k}: {a} vs {b}");
        }
        // The scene: every cylinder with its size and height.
        let cylinders = read["scene"]["cylinders"].as_array().expect("cylinders");
        assert_eq!(cylinders.len(), scenario.obstacles.len(), "{what}");
        for (c, o) in cylinders.iter().zip(&scenario.obstacles) {
            assert_eq!(c["x"].as_f64(), Some(o.x_m));
            assert_eq!(c["y"].as_f64(), Some(o.y_m));
            assert_eq!(c["diameter"].as_f64(), Some(2.0 * o.radius_m));
            assert_eq!(c["height"].as_f64(), Some(o.height_m));
        }
        let entities = read["scene"]["entities"].as_array().expect("entities");
        for id in ["ground", "obstacles", "start", "goal"] {
            assert!(entities.iter().any(|e| e == id), "{what}: no {id} in {entities:?}");
        }
    }
    // --no-mcap writes none.
    let bare = TempDir::new("mcap-none");
    let args = ["reproduce", "--scenario", "paper-2", "--in-process", "--no-plots", "--no-mcap", "--quiet"];
    let ran = hilbench(&[&args[..], &["--out", utf8(&bare)]].concat());
    assert!(ran.status.success(), "{ran:?}");
    assert!(bare.join("summary.json").exists());
    let mcaps = std::fs::read_dir(&bare)
        .expect("the output directory")
        .filter_map(Result::ok)
        .filter(|e| e.path().extension().is_some_and(|x| x == "mcap"))
        .count();
    assert_eq!(mcaps, 0);
}

#[test]
fn a_websocket_client_subscribed_during_a_real_time_run_receives_the_scene_and_poses() {
    // paper-2 for 4 s of plant time (a real-time run lasts as long).
    let dir = TempDir::new("foxglove-ws");
    let paper_2 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml"))
            .expect("scenarios/paper-2.toml");
    let text = paper_2
        .replace("max_duration_s = 60.0", "max_duration_s = 4.0")
        .replace("name = \"paper-2\"", "name = \"paper-2-short\"");
    assert_ne!(text, paper_2);
    let file = dir.join("paper-2-short.toml");
    std::fs::write(&file, text).expect("write the scenario");
    let addr = free_loopback_address();
    let out = dir.join("out");
    let args = [
        "run",
        utf8(&file),
        "--time-mode",
        "real-time",
        "--mode",
        "nmpc",
        "--foxglove-ws",
        &addr,
        "--no-plots",
        "--quiet",
        "--out",
        utf8(&out),
    ];
    let mut run = Command::new(service_binary("hilbench"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("hilbench starts");
    // The client retries until the server is up, then waits for a scene and 5 poses (10 s at most).
    let read = run_script("foxglove_ws_client.py", &[&addr, "5", "10"]);
    let status = run.wait().expect("hilbench exits");
    let mut stderr = String::new();
    if let Some(mut e) = run.stderr.take() {
        let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
    }
    assert!(status.success(), "{status}: {stderr}");
    let read: serde_json::Value = serde_json::from_str(read.trim()).expect("the script's JSON");
    assert_eq!(read["server_name"], "hilbench");
    for (topic, schema, encoding) in CHANNELS {
        assert_eq!(read["channels"][topic]["schema"], schema, "{topic}");
        assert_eq!(read["channels"][topic]["encoding"], encoding, "{topic}");
    }
    assert!(read["messages"]["/scene"].as_u64() >= Some(1), "{read}");
    let poses = read["poses"].as_array().expect("poses");
    assert!(poses.len() >= 5, "{read}");
    // Plant time moves on, and the vehicle is near paper-2's start in its first seconds.
    let times: Vec<u64> = poses.iter().filter_map(|p| p["log_time"].as_u64()).collect();
    assert!(times.windows(2).all(|w| w[0] < w[1]), "{times:?}");
    let start = Scenario::paper_2().start;
    for p in poses {
        let x = p["position"].as_array().expect("position");
        let d = (0..3).map(|k| (x[k].as_f64().expect("x") - start[k]).powi(2)).sum::<f64>().sqrt();
        assert!(d < 3.0, "{p} is {d} m from the start");
    }
    // The file of the same run is written as well.
    assert!(out.join("paper-2-short-nmpc.mcap").exists());
}

#[test]
fn foxglove_ws_is_refused_in_lockstep_and_in_process_naming_the_flag() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/paper-2.toml");
    for extra in [&["--time-mode", "lockstep"][..], &["--in-process"][..]] {
        let args = [&["run", utf8(&file), "--foxglove-ws", "--quiet"][..], extra].concat();
        let ran = hilbench(&args);
        assert_eq!(ran.status.code(), Some(1), "{extra:?}: {ran:?}");
        let stderr = String::from_utf8_lossy(&ran.stderr);
        assert!(stderr.contains("--foxglove-ws needs"), "{extra:?}: {stderr}");
    }
}
