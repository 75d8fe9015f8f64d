//! `depthsense-fuzz`: mutation-fuzz every reader of untrusted bytes (issue 10).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use depthsense_fuzz::{default_fixtures, run, Config, Reader};

const HELP: &str =
    "depthsense-fuzz — stable-Rust mutation fuzzer for the readers of untrusted bytes

USAGE: depthsense-fuzz [OPTIONS]

OPTIONS:
  --readers LIST    comma-separated readers (default: all):
                    pcd-binary, pcd-ascii, pcd-binary-compressed, pcd-bin, table-json,
                    pth, pickle, safetensors, depth-png, npy, radar-points-bin
  --execs N         executions per reader (default 100000; 1e7 accepted)
  --seconds S       wall-clock budget per reader (default: unlimited)
  --seed N          RNG seed (default 1)
  --fixtures DIR    the shared fixtures (default ../shared/fixtures of the workspace);
                    readers seeded from them are skipped, with a message, when absent
  --crashes DIR     save crashing and hanging inputs here (default fuzz-crashes)
  --hang-ms MS      an execution longer than this is a hang (default 1000)
  --out FILE        also write the JSON report here
  --progress S      progress line on stderr every S seconds (default 30; 0 = off)
  -h, --help        this text

The JSON report (stdout) has execs, accepted, rejected, crashes and hangs per reader. The
exit status is 1 when any reader crashed or hung. An abort (allocation failure, stack
overflow) would end the process: a completed report also means there were none.";

fn parse_num(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|v| v.is_finite() && *v >= 0.0)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match parse_args(&args) {
        Ok((cfg, out)) => fuzz_and_report(&cfg, out),
        Err(code) => code,
    }
}

/// The defaults of every option (see [`HELP`]).
fn default_config() -> Config {
    Config {
        readers: Reader::ALL.to_vec(),
        execs: 100_000,
        seconds: f64::INFINITY,
        seed: 1,
        fixtures: default_fixtures(),
        crash_dir: Some(PathBuf::from("fuzz-crashes")),
        hang: Duration::from_millis(1000),
        progress_s: 30.0,
    }
}

/// The run's settings and `--out`; `Err`: exit now with this status (help printed, or a bad
/// argument reported with the help).
fn parse_args(args: &[String]) -> Result<(Config, Option<PathBuf>), ExitCode> {
    let mut cfg = default_config();
    let mut out: Option<PathBuf> = None;
    let mut i = 0;
    while i < args.len() {
        let val = args.get(i + 1).cloned().unwrap_or_default();
        apply_option(&mut cfg, &mut out, &args[i], &val)?;
        i += 2;
    }
    Ok((cfg, out))
}

/// Apply option `a` with value `val` (every option but `-h` takes one).
fn apply_option(
    cfg: &mut Config,
    out: &mut Option<PathBuf>,
    a: &str,
    val: &str,
) -> Result<(), ExitCode> {
    let bad = |what: &str| {
        eprintln!("depthsense-fuzz: bad value {val:?} for {what}\n\n{HELP}");
        ExitCode::from(2)
    };
    match a {
        "-h" | "--help" => {
            println!("{HELP}");
            return Err(ExitCode::SUCCESS);
        }
        "--readers" => {
            let mut rs = Vec::new();
            for n in val.split(',').filter(|s| !s.is_empty()) {
                match Reader::from_name(n) {
                    Some(r) => rs.push(r),
                    None => return Err(bad("--readers")),
                }
            }
            cfg.readers = rs;
        }
        "--execs" => cfg.execs = parse_num(val).ok_or_else(|| bad("--execs"))? as u64,
        "--seconds" => cfg.seconds = parse_num(val).ok_or_else(|| bad("--seconds"))?,
        "--seed" => cfg.seed = val.parse().map_err(|_| bad("--seed"))?,
        "--fixtures" => cfg.fixtures = PathBuf::from(val),
        "--crashes" => cfg.crash_dir = Some(PathBuf::from(val)),
        "--hang-ms" => {
            let v = parse_num(val).ok_or_else(|| bad("--hang-ms"))?;
            cfg.hang = Duration::from_secs_f64(v / 1e3);
        }
        "--out" => *out = Some(PathBuf::from(val)),
        "--progress" => cfg.progress_s = parse_num(val).ok_or_else(|| bad("--progress"))?,
        other => {
            eprintln!("depthsense-fuzz: unknown argument {other:?}\n\n{HELP}");
            return Err(ExitCode::from(2));
        }
    }
    Ok(())
}

/// Fuzz, print the skipped readers (stderr) and the JSON report (stdout, and `out`); exit 1
/// when any reader crashed or hung, 2 when `out` cannot be written.
fn fuzz_and_report(cfg: &Config, out: Option<PathBuf>) -> ExitCode {
    let (stats, report) = run(cfg);
    for s in &stats {
        if let Some(why) = &s.skipped {
            eprintln!("skipped {}: {why}", s.reader);
        }
    }
    let text = serde_json::to_string_pretty(&report).unwrap_or_default();
    println!("{text}");
    if let Some(p) = out {
        if let Err(e) = std::fs::write(&p, &text) {
            eprintln!("depthsense-fuzz: cannot write {}: {e}", p.display());
            return ExitCode::from(2);
        }
    }
    if stats.iter().any(|s| s.crashes > 0 || s.hangs > 0) {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    }
}
