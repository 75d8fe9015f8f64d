//! `depthsense inspect PATH...` over many files (issue 25 item 2): a folder expands to its sensor
//! files, sorted; each summary equals the one-file summary; a file that cannot be read keeps its
//! error with its path and does not stop the others.

use std::path::PathBuf;

use depthsense_prep::inspect::{expand_paths, inspect, inspect_all, is_version_folder};

#[test]
fn a_folder_of_real_radar_files_and_a_bad_file() {
    let Some(radar) = depthsense_testkit::fixture("radar-front-mini") else {
        return;
    };
    let files = expand_paths(std::slice::from_ref(&radar)).unwrap();
    assert_eq!(files.len(), 404, "the fixture's radar files");
    assert!(files.windows(2).all(|w| w[0] < w[1]), "sorted");
    assert!(files.iter().all(|f| f.extension().unwrap() == "pcd"));
    let all = inspect_all(&files);
    for (f, r) in files.iter().zip(&all).step_by(50) {
        assert_eq!(r.as_ref().unwrap(), &inspect(f).unwrap(), "{}", f.display());
    }
    assert!(all.iter().all(|r| r.is_ok()));
    let points: u64 = all
        .iter()
        .map(|r| r.as_ref().unwrap()["points"].as_u64().unwrap())
        .sum();
    assert!(points > 404 * 10, "{points} radar points");

    // A bad file among good ones; a version folder stays one entry.
    let tmp = tempfile::tempdir().unwrap();
    let bad = tmp.path().join("broken.pcd");
    std::fs::write(&bad, b"not a pcd").unwrap();
    std::fs::write(tmp.path().join("notes.txt"), b"ignored").unwrap();
    let mut paths: Vec<PathBuf> = vec![tmp.path().to_path_buf(), files[0].clone()];
    if let Some(kf0) = depthsense_testkit::fixture("nuscenes-kf0") {
        let version = kf0.join("v1.0-mini");
        assert!(is_version_folder(&version));
        paths.push(version);
    }
    let expanded = expand_paths(&paths).unwrap();
    assert_eq!(expanded[0], bad, "the folder's sensor files only");
    assert_eq!(expanded[1], files[0]);
    let r = inspect_all(&expanded);
    let e = r[0].as_ref().unwrap_err().to_string();
    assert!(e.contains("broken.pcd"), "{e}");
    assert!(r[1].is_ok());
    if expanded.len() == 3 {
        assert!(r[2].as_ref().unwrap()["scenes"].is_array());
    }
}
