//! `depthsense report`: fake experiment folders in the writers' formats (the real writer where
//! cheap: eval tables, the MER report), one report over them, and its checks — sections,
//! embedded images, escaping, the Markdown table renderer, no external URL — plus the page in
//! headless Chromium (skipped when absent unless DEPTHSENSE_REQUIRE_BROWSER=1).

use std::path::{Path, PathBuf};
use std::process::Command;

use depthsense_metrics::{evaluate, EvalConfig, EvalImage};
use depthsense_report::markdown::to_html;
use depthsense_report::{build_report, Kind, ReportOptions, ReportSummary};
use depthsense_score::mer_coverage::{CoverageRow, MerReport};
use depthsense_score::tables::write_tables_with_command;
use serde_json::json;

fn write(p: &Path, text: &str) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, text).unwrap();
}

/// A PNG with a colour gradient (so a screenshot of it is not one colour).
fn png(p: &Path, w: u32, h: u32) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 255 / w) as u8, (y * 255 / h) as u8, 128])
    });
    img.save(p).unwrap();
}

const TABLE_MD: &str = "\
| variant | condition | n | δ1 | RMSE (m) |
|---|---|---:|---:|---:|
| rgb | combined | 3 | 0.697 ± 0.014 | 10.131 ± 0.378 |
| late-sam | combined | 3 | 0.706 ± 0.024 | 10.352 ± 0.816 |
";

/// One `<stem>.{json,md,csv}` experiment in `dir`, its command line in `options` or at the
/// top level as the writers put it.
fn experiment(dir: &Path, stem: &str, cmd: &str, in_options: bool) {
    let v = if in_options {
        json!({"options": {"data": "runs/p", "out": dir, "command_line": cmd}, "summary": []})
    } else {
        json!({"eval": {"data": "runs/q", "split": "held-out"}, "results": [], "command_line": cmd})
    };
    write(&dir.join(format!("{stem}.json")), &v.to_string());
    let md = format!(
        "# {stem} <title>\n\nIntro with `code` and **bold**.\n\n{TABLE_MD}\nCommand: `{cmd}`\n"
    );
    write(&dir.join(format!("{stem}.md")), &md);
    write(&dir.join(format!("{stem}.csv")), "variant,rmse\nrgb,10.1\n");
}

fn explain(dir: &Path) {
    let mut records = vec![];
    for radar in [true, false] {
        for d in [35, 70] {
            let name = format!(
                "tok_{d}m_radar_{}.png",
                if radar { "radar" } else { "noradar" }
            );
            png(&dir.join(&name), 800, 350);
            records.push(
                json!({"sample": "tok", "distance_m": d as f64, "layer": "radar",
                "radar": radar, "overlay": name}),
            );
        }
    }
    png(&dir.join("grid.png"), 3200, 712);
    let v = json!({"checkpoint": "runs/x/best.safetensors", "band": 0.1, "records": records,
        "grid": "grid.png", "command_line": "depthsense explain --data runs/p --out x"});
    write(&dir.join("explain.json"), &v.to_string());
    write(
        &dir.join("explain.md"),
        "# Grad-CAM++\n\n| sample | d |\n|---|---:|\n| tok | 35 |\n",
    );
}

/// Eval tables through the real writer (one tiny image), with its command line.
fn eval_tables(dir: &Path) {
    let gt = [10.0f32, 20.0, 0.0, 60.0];
    let pred = [11.0f32, 18.0, 5.0, 55.0];
    let imgs = [EvalImage {
        pred_m: &pred,
        gt_m: &gt,
        lowheight: None,
        conditions: &["day"],
    }];
    let r = evaluate(&imgs, &EvalConfig::default()).unwrap();
    let cmd = "depthsense eval --checkpoint m.safetensors --data runs/e";
    write_tables_with_command(dir, &[("model", &r)], Some(cmd)).unwrap();
}

fn mer(p: &Path) {
    let row = |map: &str, c: f64| CoverageRow {
        map: map.into(),
        pixels_per_image: 161.5,
        covered_gt_pixels: 86,
        gt_pixels: 92051,
        coverage: c,
        median_rel_error: 0.05,
        p90_rel_error: 0.8,
    };
    let r = MerReport {
        data: "runs/abl/prepared".into(),
        split: "held-out".into(),
        images: 32,
        cap_m: 80.0,
        rows: vec![row("raw", 0.001), row("MER θ = 0.5", 0.098)],
        command_line: Some("depthsense mer report --data runs/abl/prepared --json r.json".into()),
    };
    // NaN (a map covering no GT pixel) is written as null.
    let mut v = serde_json::to_value(&r).unwrap();
    v["rows"][1]["p90_rel_error"] = serde_json::Value::Null;
    write(p, &serde_json::to_string_pretty(&v).unwrap());
}

/// Three run folders holding every kind, one unreadable image, one broken JSON, one log.
fn fake_runs(root: &Path) -> Vec<PathBuf> {
    let abl = root.join("abl");
    experiment(
        &abl.join("ablation"),
        "ablation",
        "depthsense experiment ablation --data runs/p --out runs/abl --set \"a<b&c\"",
        true,
    );
    png(&abl.join("ablation/ablation.png"), 900, 300);
    write(&abl.join("ablation/runs/rgb/seed0/eval.json"), "{}");
    let i12 = root.join("issue12");
    experiment(
        &i12.join("reduced"),
        "reduced_data",
        "depthsense experiment reduced-data",
        true,
    );
    png(&i12.join("reduced/reduced_data.png"), 4000, 200);
    experiment(
        &i12.join("failure"),
        "failure",
        "depthsense experiment failure --checkpoint c.safetensors",
        false,
    );
    png(&i12.join("failure/failure.png"), 700, 300);
    experiment(
        &i12.join("perturb"),
        "perturb",
        "depthsense experiment perturb",
        false,
    );
    write(&i12.join("perturb/perturb.png"), "not a png");
    experiment(
        &i12.join("cost"),
        "cost",
        "depthsense experiment cost",
        true,
    );
    explain(&i12.join("explain"));
    eval_tables(&i12.join("eval_ck"));
    write(&i12.join("failure.txt"), "a log");
    write(&i12.join("broken/ablation.json"), "{ not json");
    mer(&root.join("mer/report.json"));
    vec![abl, i12, root.join("mer")]
}

fn report(root: &Path) -> (ReportSummary, String, PathBuf) {
    let runs = fake_runs(root);
    let out = root.join("out/report");
    let opts = ReportOptions {
        runs,
        out: out.clone(),
        title: "Test <report>".into(),
        command_line: Some("depthsense report --runs a --out <b>".into()),
        ..ReportOptions::default()
    };
    let s = build_report(&opts).unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    (s, html, out)
}

/// Minimal base64 decoder (standard alphabet, padded).
fn unbase64(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let mut out = vec![];
    for q in s.as_bytes().chunks(4) {
        let n = q.iter().filter(|&&c| c != b'=').count();
        let mut v = 0u32;
        for (i, &c) in q.iter().enumerate() {
            v |= (if c == b'=' { 0 } else { val(c) as u32 }) << (18 - 6 * i);
        }
        out.extend_from_slice(&v.to_be_bytes()[1..n]);
    }
    out
}

/// Sizes of the images embedded in `html`.
fn embedded_sizes(html: &str) -> Vec<(u32, u32)> {
    html.split("src=\"data:image/png;base64,")
        .skip(1)
        .map(|rest| {
            let b64 = &rest[..rest.find('"').unwrap()];
            let img = image::load_from_memory(&unbase64(b64)).unwrap();
            (img.width(), img.height())
        })
        .collect()
}

#[test]
fn every_section_and_image_is_in_the_page() {
    let dir = tempfile::tempdir().unwrap();
    let (s, html, out) = report(dir.path());
    let kinds: Vec<Kind> = s.sections.iter().map(|x| x.kind).collect();
    assert_eq!(
        kinds,
        [
            // The eval tables' model, compared at the top.
            Kind::Models,
            Kind::Ablation,
            Kind::ReducedData,
            Kind::Failure,
            Kind::Perturb,
            Kind::Cost,
            Kind::Explain,
            Kind::Eval,
            Kind::Mer
        ]
    );
    for sec in &s.sections {
        assert!(html.contains(&format!("<section id=\"{}\">", sec.anchor)));
        assert!(html.contains(&format!("<a href=\"#{}\">", sec.anchor)));
        assert!(
            sec.kind == Kind::Models
                || html.contains(&format!("(written by <code>{}</code>)", sec.kind.writer()))
        );
    }
    // ablation 1, reduced 1, failure 1, perturb 0 (unreadable), explain 4 tiles.
    let sizes = embedded_sizes(&html);
    assert_eq!(sizes.len(), 7, "{sizes:?}");
    assert!(
        sizes.contains(&(1600, 80)),
        "wide plot downscaled: {sizes:?}"
    );
    assert_eq!(sizes.iter().filter(|&&x| x == (400, 175)).count(), 4);
    assert!(sizes.iter().all(|&(w, _)| w <= 1600));
    // Distance-cap table of eval, MER table, the explain grid's labels.
    assert!(html.contains("Distance table (SPEC §10.3)"));
    assert!(html.contains("<pre>depthsense eval --checkpoint m.safetensors --data runs/e</pre>"));
    assert!(html.contains("MER θ = 0.5"));
    assert!(
        html.contains("<pre>depthsense mer report --data runs/abl/prepared --json r.json</pre>")
    );
    assert!(html.contains("<th>35 m · radar</th>") && html.contains("<th>tok · radar zeroed</th>"));
    // Commands and data from the JSON.
    assert!(html.contains("<pre>depthsense experiment failure --checkpoint c.safetensors</pre>"));
    assert!(html.contains("<dt>checkpoint</dt><dd><code>c.safetensors</code></dd>"));
    assert!(html.contains("<dt>data</dt><dd><code>runs/p</code></dd>"));
    assert!(
        html.contains("<dt>data</dt><dd><code>runs/q</code></dd>"),
        "failure's eval.data"
    );
    // Skipped, with reasons.
    let reason = |end: &str| {
        s.skipped
            .iter()
            .find(|k| k.path.ends_with(end))
            .map(|k| k.reason.clone())
            .unwrap_or_else(|| panic!("{end} not listed as skipped: {:?}", s.skipped))
    };
    assert!(reason("perturb/perturb.png").contains("not a readable image"));
    assert!(reason("broken/ablation.json").contains("not valid JSON"));
    assert!(reason("issue12/failure.txt").contains("not an experiment output"));
    assert!(!s
        .skipped
        .iter()
        .any(|k| k.path.ends_with("seed0/eval.json")));
    // report.md references copies that exist; report.json lists the sections.
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let copies: Vec<_> = s.sections.iter().flat_map(|x| x.images.iter()).collect();
    assert_eq!(copies.len(), 7);
    for c in copies {
        assert!(md.contains(&format!("]({})", c.copy.display())));
        assert!(out.join(&c.copy).is_file());
    }
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(j["sections"].as_array().unwrap().len(), 9);
    assert_eq!(j["sections"][0]["kind"], "models");
    assert_eq!(j["sections"][7]["kind"], "eval");
    assert_eq!(j["html_bytes"].as_u64().unwrap() as usize, html.len());
}

#[test]
fn html_is_escaped_and_links_nowhere() {
    let dir = tempfile::tempdir().unwrap();
    let (_, html, _) = report(dir.path());
    assert!(html.contains("<title>Test &lt;report&gt;</title>"));
    assert!(html.contains("--out &lt;b&gt;</pre>"));
    assert!(html.contains("--set &quot;a&lt;b&amp;c&quot;"));
    assert!(html.contains("<h3>ablation &lt;title&gt;</h3>"));
    assert!(!html.contains("<b>") && !html.contains("<title>\n"));
    for bad in [
        "http://", "https://", "<script", "<link", "<iframe", "url(", "@import",
    ] {
        assert!(!html.contains(bad), "page contains {bad}");
    }
    // Every src is a data: URI and every href an in-page anchor that exists.
    for src in html.split(" src=\"").skip(1) {
        assert!(src.starts_with("data:image/png;base64,"));
    }
    for href in html.split(" href=\"").skip(1) {
        let target = &href[..href.find('"').unwrap()];
        let id = target.strip_prefix('#').expect("in-page link");
        assert!(html.contains(&format!(" id=\"{id}\"")), "no anchor {id}");
    }
}

#[test]
fn markdown_table_renders_to_the_expected_html() {
    let md = "\
| variant | n | RMSE (m) |
|---|---:|:---:|
| rgb | 3 | 10.1 ± 0.4 |
| a<b & `c|d` | **2** | – |
";
    let expected = "\
<table>
<thead><tr><th>variant</th><th class=\"r\">n</th><th class=\"c\">RMSE (m)</th></tr></thead>
<tbody>
<tr><td>rgb</td><td class=\"r\">3</td><td class=\"c\">10.1 ± 0.4</td></tr>
<tr><td>a&lt;b &amp; <code>c|d</code></td><td class=\"r\"><strong>2</strong></td><td class=\"c\">–</td></tr>
</tbody>
</table>
";
    assert_eq!(to_html(md, 0), expected);
    // A paragraph, then the table right after it.
    let with_text = format!("Values: mean ± std.\n{md}");
    assert_eq!(
        to_html(&with_text, 0),
        format!("<p>Values: mean ± std.</p>\n{expected}")
    );
}

#[test]
fn an_existing_report_is_refused_and_force_replaces_only_its_own_files() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, out) = report(dir.path());
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    std::fs::write(out.join("img").join("stale.png"), "old").unwrap();
    let before = std::fs::read(out.join("report.html")).unwrap();
    let opts = ReportOptions {
        runs: vec![dir.path().join("mer")],
        out: out.clone(),
        ..ReportOptions::default()
    };
    let e = build_report(&opts).unwrap_err().to_string();
    assert!(
        e.contains("already holds a report") && e.contains("--force") && e.contains("report.html"),
        "{e}"
    );
    assert_eq!(
        std::fs::read(out.join("report.html")).unwrap(),
        before,
        "refusal changes nothing"
    );
    let s = build_report(&ReportOptions {
        force: true,
        ..opts
    })
    .unwrap();
    assert_eq!(s.sections.len(), 1);
    assert_ne!(std::fs::read(out.join("report.html")).unwrap(), before);
    assert!(
        !out.join("img").join("stale.png").exists(),
        "img/ is the report's own"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("notes.txt")).unwrap(),
        "mine"
    );
    let names: Vec<String> = std::fs::read_dir(out.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.starts_with('.')), "{names:?}");
    let inside: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(inside.iter().all(|n| !n.starts_with('.')), "{inside:?}");
}

#[test]
fn errors_name_the_folder() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope");
    let opts = ReportOptions {
        runs: vec![missing.clone()],
        out: dir.path().join("out"),
        ..ReportOptions::default()
    };
    let e = build_report(&opts).unwrap_err().to_string();
    assert!(
        e.contains(&missing.display().to_string()) && e.contains("not a folder"),
        "{e}"
    );
    let empty = dir.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let opts = ReportOptions {
        runs: vec![empty.clone()],
        ..opts
    };
    let e = build_report(&opts).unwrap_err().to_string();
    assert!(
        e.contains("no experiment output found") && e.contains("empty"),
        "{e}"
    );
}

// ---------------------------------------------------------------------------------------
// The page in a real browser.

fn find_chromium() -> Option<PathBuf> {
    if let Ok(p) = std::env::var("DEPTHSENSE_CHROMIUM") {
        return Some(PathBuf::from(p));
    }
    let path = std::env::var_os("PATH")?;
    for dir in std::env::split_paths(&path) {
        for name in ["chromium", "chromium-browser", "google-chrome"] {
            let p = dir.join(name);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

/// Run headless Chromium (at most 90 s) with `args` on `url`; stdout.
fn chromium(bin: &Path, profile: &Path, args: &[&str], url: &str) -> String {
    let out = Command::new("timeout")
        .arg("90")
        .arg(bin)
        .args([
            "--headless=new",
            "--disable-gpu",
            "--no-sandbox",
            "--disable-dev-shm-usage",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(url)
        .output()
        .expect("run chromium");
    assert!(
        out.status.success(),
        "chromium {args:?} failed ({}): {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Test-only copy of the page with a script that reports, after load, how many images
/// decoded (naturalWidth > 0) and which links point at no element.
const CHECK_SCRIPT: &str = r#"<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var bad = imgs.filter(function (i) { return !i.complete || i.naturalWidth === 0; })
    .map(function (i) { return i.alt; });
  var links = Array.from(document.querySelectorAll('[href]')).map(function (a) { return a.getAttribute('href'); });
  var broken = links.filter(function (h) { return h.charAt(0) !== '#' || !document.getElementById(h.slice(1)); });
  var res = document.createElement('pre');
  res.textContent = 'RES' + 'ULT=' + JSON.stringify({images: imgs.length, bad: bad, links: links.length, broken: broken}) + '=END';
  document.body.appendChild(res);
});
</script>
</body>"#;

/// Load `html` with [`CHECK_SCRIPT`] in headless Chromium (profile and page under `dir`):
/// the script's result and the DOM.
fn check_page(bin: &Path, dir: &Path, html: &str) -> (serde_json::Value, String) {
    let check = dir.join("check.html");
    std::fs::write(&check, html.replace("</body>", CHECK_SCRIPT)).unwrap();
    let dom = chromium(
        bin,
        &dir.join("profile"),
        &["--virtual-time-budget=10000", "--dump-dom"],
        &format!("file://{}", check.display()),
    );
    let res = dom
        .split("RESULT=")
        .nth(1)
        .and_then(|r| r.split("=END").next())
        .unwrap_or_else(|| {
            panic!(
                "no check result in the DOM:\n{}",
                &dom[..dom.len().min(2000)]
            )
        });
    (serde_json::from_str(res).unwrap(), dom)
}

/// Chromium, or `None` after a SKIP line (a panic under DEPTHSENSE_REQUIRE_BROWSER=1).
fn chromium_or_skip() -> Option<PathBuf> {
    let bin = find_chromium();
    if bin.is_none() {
        let _: Option<()> = depthsense_testkit::unavailable(
            depthsense_testkit::REQUIRE_BROWSER,
            "chromium not found on PATH (`make test-browser` installs it)",
        );
    }
    bin
}

#[test]
fn report_renders_in_headless_chromium() {
    let Some(bin) = chromium_or_skip() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (s, html, out) = report(dir.path());
    let profile = dir.path().join("profile");
    let (v, _) = check_page(&bin, dir.path(), &html);
    let n_images: usize = s.sections.iter().map(|x| x.images.len()).sum();
    assert_eq!(v["images"].as_u64(), Some(n_images as u64), "{v}");
    assert_eq!(v["bad"], json!([]), "images that did not decode: {v}");
    assert_eq!(v["broken"], json!([]), "broken links: {v}");
    assert!(v["links"].as_u64().unwrap() > s.sections.len() as u64);

    let shot = dir.path().join("shot.png");
    chromium(
        &bin,
        &profile,
        &[
            &format!("--screenshot={}", shot.display()),
            "--window-size=1280,4000",
            "--hide-scrollbars",
        ],
        &format!("file://{}", out.join("report.html").display()),
    );
    let img = image::open(&shot).expect("screenshot PNG").to_rgb8();
    assert!(
        img.width() >= 1280 && img.height() >= 4000,
        "{}x{}",
        img.width(),
        img.height()
    );
    let mut colours = std::collections::HashSet::new();
    let mut non_white = 0usize;
    for p in img.pixels() {
        colours.insert(p.0);
        non_white += usize::from(p.0 != [255, 255, 255]);
    }
    assert!(
        colours.len() > 100,
        "screenshot has {} colours",
        colours.len()
    );
    assert!(
        non_white * 20 > img.pixels().len(),
        "screenshot nearly blank"
    );
}

/// `make demo`'s one page (issue 22): a quick demo's `report/report.html` in headless Chromium —
/// every image decodes (curves, validation plot, every sample row with its colour bar), no
/// link points outside the page, and the stage commands are on it.
#[test]
fn demo_page_renders_in_headless_chromium() {
    let Some(bin) = chromium_or_skip() else {
        return;
    };
    let _torch = crate::torch_lock();
    let dir = tempfile::tempdir().unwrap();
    let opts = depthsense_experiments::demo::DemoOptions {
        out: dir.path().join("demo"),
        device: "cpu".into(),
        quick: true,
        jobs: 2,
        pictures: 2,
        ..Default::default()
    };
    let mp = depthsense_progress::Board::hidden();
    let s = depthsense_experiments::demo::run_demo(&opts, &mp).unwrap();
    let page = s.report_dir.join("report.html");
    let html = std::fs::read_to_string(&page).unwrap();
    let rows = std::fs::read_dir(s.report_dir.join("samples"))
        .unwrap()
        .count();
    assert_eq!(rows, 2);
    let (v, dom) = check_page(&bin, dir.path(), &html);
    assert_eq!(v["images"].as_u64(), Some(3 + rows as u64), "{v}");
    assert_eq!(v["bad"], json!([]), "images that did not decode: {v}");
    assert_eq!(v["broken"], json!([]), "broken links: {v}");
    assert!(
        dom.contains("depthsense train --data"),
        "stage commands missing"
    );
    assert!(dom.contains("RGB only"), "headline table missing");
}
