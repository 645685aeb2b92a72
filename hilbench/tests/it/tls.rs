//! `hilbench certs` and runs over mutual TLS, as a user gives them on the command line:
//! certificates made at test time (no key committed).

use crate::common::csv_without_solve_times;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn hilbench(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_hilbench")).args(args).output().expect("hilbench runs")
}

fn out_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8")
}

/// `hilbench certs --out <name>`: a fresh CA and identities.
fn certs(name: &str) -> PathBuf {
    let dir = out_dir(name);
    let made = hilbench(&["certs", "--out", path(&dir)]);
    assert!(made.status.success(), "{made:?}");
    dir
}

/// summary.json's runs without their solve times (wall clock).
fn runs_without_solve_times(dir: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    let summary: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let mut runs = summary["runs"].as_array().expect("runs").clone();
    for run in &mut runs {
        run.as_object_mut().expect("a run").remove("solve_ms");
    }
    runs
}

#[test]
fn certs_writes_a_ca_and_an_identity_per_service_and_never_overwrites() {
    let dir = certs("tls-certs-layout");
    for name in ["ca", "plant", "netem", "controller", "gateway", "hilbench"] {
        let cert = std::fs::read_to_string(dir.join(format!("{name}.pem"))).expect("certificate");
        assert!(cert.starts_with("-----BEGIN CERTIFICATE-----"), "{name}.pem: {cert}");
        let key = std::fs::read_to_string(dir.join(format!("{name}-key.pem"))).expect("key");
        assert!(key.contains("PRIVATE KEY-----"), "{name}-key.pem");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode =
                std::fs::metadata(dir.join(format!("{name}-key.pem"))).expect("key").permissions().mode();
            assert_eq!(mode & 0o077, 0, "{name}-key.pem is readable by others: {mode:o}");
        }
    }
    let again = hilbench(&["certs", "--out", path(&dir)]);
    assert_eq!(again.status.code(), Some(1), "{again:?}");
    assert!(String::from_utf8_lossy(&again.stderr).contains("exists already"), "{again:?}");
}

#[test]
fn certs_are_valid_for_days_from_now_and_empty_or_spaced_names_are_refused() {
    let days = |dir: &Path, name: &str| -> (i64, i64) {
        let pem = std::fs::read(dir.join(format!("{name}.pem"))).expect("certificate");
        let (_, pem) = x509_parser::pem::parse_x509_pem(&pem).expect("PEM");
        let cert = pem.parse_x509().expect("X.509");
        let now =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).expect("after 1970").as_secs()
                as i64;
        let v = cert.validity();
        (v.not_before.timestamp() - now, v.not_after.timestamp() - now)
    };
    // The default: a year, not 1975 to 4096.
    let dir = certs("tls-certs-validity");
    for name in ["ca", "plant", "hilbench"] {
        let (before, after) = days(&dir, name);
        assert!((-3700..=-3500).contains(&before), "{name}: valid from {before} s from now");
        assert!((365 * 86_400 - 100..=365 * 86_400 + 100).contains(&after), "{name}: until {after} s");
    }
    let dir = out_dir("tls-certs-days");
    let made = hilbench(&["certs", "--out", path(&dir), "--days", "30"]);
    assert!(made.status.success(), "{made:?}");
    let (_, after) = days(&dir, "netem");
    assert!((30 * 86_400 - 100..=30 * 86_400 + 100).contains(&after), "until {after} s");
    for args in [
        vec!["--san", ""],
        vec!["--san", "my host"],
        vec!["--san", "ok.example", "--san", "a/b"],
        vec!["--days", "0"],
        vec!["--days", "100000"],
    ] {
        let dir = out_dir("tls-certs-refused");
        let run = hilbench(&[&["certs", "--out", path(&dir)], &args[..]].concat());
        assert_eq!(run.status.code(), Some(2), "{args:?}: {run:?}");
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(stderr.contains(args[args.len() - 2]), "{args:?}: {stderr}");
        assert!(!dir.exists(), "{args:?}: written");
    }
}

#[test]
fn reproduce_paper_2_over_mutual_tls_gives_the_plaintext_numbers() {
    let tls = certs("tls-reproduce-certs");
    let (plain, secure) = (out_dir("tls-reproduce-plaintext"), out_dir("tls-reproduce-mtls"));
    let args = ["--quiet", "--no-plots", "reproduce", "--scenario", "paper-2"];
    let run = hilbench(&[&args[..], &["--out", path(&plain)]].concat());
    assert!(run.status.success(), "{run:?}");
    let run = hilbench(&[&args[..], &["--out", path(&secure), "--tls-dir", path(&tls)]].concat());
    assert!(run.status.success(), "{run:?}");
    assert_eq!(runs_without_solve_times(&plain), runs_without_solve_times(&secure));
    for mode in ["nmpc", "multistage"] {
        let csv = format!("paper-2-{mode}.csv");
        assert_eq!(
            csv_without_solve_times(&plain.join(&csv)),
            csv_without_solve_times(&secure.join(&csv)),
            "{mode}"
        );
    }
}

#[test]
fn a_run_whose_client_certificate_another_ca_signed_fails_at_once_naming_the_refusal() {
    let tls = certs("tls-stranger-certs");
    let other = certs("tls-stranger-other-ca");
    // hilbench presents a certificate of another CA; the services it starts require the CA's.
    for file in ["hilbench.pem", "hilbench-key.pem"] {
        std::fs::remove_file(tls.join(file)).expect("remove");
        std::fs::copy(other.join(file), tls.join(file)).expect("copy");
    }
    let out = out_dir("tls-stranger-run");
    let run = hilbench(&[
        "--quiet",
        "--no-plots",
        "reproduce",
        "--scenario",
        "paper-2",
        "--tls-dir",
        path(&tls),
        "--out",
        path(&out),
    ]);
    assert_eq!(run.status.code(), Some(1), "{run:?}");
    let stderr = String::from_utf8_lossy(&run.stderr);
    // The server's alert, passed on (both CAs are named "hilbench CA": the server finds the
    // signature wrong, DecryptError). In TLS 1.3 the client checks nothing more after its
    // Finished, so the server's alert can lose the race with the close it is followed by: then
    // the call fails on the connection the server closed (read: "connection closed"; or the
    // client's next write: "broken pipe"). Either way it fails at once, naming the service it
    // could not talk to.
    assert!(
        ["received fatal alert", "connection closed", "broken pipe"].iter().any(|m| stderr.contains(m)),
        "{stderr}"
    );
    assert!(stderr.contains("127.0.0.1:"), "names the address: {stderr}");
}

#[test]
fn a_service_address_whose_scheme_contradicts_the_tls_set_up_is_refused_at_once_naming_the_flag() {
    let tls = certs("tls-scheme");
    let cases: [(&[&str], &str); 3] = [
        (
            &["--plant", "http://127.0.0.1:1", "--tls-dir", path(&tls)],
            "--plant: address http://127.0.0.1:1: http:// with --tls-ca",
        ),
        (
            &["--plant", "https://127.0.0.1:1"],
            "--plant: address https://127.0.0.1:1: https:// needs --tls-ca",
        ),
        (
            &["--netem", "https://127.0.0.1:1"],
            "--netem: address https://127.0.0.1:1: https:// needs --tls-ca",
        ),
    ];
    for (flags, expected) in cases {
        let out = out_dir("tls-scheme-run");
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenarios/paper-2.toml");
        let run = hilbench(
            &[&["--no-plots", "run", file, "--mode", "nmpc", "--out", path(&out)][..], flags].concat(),
        );
        assert_eq!(run.status.code(), Some(1), "{flags:?}: {run:?}");
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(stderr.contains(expected), "{flags:?}: {stderr}");
        assert!(!stderr.contains("waiting for"), "{flags:?}: waited instead of refusing: {stderr}");
    }
}

#[test]
fn bad_tls_flags_are_refused_at_start_naming_the_flag() {
    let tls = certs("tls-bad-flags");
    let readme = concat!(env!("CARGO_MANIFEST_DIR"), "/../README.md");
    let (cert, missing, ca) = (tls.join("hilbench.pem"), tls.join("missing.pem"), tls.join("ca.pem"));
    let cases: [(&[&str], &str); 4] = [
        (&["--tls-cert", path(&cert)], "--tls-cert needs --tls-key"),
        (&["--tls-ca", path(&missing)], "--tls-ca"),
        (&["--tls-ca", readme], "no PEM certificate"),
        (&["--tls-ca", path(&ca)], "--tls-ca without --tls-cert"),
    ];
    for (flags, expected) in cases {
        let run =
            hilbench(&[&["--quiet", "--no-plots", "reproduce", "--scenario", "paper-2"][..], flags].concat());
        assert_eq!(run.status.code(), Some(1), "{flags:?}: {run:?}");
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(stderr.contains(expected), "{flags:?}: {stderr}");
    }
}
