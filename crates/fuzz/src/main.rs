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
                    pth, pickle, safetensors, depth-png
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
    let mut cfg = Config {
        readers: Reader::ALL.to_vec(),
        execs: 100_000,
        seconds: f64::INFINITY,
        seed: 1,
        fixtures: default_fixtures(),
        crash_dir: Some(PathBuf::from("fuzz-crashes")),
        hang: Duration::from_millis(1000),
        progress_s: 30.0,
    };
    let mut out: Option<PathBuf> = None;
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut i = 0;
    while i < args.len() {
        let a = args[i].as_str();
        let val = args.get(i + 1).cloned().unwrap_or_default();
        let bad = |what: &str| {
            eprintln!("depthsense-fuzz: bad value {val:?} for {what}\n\n{HELP}");
            ExitCode::from(2)
        };
        match a {
            "-h" | "--help" => {
                println!("{HELP}");
                return ExitCode::SUCCESS;
            }
            "--readers" => {
                let mut rs = Vec::new();
                for n in val.split(',').filter(|s| !s.is_empty()) {
                    match Reader::from_name(n) {
                        Some(r) => rs.push(r),
                        None => return bad("--readers"),
                    }
                }
                cfg.readers = rs;
            }
            "--execs" => match parse_num(&val) {
                Some(v) => cfg.execs = v as u64,
                None => return bad("--execs"),
            },
            "--seconds" => match parse_num(&val) {
                Some(v) => cfg.seconds = v,
                None => return bad("--seconds"),
            },
            "--seed" => match val.parse() {
                Ok(v) => cfg.seed = v,
                Err(_) => return bad("--seed"),
            },
            "--fixtures" => cfg.fixtures = PathBuf::from(&val),
            "--crashes" => cfg.crash_dir = Some(PathBuf::from(&val)),
            "--hang-ms" => match parse_num(&val) {
                Some(v) => cfg.hang = Duration::from_secs_f64(v / 1e3),
                None => return bad("--hang-ms"),
            },
            "--out" => out = Some(PathBuf::from(&val)),
            "--progress" => match parse_num(&val) {
                Some(v) => cfg.progress_s = v,
                None => return bad("--progress"),
            },
            other => {
                eprintln!("depthsense-fuzz: unknown argument {other:?}\n\n{HELP}");
                return ExitCode::from(2);
            }
        }
        i += 2;
    }
    let (stats, report) = run(&cfg);
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
