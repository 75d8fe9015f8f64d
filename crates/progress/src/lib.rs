//! Progress of the long commands, followable on a terminal *and* in a log file.
//!
//! - On a terminal (stderr is a TTY) a [`Progress`] is an indicatif bar, as it always was.
//! - Otherwise (`depthsense train … > train.log 2>&1`, Slurm, nohup, torchrun, CI), where
//!   indicatif draws nothing, it prints plain lines on stderr: one every `--log-every`
//!   ([`LogEvery`], default 30 s) with the position, the caller's message (epoch, loss, lr,
//!   img/s), the rate and the ETA; every [`Progress::println`] (start lines, validations,
//!   notes); and one closing line when it finishes. Each line starts with the UTC time.
//! - `DEPTHSENSE_PROGRESS=bars|lines|none` overrides the choice ([`Mode::detect`]).
//!
//! A [`Board`] holds several bars at once (the demo's stages, an experiment's runs).

use std::collections::VecDeque;
use std::fmt;
use std::io::IsTerminal;
use std::str::FromStr;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use indicatif::{MultiProgress, ProgressBar, ProgressStyle};

/// How often a progress line is printed when stderr is not a terminal (`--log-every`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LogEvery {
    /// At most one line per this many seconds (`30s`, `2m`, `1h`; a bare number is seconds).
    Seconds(f64),
    /// One line per this many steps of the bar (`100it`: iterations, samples, keyframes).
    Iterations(u64),
}

impl Default for LogEvery {
    fn default() -> Self {
        LogEvery::Seconds(30.0)
    }
}

/// A `--log-every` value that is neither a duration nor a step count.
#[derive(Debug, thiserror::Error)]
#[error("--log-every {0:?}: expected seconds (`30s`, `2m`, `1h`, or a bare number) or steps (`100it`), greater than 0")]
pub struct BadLogEvery(String);

impl FromStr for LogEvery {
    type Err = BadLogEvery;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || BadLogEvery(s.to_string());
        let t = s.trim().to_ascii_lowercase();
        if let Some(n) = t.strip_suffix("it") {
            let n: u64 = n.trim().parse().map_err(|_| bad())?;
            return if n > 0 {
                Ok(LogEvery::Iterations(n))
            } else {
                Err(bad())
            };
        }
        let (num, scale) = match t.chars().last() {
            Some('s') => (&t[..t.len() - 1], 1.0),
            Some('m') => (&t[..t.len() - 1], 60.0),
            Some('h') => (&t[..t.len() - 1], 3600.0),
            _ => (t.as_str(), 1.0),
        };
        let v: f64 = num.trim().parse().map_err(|_| bad())?;
        if v.is_finite() && v > 0.0 {
            Ok(LogEvery::Seconds(v * scale))
        } else {
            Err(bad())
        }
    }
}

impl fmt::Display for LogEvery {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LogEvery::Seconds(s) => write!(f, "{s}s"),
            LogEvery::Iterations(n) => write!(f, "{n}it"),
        }
    }
}

/// How progress is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// indicatif bars (stderr is a terminal).
    Bars,
    /// Plain lines (stderr is a file or a pipe).
    Lines,
    /// Nothing (tests, library calls).
    Hidden,
}

impl Mode {
    /// `DEPTHSENSE_PROGRESS` (`bars`, `lines` or `none`) when set, else bars on a terminal and
    /// lines otherwise.
    pub fn detect() -> Mode {
        match std::env::var("DEPTHSENSE_PROGRESS")
            .unwrap_or_default()
            .to_ascii_lowercase()
            .as_str()
        {
            "bars" | "bar" => Mode::Bars,
            "lines" | "plain" => Mode::Lines,
            "none" | "off" | "hidden" => Mode::Hidden,
            _ if std::io::stderr().is_terminal() => Mode::Bars,
            _ => Mode::Lines,
        }
    }
}

static LOG_EVERY: OnceLock<LogEvery> = OnceLock::new();

/// Sets the process's `--log-every` (once, from the command line; later calls are ignored).
pub fn configure(every: LogEvery) {
    let _ = LOG_EVERY.set(every);
}

/// The process's `--log-every` ([`LogEvery::default`] unless [`configure`]d).
pub fn log_every() -> LogEvery {
    LOG_EVERY.get().copied().unwrap_or_default()
}

/// One line on stderr as every mode prints it: with the UTC time in front when stderr is not a
/// terminal (so that a log file tells when things happened).
pub fn note(msg: &str) {
    match Mode::detect() {
        Mode::Lines => eprintln!("{} {msg}", utc_stamp(SystemTime::now())),
        _ => eprintln!("{msg}"),
    }
}

/// The state of a plain-line progress.
struct Lines {
    every: LogEvery,
    state: Mutex<LineState>,
}

struct LineState {
    created: Instant,
    /// Time and position of the first position update: the rate and ETA count from here (a
    /// resumed run starts at its iteration, not at 0).
    origin: Option<(Instant, u64)>,
    /// Time and position of the last line printed.
    last: (Instant, u64),
    /// The latest position updates (at most [`RATE_WINDOW`], none older than
    /// [`RATE_WINDOW_SECS`] but the last two): the rate and ETA of a line are this window's,
    /// so that a slow start (set-up, the first validation, a loaded machine) stops weighing on
    /// the estimate once it is past.
    recent: VecDeque<(Instant, u64)>,
    finished: bool,
}

/// Position updates in the rate's moving window.
const RATE_WINDOW: usize = 32;
/// The moving window's longest span.
const RATE_WINDOW_SECS: f64 = 120.0;

impl LineState {
    /// Records an update at `pos`.
    fn record(&mut self, now: Instant, pos: u64) {
        if self.recent.back().is_some_and(|&(_, p)| p == pos) {
            return;
        }
        // The first step's time is set-up (data, the first validation, autotuning): the window
        // starts when it ends.
        if self.recent.len() == 1 && self.origin.is_some_and(|(_, p0)| self.recent[0].1 == p0) {
            self.recent.clear();
        }
        self.recent.push_back((now, pos));
        while self.recent.len() > RATE_WINDOW
            || (self.recent.len() > 2
                && self
                    .recent
                    .front()
                    .is_some_and(|&(t, _)| now.duration_since(t).as_secs_f64() > RATE_WINDOW_SECS))
        {
            self.recent.pop_front();
        }
    }

    /// Steps per second over the moving window (at `now`, position `pos`).
    fn rate(&self, now: Instant, pos: u64) -> Option<f64> {
        let &(t0, p0) = self.recent.front()?;
        let secs = now.duration_since(t0).as_secs_f64();
        let done = pos.saturating_sub(p0);
        (done > 0 && secs > 0.0).then(|| done as f64 / secs)
    }
}

/// A progress bar on a terminal, plain lines in a log file, or nothing (module docs).
#[derive(Clone)]
pub struct Progress {
    name: Arc<str>,
    bar: ProgressBar,
    lines: Option<Arc<Lines>>,
}

const TEMPLATE: &str = "[{bar:30}] {pos}/{len} {elapsed_precise} ETA {eta} {msg}";

impl Progress {
    /// A progress named `name` (the bar's prefix, the lines' subject) in the detected mode.
    pub fn new(name: &str) -> Self {
        Self::build(name, Mode::detect(), log_every(), 6, None)
    }

    /// A progress that shows nothing.
    pub fn hidden() -> Self {
        Progress {
            name: Arc::from(""),
            bar: ProgressBar::hidden(),
            lines: None,
        }
    }

    /// A plain-line progress whatever stderr is (tests).
    pub fn lines(name: &str, every: LogEvery) -> Self {
        Self::build(name, Mode::Lines, every, 6, None)
    }

    fn build(
        name: &str,
        mode: Mode,
        every: LogEvery,
        width: usize,
        board: Option<&MultiProgress>,
    ) -> Self {
        match mode {
            Mode::Hidden => Self::hidden(),
            Mode::Bars => {
                let bar = ProgressBar::new(0);
                bar.set_style(
                    ProgressStyle::with_template(&format!("{{prefix:>{width}.bold}} {TEMPLATE}"))
                        .unwrap_or_else(|_| ProgressStyle::default_bar())
                        .progress_chars("=> "),
                );
                bar.set_prefix(name.to_string());
                let bar = match board {
                    Some(mp) => mp.add(bar),
                    None => bar,
                };
                Progress {
                    name: Arc::from(name),
                    bar,
                    lines: None,
                }
            }
            Mode::Lines => {
                let now = Instant::now();
                Progress {
                    name: Arc::from(name),
                    bar: ProgressBar::hidden(),
                    lines: Some(Arc::new(Lines {
                        every,
                        state: Mutex::new(LineState {
                            created: now,
                            origin: None,
                            last: (now, 0),
                            recent: VecDeque::new(),
                            finished: false,
                        }),
                    })),
                }
            }
        }
    }

    /// Total number of steps.
    pub fn set_length(&self, len: u64) {
        self.bar.set_length(len);
    }

    /// Moves to step `pos` (a resumed run's first call sets where the rate counts from).
    pub fn set_position(&self, pos: u64) {
        self.set_origin(pos);
        self.bar.set_position(pos);
        self.maybe_line();
    }

    /// Advances by `delta` steps.
    pub fn inc(&self, delta: u64) {
        self.set_origin(self.bar.position());
        self.bar.inc(delta);
        self.maybe_line();
    }

    /// What the bar shows after its counts, and what the next progress line carries.
    pub fn set_message(&self, msg: impl Into<String>) {
        self.bar.set_message(msg.into());
    }

    /// `NAME: msg` above the bars, or as a plain line in a log (start lines, validations,
    /// notes); nothing when hidden.
    pub fn println(&self, msg: impl AsRef<str>) {
        let line = if self.name.is_empty() {
            msg.as_ref().to_string()
        } else {
            format!("{}: {}", self.name, msg.as_ref())
        };
        match &self.lines {
            Some(_) => eprintln!("{} {line}", utc_stamp(SystemTime::now())),
            None => self.bar.println(line),
        }
    }

    /// The current step.
    pub fn position(&self) -> u64 {
        self.bar.position()
    }

    /// The total number of steps.
    pub fn length(&self) -> Option<u64> {
        self.bar.length()
    }

    /// Redraws a terminal bar at least every `every` (spinners of long single steps).
    pub fn enable_steady_tick(&self, every: Duration) {
        if self.lines.is_none() {
            self.bar.enable_steady_tick(every);
        }
    }

    /// Done: the bar stays; a log gets the closing line.
    pub fn finish(&self) {
        self.bar.finish();
        self.closing_line(None);
    }

    /// Done: the bar disappears; a log gets the closing line.
    pub fn finish_and_clear(&self) {
        self.bar.finish_and_clear();
        self.closing_line(None);
    }

    /// Done with a last message.
    pub fn finish_with_message(&self, msg: impl Into<String>) {
        let msg = msg.into();
        self.bar.finish_with_message(msg.clone());
        self.closing_line(Some(&msg));
    }

    fn set_origin(&self, pos: u64) {
        if let Some(l) = &self.lines {
            if let Ok(mut st) = l.state.lock() {
                if st.origin.is_none() {
                    let now = Instant::now();
                    st.origin = Some((now, pos));
                    st.last = (now, pos);
                    st.record(now, pos);
                }
            }
        }
    }

    fn maybe_line(&self) {
        let Some(l) = &self.lines else { return };
        let Ok(mut st) = l.state.lock() else { return };
        let now = Instant::now();
        let pos = self.bar.position();
        st.record(now, pos);
        let due = match l.every {
            LogEvery::Seconds(s) => now.duration_since(st.last.0).as_secs_f64() >= s,
            LogEvery::Iterations(n) => pos >= st.last.1.saturating_add(n),
        };
        if !due || pos == st.last.1 || st.finished {
            return;
        }
        st.last = (now, pos);
        let line = self.progress_line(&st, now);
        drop(st);
        eprintln!("{line}");
    }

    fn progress_line(&self, st: &LineState, now: Instant) -> String {
        let pos = self.bar.position();
        let mut s = format!("{} {}: {pos}", utc_stamp(SystemTime::now()), self.name);
        if let Some(len) = self.bar.length().filter(|&n| n > 0) {
            s += &format!("/{len} ({:.0} %)", 100.0 * pos as f64 / len as f64);
        }
        let msg = self.bar.message();
        if !msg.is_empty() {
            s += &format!(", {msg}");
        }
        let elapsed = now.duration_since(st.created);
        s += &format!("; elapsed {}", human(elapsed));
        if let Some(rate) = st.rate(now, pos) {
            s += &format!(", {rate:.2} steps/s");
            if let Some(len) = self.bar.length().filter(|&n| n >= pos) {
                let eta = (len - pos) as f64 / rate;
                s += &format!(", ETA {}", human(Duration::from_secs_f64(eta)));
            }
        }
        s
    }

    fn closing_line(&self, msg: Option<&str>) {
        let Some(l) = &self.lines else { return };
        let Ok(mut st) = l.state.lock() else { return };
        if st.finished {
            return;
        }
        st.finished = true;
        let pos = self.bar.position();
        let len = self
            .bar
            .length()
            .filter(|&n| n > 0)
            .map_or(String::new(), |n| format!("/{n}"));
        let tail = msg.map_or(String::new(), |m| format!(": {m}"));
        eprintln!(
            "{} {}: done, {pos}{len} in {}{tail}",
            utc_stamp(SystemTime::now()),
            self.name,
            human(st.created.elapsed())
        );
    }
}

/// Several progresses shown together: stacked bars on a terminal, interleaved lines in a log.
pub struct Board {
    mp: MultiProgress,
    mode: Mode,
    width: usize,
}

impl Board {
    /// A board in the detected mode whose bars' names are right-aligned to `width` columns.
    pub fn new(width: usize) -> Self {
        Board {
            mp: MultiProgress::new(),
            mode: Mode::detect(),
            width,
        }
    }

    /// A board that shows nothing (tests).
    pub fn hidden() -> Self {
        Board {
            mp: MultiProgress::with_draw_target(indicatif::ProgressDrawTarget::hidden()),
            mode: Mode::Hidden,
            width: 0,
        }
    }

    /// A new progress on the board.
    pub fn bar(&self, name: &str) -> Progress {
        Progress::build(name, self.mode, log_every(), self.width, Some(&self.mp))
    }

    /// A line above the bars, or a plain line in a log.
    pub fn println(&self, msg: impl AsRef<str>) {
        match self.mode {
            Mode::Bars => {
                let _ = self.mp.println(msg.as_ref());
            }
            Mode::Lines => eprintln!("{} {}", utc_stamp(SystemTime::now()), msg.as_ref()),
            Mode::Hidden => {}
        }
    }
}

/// `1h02m`, `2m05s`, `45s`, `0.4s`.
pub fn human(d: Duration) -> String {
    let s = d.as_secs_f64();
    if s < 10.0 {
        return format!("{s:.1}s");
    }
    let t = s.round() as u64;
    match (t / 3600, t / 60 % 60, t % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m{s:02}s"),
        (h, m, _) => format!("{h}h{m:02}m"),
    }
}

/// `2026-12-03T15:40:01Z`.
pub fn utc_stamp(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    depthsense_base::lock::utc_iso8601(secs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_every_words() {
        assert_eq!("30s".parse::<LogEvery>().unwrap(), LogEvery::Seconds(30.0));
        assert_eq!("2m".parse::<LogEvery>().unwrap(), LogEvery::Seconds(120.0));
        assert_eq!("1h".parse::<LogEvery>().unwrap(), LogEvery::Seconds(3600.0));
        assert_eq!("5".parse::<LogEvery>().unwrap(), LogEvery::Seconds(5.0));
        assert_eq!("0.5s".parse::<LogEvery>().unwrap(), LogEvery::Seconds(0.5));
        assert_eq!(
            "100it".parse::<LogEvery>().unwrap(),
            LogEvery::Iterations(100)
        );
        for bad in ["", "0", "0it", "-3s", "fast", "10 minutes", "nans"] {
            assert!(bad.parse::<LogEvery>().is_err(), "{bad:?} accepted");
        }
        assert_eq!(LogEvery::Iterations(7).to_string(), "7it");
        assert_eq!(
            LogEvery::Seconds(30.0)
                .to_string()
                .parse::<LogEvery>()
                .unwrap(),
            LogEvery::Seconds(30.0)
        );
    }

    #[test]
    fn stamps_and_durations() {
        // 2026-12-03T15:35:13Z = 1 796 312 113 s after the epoch.
        let t = UNIX_EPOCH + Duration::from_secs(1_796_312_113);
        assert_eq!(utc_stamp(t), "2026-12-03T15:35:13Z");
        assert_eq!(utc_stamp(UNIX_EPOCH), "1970-01-01T00:00:00Z");
        // A leap day.
        assert_eq!(
            utc_stamp(UNIX_EPOCH + Duration::from_secs(951_782_400)),
            "2000-02-29T00:00:00Z"
        );
        assert_eq!(human(Duration::from_millis(400)), "0.4s");
        assert_eq!(human(Duration::from_secs(45)), "45s");
        assert_eq!(human(Duration::from_secs(125)), "2m05s");
        assert_eq!(human(Duration::from_secs(3720)), "1h02m");
    }

    #[test]
    fn the_rate_is_the_moving_window_s_not_the_slow_start_s() {
        let t0 = Instant::now();
        let mut st = LineState {
            created: t0,
            origin: Some((t0, 0)),
            last: (t0, 0),
            recent: VecDeque::new(),
            finished: false,
        };
        st.record(t0, 0);
        // A first step of 100 s (set-up under load), then steps of 1 s each: from the first
        // step's end on, the rate is theirs.
        let at = |s: u64| t0 + Duration::from_secs(s);
        st.record(at(100), 1);
        assert_eq!(st.rate(at(100), 1), None, "one step: no rate yet");
        for i in 2..=6 {
            st.record(at(100 + i - 1), i);
        }
        let rate = st.rate(at(105), 6).unwrap();
        assert!(
            (rate - 1.0).abs() < 1e-9,
            "{rate}: the first step's 100 s are not counted"
        );
        for i in 7..=101 {
            st.record(at(100 + i - 1), i);
        }
        let rate = st.rate(at(200), 101).unwrap();
        assert!(
            (rate - 1.0).abs() < 1e-9,
            "{rate}: the window's steps of 1 s"
        );
        // Since the start it would read 101 / 200 ≈ 0.5 steps/s, an ETA twice as long.
        assert_eq!(st.recent.len(), RATE_WINDOW);
    }

    #[test]
    fn lines_count_from_the_first_position_and_close_once() {
        let p = Progress::lines("t", LogEvery::Iterations(2));
        p.set_length(10);
        p.set_position(4); // a resumed run: the origin
        let l = p.lines.as_ref().unwrap();
        assert_eq!(l.state.lock().unwrap().origin.map(|o| o.1), Some(4));
        p.inc(1);
        assert_eq!(l.state.lock().unwrap().last.1, 4, "one step is not yet due");
        p.inc(1);
        assert_eq!(l.state.lock().unwrap().last.1, 6, "two steps are");
        p.finish();
        assert!(l.state.lock().unwrap().finished);
        p.inc(4);
        assert_eq!(
            l.state.lock().unwrap().last.1,
            6,
            "no line after the closing one"
        );
    }
}
