//! Measurements other tools write, into a delay trace ([`delay::TraceFile`]: delays in s,
//! [`delay::LOST_S`] for each lost probe, in the order the probes were sent, and the
//! provenance the tool's output tells).
//!
//! - **ping** (Linux iputils and macOS): every reply line `... icmp_seq=N ... time=T ms` puts
//!   `T` at probe `N`; a probe without a reply is a loss. The probes run from the first one
//!   (iputils numbers from 1, macOS from 0, told apart by ping's first line; without it, the
//!   lowest number seen) to the last one transmitted (the summary's `N packets transmitted`,
//!   so losses at the end count too; without the summary, the highest number seen). Sequence
//!   numbers wrap at 65536 and are unwrapped; replies out of order go to their probe; a
//!   duplicate reply (`DUP!`) is counted and left out. `no answer yet`, `Request timeout`,
//!   `From ... icmp_seq=N Destination ...` lines are known and add nothing (the missing reply
//!   is the loss), as are the header, the summary and blank lines; a `[1795813059.422084]`
//!   prefix (`ping -D`) is dropped. Any other line is bad.
//! - **irtt** (`irtt client -o file.json`, JSON format 1): each of `round_trips` is probe
//!   `seqno`; `lost` other than `"false"` is a loss, else its `delay.rtt` (or the one-way
//!   `send` or `receive` delay, [`IrttDelay`]), ns. A round trip without that delay is bad.
//! - **CSV**: one column, by its header name or the only column; values in s, ms or us (from
//!   [`ImportOptions::unit`], else the column name's suffix `_s`, `_ms`, `_us`, else s); an
//!   empty cell or `lost` is a loss; `#` comments and blank lines are skipped. Cells are split
//!   at commas (quotes around a cell are removed; a quoted comma is not supported).
//!
//! A bad line is an error naming its line (a round trip: its index), unless
//! [`ImportOptions::skip_bad`], which skips it and counts it ([`Imported::skipped`]). A
//! skipped ping or irtt probe is a loss (its probe number is still sent); a skipped CSV row is
//! left out. Nothing here reads a file: the caller passes the text.

use delay::{LOST_S, MAX_DELAY_S, Provenance, TraceFile};

/// What the text is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// `ping` output, Linux iputils or macOS.
    Ping,
    /// irtt's JSON (`irtt client -o`).
    Irtt,
    /// A CSV column.
    Csv,
}

impl std::str::FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "ping" => Ok(Format::Ping),
            "irtt" => Ok(Format::Irtt),
            "csv" => Ok(Format::Csv),
            _ => Err(format!("unknown format `{s}` (ping, irtt or csv)")),
        }
    }
}

/// The unit of a CSV column's values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    S,
    Ms,
    Us,
}

impl Unit {
    /// Seconds per unit.
    pub fn seconds(self) -> f64 {
        match self {
            Unit::S => 1.0,
            Unit::Ms => 1e-3,
            Unit::Us => 1e-6,
        }
    }

    /// The power of ten of a second.
    fn exponent(self) -> i32 {
        match self {
            Unit::S => 0,
            Unit::Ms => -3,
            Unit::Us => -6,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Unit::S => "s",
            Unit::Ms => "ms",
            Unit::Us => "us",
        }
    }

    /// The unit a column name ends with (`rtt_ms`), if any.
    fn of_column(name: &str) -> Option<Unit> {
        let lower = name.to_ascii_lowercase();
        [("_ms", Unit::Ms), ("_us", Unit::Us), ("_s", Unit::S)]
            .into_iter()
            .find(|(suffix, _)| lower.ends_with(suffix))
            .map(|(_, u)| u)
    }
}

impl std::str::FromStr for Unit {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "s" => Ok(Unit::S),
            "ms" => Ok(Unit::Ms),
            "us" => Ok(Unit::Us),
            _ => Err(format!("unknown unit `{s}` (s, ms or us)")),
        }
    }
}

/// Which of irtt's delays a trace takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum IrttDelay {
    /// The round trip (what the bench's `[scenario.delays]` round trip is).
    #[default]
    Rtt,
    /// Client to server, one way (meaningful only with synchronised clocks).
    Send,
    /// Server to client, one way (same caveat).
    Receive,
}

/// How to read the text.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportOptions {
    pub format: Format,
    /// CSV: the column's header name (default: the only column).
    pub column: Option<String>,
    /// CSV: the values' unit (default: the column name's suffix, else s). Ping's are ms and
    /// irtt's ns, as those tools write them: a unit given for them is refused.
    pub unit: Option<Unit>,
    /// Skip and count bad lines instead of refusing the text.
    pub skip_bad: bool,
    /// irtt: which delay.
    pub irtt_delay: IrttDelay,
    /// Probes per second, for the provenance: over what the text says (ping -D's stamps,
    /// irtt's interval), else the only source for a CSV or a plain ping log.
    pub rate_hz: Option<f64>,
}

impl ImportOptions {
    /// `format` with every other option at its default.
    pub fn new(format: Format) -> Self {
        Self { format, column: None, unit: None, skip_bad: false, irtt_delay: IrttDelay::Rtt, rate_hz: None }
    }
}

/// A line left out by [`ImportOptions::skip_bad`].
#[derive(Debug, Clone, PartialEq)]
pub struct Skipped {
    /// 1-based line (irtt: the round trip's index in `round_trips`).
    pub line: usize,
    pub reason: String,
}

/// What an import gives.
#[derive(Debug, Clone, PartialEq)]
pub struct Imported {
    /// The entries in probe order and the provenance (`losses` set to the losses found).
    pub trace: TraceFile,
    /// How many lines were skipped as bad.
    pub skipped: usize,
    /// The first [`Imported::SKIPPED_KEPT`] of them, for the report.
    pub skipped_first: Vec<Skipped>,
    /// Duplicate replies left out (ping's `DUP!`, irtt's repeated `seqno`).
    pub duplicates: usize,
}

impl Imported {
    /// How many skipped lines [`Imported::skipped_first`] keeps.
    pub const SKIPPED_KEPT: usize = 10;
}

/// Why a text cannot be imported.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImportError {
    /// A bad line (irtt: `round_trips[line - 1]`).
    #[error("line {line}: {reason}")]
    Line { line: usize, reason: String },
    /// The text as a whole (no probe, bad JSON, a column not there, a contradicting option).
    #[error("{0}")]
    Text(String),
}

/// Bad lines: refused, or skipped and counted.
struct Bad {
    skip: bool,
    count: usize,
    first: Vec<Skipped>,
}

impl Bad {
    fn new(skip: bool) -> Self {
        Self { skip, count: 0, first: Vec::new() }
    }

    /// `Ok` when the line is skipped, else the error.
    fn line(&mut self, line: usize, reason: String) -> Result<(), ImportError> {
        if !self.skip {
            return Err(ImportError::Line { line, reason });
        }
        self.count += 1;
        if self.first.len() < Imported::SKIPPED_KEPT {
            self.first.push(Skipped { line, reason });
        }
        Ok(())
    }
}

/// Imports `text` as `options` say.
pub fn import(text: &str, options: &ImportOptions) -> Result<Imported, ImportError> {
    // A byte-order mark (a spreadsheet's UTF-8 export) is no part of the first line.
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    if let Some(r) = options.rate_hz
        && !(r.is_finite() && r > 0.0 && r <= MAX_RATE_HZ)
    {
        return Err(ImportError::Text(format!("--rate-hz must be in (0, {MAX_RATE_HZ}], got {r}")));
    }
    if options.format != Format::Csv {
        if let Some(u) = options.unit {
            return Err(ImportError::Text(format!(
                "--unit {} applies to csv only (ping writes ms, irtt ns)",
                u.name()
            )));
        }
        if options.column.is_some() {
            return Err(ImportError::Text("--column applies to csv only".into()));
        }
    }
    let mut imported = match options.format {
        Format::Ping => ping(text, options.skip_bad),
        Format::Irtt => irtt(text, options.irtt_delay, options.skip_bad),
        Format::Csv => csv(text, options.column.as_deref(), options.unit, options.skip_bad),
    }?;
    if options.rate_hz.is_some() {
        imported.trace.provenance.rate_hz = options.rate_hz;
    }
    Ok(imported)
}

/// A CSV column whose unit is not said is read as seconds only while its median stays below
/// this, s: above, the values are most likely ms, and the unit is asked for.
pub const ASSUMED_SECONDS_MAX_MEDIAN_S: f64 = 1.0;

/// The highest probe rate an import takes, Hz (a probe every 10 µs).
pub const MAX_RATE_HZ: f64 = 100_000.0;

/// Most entries an imported trace holds (ten million probes: 28 hours at 100 Hz). A log that
/// claims more (a `packets transmitted` count or a sequence number far past the probes it
/// holds) is refused before anything is allocated for it.
pub const MAX_ENTRIES: u64 = 10_000_000;

/// Probes by (unwrapped) number: the delay of each reply, for ping and irtt.
struct Probes {
    /// `(probe number, delay_s)`; `None` for a probe known lost (irtt).
    seen: Vec<(u64, Option<f64>)>,
}

impl Probes {
    /// The entries from `first` to `last` (inclusive), a loss where no delay was seen; the
    /// duplicates found. Refused past [`MAX_ENTRIES`], naming `claim`, what set the span.
    fn entries(mut self, first: u64, last: u64, claim: &str) -> Result<(Vec<f64>, usize), ImportError> {
        let span = last.saturating_sub(first).saturating_add(1);
        if span > MAX_ENTRIES {
            return Err(ImportError::Text(format!(
                "{claim}: probes {first} to {last} would be {span} entries, more than the {MAX_ENTRIES} a trace \
                 holds ({} replies seen); import a part of the log",
                self.seen.len()
            )));
        }
        let n = usize::try_from(span).unwrap_or(usize::MAX);
        let mut out = vec![LOST_S; n];
        let mut filled = vec![false; n];
        let mut duplicates = 0;
        self.seen.sort_by_key(|(k, _)| *k);
        for (k, d) in self.seen {
            let Some(i) = k.checked_sub(first).and_then(|i| usize::try_from(i).ok()).filter(|i| *i < n)
            else {
                continue;
            };
            if std::mem::replace(&mut filled[i], true) {
                duplicates += 1;
                continue;
            }
            if let Some(d) = d {
                out[i] = d;
            }
        }
        Ok((out, duplicates))
    }
}

/// The value after `key` up to the next blank (`icmp_seq=12 ttl` gives `12`).
fn value_after<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    let at = line.find(key)? + key.len();
    let rest = &line[at..];
    let end = rest.find(|c: char| c.is_ascii_whitespace()).unwrap_or(rest.len());
    Some(&rest[..end])
}

/// `icmp_seq=N` or macOS's `icmp_seq N` (in `Request timeout for icmp_seq N`).
fn icmp_seq(line: &str) -> Option<Result<u16, String>> {
    let v = value_after(line, "icmp_seq=").or_else(|| value_after(line, "icmp_seq "))?;
    Some(v.parse::<u16>().map_err(|_| format!("icmp_seq `{}` is not a number in 0..=65535", clip(v))))
}

/// Unwraps 16-bit sequence numbers: each to the value nearest the previous one.
struct Unwrap {
    last: Option<u64>,
}

impl Unwrap {
    fn next(&mut self, raw: u16) -> u64 {
        let v = match self.last {
            None => u64::from(raw) + (1 << 16),
            Some(last) => {
                let base = (last & !0xFFFF) | u64::from(raw);
                [base.wrapping_sub(1 << 16), base, base + (1 << 16)]
                    .into_iter()
                    .min_by_key(|c| c.abs_diff(last))
                    .unwrap_or(base)
            }
        };
        // Starting one wrap up keeps a probe just before the first one representable.
        self.last = Some(self.last.map_or(v, |l| l.max(v)));
        v
    }
}

fn ping(text: &str, skip_bad: bool) -> Result<Imported, ImportError> {
    let mut bad = Bad::new(skip_bad);
    let mut probes = Probes { seen: Vec::new() };
    let mut unwrap = Unwrap { last: None };
    let mut dup_lines = 0;
    let mut transmitted: Option<u64> = None;
    let mut provenance = Provenance::default();
    let mut macos = false;
    let mut lowest: Option<u64> = None;
    let mut highest: Option<u64> = None;
    let mut note = |k: u64| {
        lowest = Some(lowest.map_or(k, |l| l.min(k)));
        highest = Some(highest.map_or(k, |h| h.max(k)));
    };
    // `ping -D`'s stamps of the replies, `(probe number, Unix s)`: the rate they imply.
    let mut stamped: Vec<(u64, f64)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        let mut line = raw.trim();
        let mut stamp_s = None;
        // `ping -D`: `[1795813059.422084] 64 bytes from ...`
        if line.starts_with('[')
            && let Some(end) = line.find(']')
        {
            stamp_s = line[1..end].parse::<f64>().ok().filter(|t| t.is_finite());
            line = line[end + 1..].trim_start();
        }
        if line.is_empty() {
            continue;
        }
        if let Some(rest) = line.strip_prefix("PING ") {
            // Linux: `PING host (addr) 56(84) bytes of data.`; macOS: `PING host (addr): 56 data bytes`.
            macos = rest.contains("data bytes");
            provenance.source = rest.split_whitespace().next().map(str::to_string);
            let bytes = if macos {
                rest.split_once("):").and_then(|(_, b)| b.split_whitespace().next())
            } else {
                rest.split_once(") ").and_then(|(_, b)| b.split('(').next())
            };
            provenance.probe_bytes = bytes.and_then(|b| b.trim().parse().ok());
            provenance.tool = Some(if macos { "ping (macOS)" } else { "ping (iputils)" }.to_string());
            continue;
        }
        if line.starts_with("---") || line.starts_with("rtt ") || line.starts_with("round-trip ") {
            continue;
        }
        if let Some((n, _)) = line.split_once(" packets transmitted") {
            match n.trim().parse() {
                Ok(n) => transmitted = Some(n),
                Err(_) => bad.line(line_no, format!("`{}` packets transmitted is not a number", clip(n)))?,
            }
            continue;
        }
        let seq = match icmp_seq(line) {
            Some(Ok(s)) => s,
            Some(Err(reason)) => {
                bad.line(line_no, reason)?;
                continue;
            }
            None => {
                bad.line(line_no, format!("not a line of ping's output: `{}`", clip(line)))?;
                continue;
            }
        };
        let no_reply = line.starts_with("no answer yet")
            || line.starts_with("Request timeout")
            || line.starts_with("From ");
        if no_reply {
            note(unwrap.next(seq));
            continue;
        }
        if !line.contains("bytes from") {
            bad.line(line_no, format!("not a line of ping's output: `{}`", clip(line)))?;
            continue;
        }
        let k = unwrap.next(seq);
        note(k);
        if let Some(t) = stamp_s {
            stamped.push((k, t));
        }
        if line.contains("DUP!") {
            dup_lines += 1;
            continue;
        }
        let Some(t) = value_after(line, "time=") else {
            bad.line(line_no, "a reply without `time=`".into())?;
            continue;
        };
        let ms = t.strip_suffix("ms").unwrap_or(t);
        let unit_ms = t.ends_with("ms") || line[line.find("time=").unwrap_or(0)..].contains(" ms");
        match parse_scaled(ms, -3) {
            Some(v) if unit_ms && (0.0..=MAX_DELAY_S).contains(&v) => probes.seen.push((k, Some(v))),
            Some(v) if unit_ms => bad.line(
                line_no,
                format!("time {} ms is not a delay in [0, {MAX_DELAY_S}] s ({v:e} s)", clip(ms)),
            )?,
            _ => bad.line(line_no, format!("time `{}` is not a number of ms", clip(t)))?,
        }
    }
    let Some(hi) = highest else {
        return Err(ImportError::Text("no probe: not ping's output, or it sent nothing".into()));
    };
    let lo = lowest.unwrap_or(hi);
    // The first probe by the header's numbering (1 on Linux, 0 on macOS), unless the lowest
    // number seen is below (a ping that did not start there) or far above (a wrapped one).
    let start = if provenance.tool.is_some() { Some(if macos { 0 } else { 1 }) } else { None };
    let first = match start {
        Some(s) => {
            let s = (1u64 << 16) + s;
            if lo >= s && lo - s < 1 << 15 { s } else { lo }
        }
        None => lo,
    };
    let (last, claim) = match transmitted {
        Some(n) if n > 0 && first.saturating_add(n - 1) > hi => {
            (first.saturating_add(n - 1), format!("`{n} packets transmitted`"))
        }
        _ => (hi, format!("icmp_seq up to {hi}")),
    };
    let (delays_s, repeated) = probes.entries(first, last, &claim)?;
    provenance.rate_hz = stamped_rate_hz(&stamped);
    finish(delays_s, provenance, bad, dup_lines + repeated)
}

/// The probe rate of `ping -D`'s stamps, Hz: the probes between the first and the last stamped
/// reply over the time between them (each reply's stamp is its send time plus its delay, so
/// the delays' spread is the error, over the whole span). `None` for fewer than two.
fn stamped_rate_hz(stamped: &[(u64, f64)]) -> Option<f64> {
    let first = stamped.iter().min_by_key(|(k, _)| *k)?;
    let last = stamped.iter().max_by_key(|(k, _)| *k)?;
    let span_s = last.1 - first.1;
    (last.0 > first.0 && span_s > 0.0).then(|| {
        let rate = (last.0 - first.0) as f64 / span_s;
        // Four significant digits: what the stamps can say.
        let scale = 10f64.powi(3 - rate.log10().floor() as i32);
        (rate * scale).round() / scale
    })
}

/// The number `text` times `10^exp`, rounded once: `0.047` ms is `0.047e-3` s, read as
/// written (`0.047 * 1e-3` would be `4.7000000000000004e-5`). `None` if `text` is no number.
fn parse_scaled(text: &str, exp: i32) -> Option<f64> {
    if exp == 0 || text.contains(['e', 'E']) || text.len() > 48 || !(-9..0).contains(&exp) {
        let v: f64 = text.parse().ok()?;
        return Some(if exp == 0 { v } else { v / 10f64.powi(-exp) });
    }
    // Only a plain decimal gets the exponent appended (`inf`, `nan` fail to parse then).
    if !text.bytes().all(|b| b.is_ascii_digit() || b == b'.' || b == b'-' || b == b'+') {
        return None;
    }
    let mut buf = [0u8; 52];
    let n = text.len();
    buf[..n].copy_from_slice(text.as_bytes());
    buf[n..n + 3].copy_from_slice(&[b'e', b'-', b'0' + (-exp) as u8]);
    std::str::from_utf8(&buf[..n + 3]).ok()?.parse().ok()
}

/// At most 60 characters of `s`, for messages.
fn clip(s: &str) -> String {
    if s.chars().count() <= 60 {
        s.to_string()
    } else {
        format!("{}...", s.chars().take(60).collect::<String>())
    }
}

fn finish(
    delays_s: Vec<f64>,
    mut provenance: Provenance,
    bad: Bad,
    duplicates: usize,
) -> Result<Imported, ImportError> {
    if delays_s.is_empty() {
        return Err(ImportError::Text("holds no delay".into()));
    }
    let losses = delays_s.iter().filter(|d| delay::is_lost(**d)).count();
    provenance.losses = Some(losses as u64);
    Ok(Imported {
        trace: TraceFile { delays_s, provenance },
        skipped: bad.count,
        skipped_first: bad.first,
        duplicates,
    })
}

/// irtt's JSON, the parts read.
mod irtt_json {
    #[derive(serde::Deserialize)]
    pub struct Output {
        #[serde(default)]
        pub version: Option<Version>,
        #[serde(default)]
        pub config: Option<Config>,
        #[serde(default)]
        pub stats: Option<Stats>,
        pub round_trips: Vec<serde_json::Value>,
    }
    #[derive(serde::Deserialize)]
    pub struct Version {
        pub irtt: Option<String>,
    }
    #[derive(serde::Deserialize)]
    pub struct Config {
        pub remote_address: Option<String>,
        pub params: Option<Params>,
    }
    #[derive(serde::Deserialize)]
    pub struct Params {
        /// ns
        pub interval: Option<f64>,
        pub length: Option<u64>,
    }
    #[derive(serde::Deserialize)]
    pub struct Stats {
        pub start_time: Option<String>,
    }
    #[derive(serde::Deserialize)]
    pub struct RoundTrip {
        pub seqno: u64,
        pub lost: String,
        #[serde(default)]
        pub delay: Delay,
    }
    #[derive(serde::Deserialize, Default)]
    pub struct Delay {
        pub rtt: Option<f64>,
        pub send: Option<f64>,
        pub receive: Option<f64>,
    }
}

fn irtt(text: &str, which: IrttDelay, skip_bad: bool) -> Result<Imported, ImportError> {
    let out: irtt_json::Output =
        serde_json::from_str(text).map_err(|e| ImportError::Text(format!("not irtt's JSON: {e}")))?;
    let mut bad = Bad::new(skip_bad);
    let mut probes = Probes { seen: Vec::with_capacity(out.round_trips.len()) };
    let mut lo = u64::MAX;
    let mut hi = 0;
    for (i, value) in out.round_trips.into_iter().enumerate() {
        let at = i + 1;
        let rt: irtt_json::RoundTrip = match serde_json::from_value(value) {
            Ok(rt) => rt,
            Err(e) => {
                bad.line(at, format!("round_trips[{i}]: {e}"))?;
                continue;
            }
        };
        lo = lo.min(rt.seqno);
        hi = hi.max(rt.seqno);
        let delay_ns = match which {
            IrttDelay::Rtt => rt.delay.rtt,
            IrttDelay::Send => rt.delay.send,
            IrttDelay::Receive => rt.delay.receive,
        };
        match (rt.lost.as_str(), delay_ns) {
            ("false", Some(ns)) if ns.is_finite() && ns >= 0.0 && ns * 1e-9 <= MAX_DELAY_S => {
                // irtt writes whole nanoseconds: read `119984` as `119984e-9` s.
                let s = if ns.fract() == 0.0 { parse_scaled(&format!("{ns}"), -9) } else { None };
                probes.seen.push((rt.seqno, Some(s.unwrap_or(ns * 1e-9))))
            }
            ("false", Some(ns)) => {
                bad.line(at, format!("round_trips[{i}] (seqno {}): delay {ns} ns out of range", rt.seqno))?
            }
            ("false", None) => bad.line(
                at,
                format!("round_trips[{i}] (seqno {}): not lost and no {which:?} delay", rt.seqno)
                    .to_lowercase(),
            )?,
            ("true" | "true_up" | "true_down", _) => probes.seen.push((rt.seqno, None)),
            (other, _) => bad.line(at, format!("round_trips[{i}]: unknown `lost` value `{other}`"))?,
        }
    }
    if lo > hi {
        return Err(ImportError::Text("irtt's JSON holds no round trip".into()));
    }
    let (delays_s, duplicates) = probes.entries(lo, hi, &format!("seqno {lo} to {hi}"))?;
    let mut provenance = Provenance::default();
    if let Some(c) = &out.config {
        provenance.source = c.remote_address.clone();
        if let Some(p) = &c.params {
            provenance.rate_hz = p.interval.filter(|ns| *ns > 0.0).map(|ns| 1e9 / ns);
            provenance.probe_bytes = p.length;
        }
    }
    provenance.when = out.stats.and_then(|s| s.start_time);
    let version = out.version.and_then(|v| v.irtt).unwrap_or_default();
    provenance.tool = Some(format!("irtt {version}").trim().to_string());
    if which != IrttDelay::Rtt {
        provenance.other.push(("delay".into(), format!("{which:?}").to_lowercase()));
    }
    finish(delays_s, provenance, bad, duplicates)
}

/// The cells of a CSV line (quotes around a cell removed).
fn cells(line: &str) -> impl Iterator<Item = &str> {
    line.split(',').map(|c| {
        let c = c.trim();
        c.strip_prefix('"').and_then(|c| c.strip_suffix('"')).unwrap_or(c).trim()
    })
}

fn csv(
    text: &str,
    column: Option<&str>,
    unit: Option<Unit>,
    skip_bad: bool,
) -> Result<Imported, ImportError> {
    let mut bad = Bad::new(skip_bad);
    let mut delays_s = Vec::new();
    let mut index: Option<usize> = None; // the column, once the first row is read
    let mut width = 0;
    let mut scale = unit.unwrap_or(Unit::S);
    // Whether the unit was said (--unit, or the column's suffix) rather than taken as s.
    let mut unit_said = unit.is_some();
    let mut column_name = String::from("the column");
    for (i, raw) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let col = if let Some(col) = index {
            col
        } else {
            // The first row: a header if any cell is not a number (nor a loss).
            let row: Vec<&str> = cells(line).collect();
            let header = row.iter().any(|c| c.parse::<f64>().is_err() && !c.is_empty() && *c != "lost");
            width = row.len();
            let col = if header {
                let i = match column {
                    Some(name) => row.iter().position(|c| *c == name).ok_or_else(|| {
                        ImportError::Text(format!(
                            "line {line_no}: no column `{}` (columns: {})",
                            clip(name),
                            clip(&row.join(", "))
                        ))
                    })?,
                    None if row.len() == 1 => 0,
                    None => {
                        return Err(ImportError::Text(format!(
                            "line {line_no}: {} columns ({}); name one with --column",
                            row.len(),
                            clip(&row.join(", "))
                        )));
                    }
                };
                if let Some(named) = Unit::of_column(row[i]) {
                    match unit {
                        Some(u) if u != named => {
                            return Err(ImportError::Text(format!(
                                "column `{}` says {} but --unit is {}",
                                clip(row[i]),
                                named.name(),
                                u.name()
                            )));
                        }
                        _ => scale = named,
                    }
                    unit_said = true;
                }
                column_name = format!("column `{}`", clip(row[i]));
                i
            } else {
                if let Some(name) = column {
                    return Err(ImportError::Text(format!(
                        "line {line_no}: no header row, so no column `{name}`"
                    )));
                }
                if row.len() != 1 {
                    return Err(ImportError::Text(format!(
                        "line {line_no}: {} columns and no header; name one with --column",
                        row.len()
                    )));
                }
                0
            };
            index = Some(col);
            if header {
                continue;
            }
            col
        };
        let mut n = 0;
        let mut cell = None;
        for (k, c) in cells(line).enumerate() {
            n += 1;
            if k == col {
                cell = Some(c);
            }
        }
        if n != width {
            bad.line(line_no, format!("{n} cells, the first row has {width}"))?;
            continue;
        }
        let c = cell.unwrap_or("");
        if c.is_empty() || c == "lost" {
            delays_s.push(LOST_S);
            continue;
        }
        match parse_scaled(c, scale.exponent()) {
            Some(v) if (0.0..=MAX_DELAY_S).contains(&v) => delays_s.push(v),
            Some(_) => bad.line(
                line_no,
                format!("{} {} is not a delay in [0, {MAX_DELAY_S}] s", clip(c), scale.name()),
            )?,
            None => bad.line(line_no, format!("`{}` is not a number (nor empty or `lost`)", clip(c)))?,
        }
    }
    if delays_s.is_empty() {
        return Err(ImportError::Text("holds no delay".into()));
    }
    // Seconds were assumed: a median round trip of a second or more is most likely ms (a
    // column `rtt` of 40 to 69 would be 40 to 69 s delays); the user says which.
    let mut delivered: Vec<f64> = delays_s.iter().copied().filter(|d| !delay::is_lost(*d)).collect();
    delivered.sort_by(f64::total_cmp);
    if let Some(median) = delivered.get(delivered.len() / 2)
        && !unit_said
        && *median >= ASSUMED_SECONDS_MAX_MEDIAN_S
    {
        return Err(ImportError::Text(format!(
            "{column_name} names no unit and its median is {median} s if the values are seconds: \
             give --unit s, ms or us (or name the column with a suffix, e.g. rtt_ms)"
        )));
    }
    finish(delays_s, Provenance { tool: Some("csv".into()), ..Provenance::default() }, bad, 0)
}

#[cfg(test)]
mod tests;
