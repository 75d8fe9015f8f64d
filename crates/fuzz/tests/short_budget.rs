//! The CI budget of the fuzzer (issue 10): a few thousand executions per reader, ≤ 60 s in
//! all, no crash and no hang. Readers seeded from the fixtures are skipped with a message
//! when the fixtures are absent; the in-memory-seeded ones always run.

use std::time::Duration;

use depthsense_fuzz::{default_fixtures, run, Config, Reader};

#[test]
fn every_reader_survives_a_short_fuzz_run() {
    let debug = cfg!(debug_assertions);
    let cfg = Config {
        readers: Reader::ALL.to_vec(),
        execs: if debug { 2_000 } else { 5_000 },
        // 11 readers × 5 s stays under the 60 s CI budget even on a loaded machine
        seconds: 5.0,
        seed: 0x5eed,
        fixtures: default_fixtures(),
        crash_dir: Some(std::env::temp_dir().join("depthsense-fuzz-ci-crashes")),
        // generous in debug builds on a shared 2-core machine; the release run uses 1 s
        hang: Duration::from_secs(if debug { 5 } else { 1 }),
        progress_s: 0.0,
    };
    let (stats, report) = run(&cfg);
    println!("{}", serde_json::to_string_pretty(&report).unwrap());
    for s in &stats {
        if let Some(why) = &s.skipped {
            depthsense_testkit::skip(&format!("fuzz reader {}: {why}", s.reader));
            assert!(
                Reader::from_name(s.reader).is_some_and(|r| r.needs_fixtures()),
                "{} skipped: {why}",
                s.reader
            );
            continue;
        }
        assert!(s.execs >= 200, "{}: only {} executions", s.reader, s.execs);
        assert_eq!(
            (s.crashes, s.hangs),
            (0, 0),
            "{}: first crash {:?}, inputs {:?}",
            s.reader,
            s.first_crash,
            s.saved
        );
        assert!(s.accepted > 0, "{}: no seed was accepted", s.reader);
    }
}

#[test]
fn mutations_are_deterministic() {
    let mut a = depthsense_fuzz::Rng::new(7);
    let mut b = depthsense_fuzz::Rng::new(7);
    let seed = b"VERSION 0.7\nWIDTH 12\n".to_vec();
    for _ in 0..100 {
        let (mut x, mut y) = (seed.clone(), seed.clone());
        depthsense_fuzz::mutate(&mut x, &[], true, &mut a);
        depthsense_fuzz::mutate(&mut y, &[], true, &mut b);
        assert_eq!(x, y);
    }
}
