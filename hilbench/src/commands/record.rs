//! `hilbench trace record` and `hilbench trace echo`: the socket loops around
//! `linkfit::probe` (docs/links.md, "Record"). The recorder sends a probe at each tick of the
//! rate from one thread and reads replies on another; the ledger (under a lock) matches them
//! and settles each probe as answered or lost. Both sides stamp with their own monotonic clock
//! (ns since the command started), passed into the pure core.

use std::net::{ToSocketAddrs, UdpSocket};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use anyhow::Context;
use linkfit::probe::{self, FarStamps, Ledger, Packet};

use super::Exit;

/// How often the recorder says how far it is.
const PROGRESS_EVERY: Duration = Duration::from_secs(5);
/// The window of each clock-offset estimate (the shortest round trip in it), ns.
pub const OFFSET_WINDOW_NS: u64 = 10_000_000_000;
/// How long a blocking read waits before looking at the stop flag.
const READ_TICK: Duration = Duration::from_millis(100);

/// What `trace record` was asked.
#[derive(Debug, Clone)]
pub struct RecordSpec {
    pub target: String,
    pub rate_hz: f64,
    pub duration_s: f64,
    pub out: PathBuf,
    pub out_directions: Option<PathBuf>,
    pub probe_bytes: usize,
    pub timeout_s: f64,
}

fn now_ns(origin: Instant) -> u64 {
    u64::try_from(origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
}

fn lock(l: &Mutex<Ledger>) -> std::sync::MutexGuard<'_, Ledger> {
    l.lock().unwrap_or_else(PoisonError::into_inner)
}

/// How long the recorder waits for the last replies after Ctrl-C, at most (the probes still
/// waiting then are left out): the user asked to stop, not to wait out `--timeout-s`.
const INTERRUPTED_WAIT: Duration = Duration::from_secs(1);

/// `hilbench trace record`.
pub fn record(spec: &RecordSpec, quiet: bool) -> anyhow::Result<Exit> {
    probe::check_size(spec.probe_bytes).map_err(|e| anyhow::anyhow!("--probe-bytes: {e}"))?;
    // Where the files go is checked before the recording, which a bad path would lose.
    check_writable(&spec.out, "--out")?;
    if let Some(prefix) = &spec.out_directions {
        for name in ["up", "down"] {
            check_writable(&with_suffix(prefix, name), "--out-directions")?;
        }
    }
    let target = spec
        .target
        .to_socket_addrs()
        .with_context(|| format!("--target {}: not an address", spec.target))?
        .next()
        .with_context(|| format!("--target {}: no address", spec.target))?;
    let local = if target.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" };
    let socket = UdpSocket::bind(local).context("cannot open a UDP socket")?;
    socket.connect(target).with_context(|| format!("--target {target}: cannot reach it"))?;
    socket.set_read_timeout(Some(READ_TICK))?;
    let reader_socket = socket.try_clone()?;

    let timeout_ns = (spec.timeout_s * 1e9) as u64;
    let ledger = Arc::new(Mutex::new(Ledger::new(timeout_ns)));
    let stop = Arc::new(AtomicBool::new(false));
    let interrupted = Arc::new(AtomicBool::new(false));
    crate::fly::watch_ctrl_c(Arc::clone(&interrupted), "hilbench-record-ctrl-c");
    let refused = Arc::new(AtomicU64::new(0));
    let origin = Instant::now();
    let wall_start = std::time::SystemTime::now();

    let reader = {
        let (ledger, stop, refused) = (Arc::clone(&ledger), Arc::clone(&stop), Arc::clone(&refused));
        std::thread::Builder::new().name("hilbench-record-recv".into()).spawn(move || {
            let mut buf = vec![0u8; 65_536];
            while !stop.load(Ordering::Relaxed) {
                match reader_socket.recv(&mut buf) {
                    Ok(n) => {
                        let at = now_ns(origin);
                        let (seq, far) = match probe::decode(&buf[..n]) {
                            Ok(Packet::Reply(p, far)) => (p.seq, Some(far)),
                            // A plain echo returned our probe as it was: the round trip only.
                            Ok(Packet::Probe(p)) => (p.seq, None),
                            Err(_) => continue,
                        };
                        lock(&ledger).answer(seq, at, far);
                    }
                    // Nothing listens there (the ICMP port unreachable of a connected socket).
                    Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                        refused.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(_) => {}
                }
            }
        })?
    };

    if !quiet {
        eprintln!(
            "recording {} at {} Hz for {} s ({} bytes a probe, lost after {} s); Ctrl-C stops and writes what was recorded",
            spec.target, spec.rate_hz, spec.duration_s, spec.probe_bytes, spec.timeout_s
        );
    }
    let period_ns = 1e9 / spec.rate_hz;
    let total = (spec.duration_s * spec.rate_hz).round().max(1.0) as u64;
    let mut buf = Vec::with_capacity(spec.probe_bytes);
    let mut said = Instant::now();
    let mut said_settled = 0;
    let mut send_errors = 0u64;
    let mut slips = 0u64;
    // The k-th probe's time: origin + k * period, whatever the sleeps did; a sender more than
    // a period behind (a suspended process) skips the missed ticks instead of bursting.
    let mut tick: u64 = 0;
    let mut k: u64 = 0;
    while k < total && !interrupted.load(Ordering::Relaxed) {
        let due = (tick as f64 * period_ns) as u64;
        // Slept in slices, so that Ctrl-C is seen within one at any rate (0.01 Hz included).
        while now_ns(origin) < due && !interrupted.load(Ordering::Relaxed) {
            let left = Duration::from_nanos(due - now_ns(origin).min(due));
            std::thread::sleep(left.min(READ_TICK));
        }
        if interrupted.load(Ordering::Relaxed) {
            break;
        }
        let now = now_ns(origin);
        if now > due && now - due > period_ns as u64 && tick > 0 {
            let behind = ((now - due) as f64 / period_ns) as u64;
            slips += behind;
            tick += behind;
        }
        {
            let mut l = lock(&ledger);
            let p = l.send(now_ns(origin));
            probe::encode_probe(p, spec.probe_bytes, &mut buf).map_err(|e| anyhow::anyhow!("{e}"))?;
            if socket.send(&buf).is_err() {
                send_errors += 1;
            }
            l.settle(now_ns(origin));
        }
        tick += 1;
        k += 1;
        if !quiet && said.elapsed() >= PROGRESS_EVERY {
            said = Instant::now();
            let l = lock(&ledger);
            progress(origin, &l, said_settled);
            said_settled = l.settled().len();
        }
    }
    // The last probes' replies: until all are in or their timeout has passed (after Ctrl-C
    // too, at most the timeout: the probes still waiting then are left out, not called lost).
    let last_send = now_ns(origin);
    let mut wait_ns = timeout_ns;
    loop {
        if interrupted.load(Ordering::Relaxed) {
            wait_ns = wait_ns.min(INTERRUPTED_WAIT.as_nanos() as u64);
        }
        let l = lock(&ledger);
        if l.all_answered() || now_ns(origin).saturating_sub(last_send) > wait_ns {
            break;
        }
        drop(l);
        std::thread::sleep(Duration::from_millis(5));
    }
    stop.store(true, Ordering::Relaxed);
    let _ = reader.join();
    let ledger = Arc::try_unwrap(ledger)
        .map_or_else(|l| lock(&l).clone(), |m| m.into_inner().unwrap_or_else(PoisonError::into_inner));
    let (exchanges, counts, left_out) = ledger.finish(now_ns(origin));
    if exchanges.is_empty() {
        anyhow::bail!("nothing recorded: no probe was sent");
    }
    if counts.answered == 0 {
        let why = if refused.load(Ordering::Relaxed) > 0 {
            " (the host answered that nothing listens on that port: start `hilbench trace echo --listen HOST:PORT` there)"
        } else {
            " (is `hilbench trace echo` running there? a firewall?)"
        };
        anyhow::bail!(
            "--target {}: none of {} probes was answered{why}; nothing written",
            spec.target,
            counts.sent
        );
    }
    let mut provenance = delay::Provenance {
        source: Some(spec.target.clone()),
        when: Some(iso8601(wall_start)),
        rate_hz: Some(spec.rate_hz),
        probe_bytes: Some(spec.probe_bytes as u64),
        losses: Some(counts.lost),
        tool: Some(format!("hilbench {} trace record (UDP)", env!("CARGO_PKG_VERSION"))),
        other: vec![
            ("probes".into(), exchanges.len().to_string()),
            ("timeout_s".into(), spec.timeout_s.to_string()),
            ("late".into(), counts.late.to_string()),
            ("duplicates".into(), counts.duplicates.to_string()),
        ],
    };
    if slips > 0 {
        provenance.other.push(("ticks_skipped".into(), slips.to_string()));
    }
    let held_past = exchanges.iter().filter(|e| e.held_past_round_trip()).count();
    if held_past > 0 {
        provenance.other.push(("held_past_round_trip".into(), held_past.to_string()));
        eprintln!(
            "warning: {held_past} replies claim the echo held them longer than their whole round trip (recorded as 0 s): the far side's stamps are wrong"
        );
    }
    write(&spec.out, &probe::round_trips_s(&exchanges), &provenance)?;
    let mut written = vec![spec.out.clone()];
    if let Some(prefix) = &spec.out_directions {
        match probe::directions(&exchanges, OFFSET_WINDOW_NS) {
            Some(d) => {
                for (name, delays) in [("up", &d.up_s), ("down", &d.down_s)] {
                    let mut p = provenance.clone();
                    p.other.push((
                        "direction".into(),
                        format!("{name} (recorder {} echo)", if name == "up" { "to" } else { "from" }),
                    ));
                    p.other.push((
                        "clock_offset".into(),
                        "shortest round trip per 10 s window, interpolated".into(),
                    ));
                    p.other.push(("clamped_to_zero".into(), d.clamped.to_string()));
                    let path = with_suffix(prefix, name);
                    write(&path, delays, &p)?;
                    written.push(path);
                }
            }
            None => eprintln!(
                "--out-directions: the echo does not stamp its replies (not `hilbench trace echo`): only the round trips are written"
            ),
        }
    }
    if !quiet {
        let rtts: Vec<f64> =
            exchanges.iter().filter_map(|e| e.round_trip_ns()).map(|n| n as f64 * 1e-6).collect();
        eprintln!(
            "{} probes: {} answered, {} lost ({:.2} %), {} late, {} duplicate(s){}{}; median {:.3} ms, max {:.3} ms -> {}",
            exchanges.len(),
            counts.answered,
            counts.lost,
            100.0 * counts.lost as f64 / exchanges.len() as f64,
            counts.late,
            counts.duplicates,
            if left_out > 0 { format!(", {left_out} still waiting left out") } else { String::new() },
            if send_errors > 0 { format!(", {send_errors} send error(s)") } else { String::new() },
            median(&rtts),
            rtts.iter().copied().fold(0.0, f64::max),
            written.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        );
    }
    Ok(if interrupted.load(Ordering::Relaxed) { Exit::Interrupted } else { Exit::Success })
}

/// Refuses `path` (of `flag`) unless a file can be written there: its directory exists and
/// takes a new file, and it is not a directory. Nothing is left behind.
fn check_writable(path: &Path, flag: &str) -> anyhow::Result<()> {
    anyhow::ensure!(!path.is_dir(), "{flag} {}: is a directory, not a file", path.display());
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    anyhow::ensure!(dir.is_dir(), "{flag} {}: no directory {}", path.display(), dir.display());
    let probe = dir.join(format!(".hilbench-record-check-{}", std::process::id()));
    std::fs::File::create(&probe)
        .with_context(|| format!("{flag} {}: cannot write in {}", path.display(), dir.display()))?;
    let _ = std::fs::remove_file(&probe);
    if path.exists() {
        std::fs::OpenOptions::new()
            .append(true)
            .open(path)
            .with_context(|| format!("{flag} {}: cannot be written", path.display()))?;
    }
    Ok(())
}

/// `PREFIX-up.csv`.
fn with_suffix(prefix: &Path, name: &str) -> PathBuf {
    let mut s = prefix.as_os_str().to_owned();
    s.push(format!("-{name}.csv"));
    PathBuf::from(s)
}

fn write(path: &Path, delays: &[f64], provenance: &delay::Provenance) -> anyhow::Result<()> {
    let text =
        delay::write_trace(delays, provenance).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

/// The progress line: the counts, and the round trips settled since the last line.
fn progress(origin: Instant, l: &Ledger, since: usize) {
    let c = l.counts();
    let recent: Vec<f64> =
        l.settled()[since..].iter().filter_map(|e| e.round_trip_ns()).map(|n| n as f64 * 1e-6).collect();
    let max = recent.iter().copied().fold(0.0, f64::max);
    eprintln!(
        "  record: {:.0} s, {} sent, {} answered, {} lost; last {} s: median {:.3} ms, max {:.3} ms",
        origin.elapsed().as_secs_f64(),
        c.sent,
        c.answered,
        c.lost,
        PROGRESS_EVERY.as_secs(),
        median(&recent),
        max
    );
}

/// `YYYY-MM-DDTHH:MM:SSZ` of a wall-clock time (UTC).
fn iso8601(t: std::time::SystemTime) -> String {
    probe::iso8601_utc(t.duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()))
}

/// `hilbench trace echo`: answers probes on `listen` until Ctrl-C.
pub fn echo(listen: &str, quiet: bool) -> anyhow::Result<Exit> {
    let socket = UdpSocket::bind(listen).with_context(|| format!("--listen {listen}: cannot bind"))?;
    socket.set_read_timeout(Some(READ_TICK))?;
    let stop = Arc::new(AtomicBool::new(false));
    crate::fly::watch_ctrl_c(Arc::clone(&stop), "hilbench-echo-ctrl-c");
    let origin = Instant::now();
    if !quiet {
        eprintln!("echoing hilbench probes on {} (UDP) until Ctrl-C", socket.local_addr()?);
    }
    let (mut buf, mut reply) = (vec![0u8; 65_536], Vec::with_capacity(probe::MAX_PROBE_BYTES));
    let (mut answered, mut refused) = (0u64, 0u64);
    while !stop.load(Ordering::Relaxed) {
        let Ok((n, from)) = socket.recv_from(&mut buf) else { continue };
        let received_ns = now_ns(origin);
        let far = FarStamps { received_ns, sent_ns: now_ns(origin) };
        if probe::encode_reply(&buf[..n], far, &mut reply).is_ok() && n <= probe::MAX_PROBE_BYTES {
            let _ = socket.send_to(&reply, from);
            answered += 1;
        } else {
            refused += 1;
        }
    }
    if !quiet {
        eprintln!("echo: {answered} probe(s) answered, {refused} other datagram(s) ignored");
    }
    // Ctrl-C is how an echo ends.
    Ok(Exit::Success)
}
