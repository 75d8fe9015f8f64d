//! `depthsense mer report`: how much of the sparse lidar GT each radar map covers and how
//! wrong its depth is there — raw radar, height-extended radar (SPEC §5) and MER at every θ —
//! over the samples of a split (default: the test scenes, never used to choose anything).
//!
//! Per map: covered = GT pixels (sparse lidar > 0, ≤ `cap_m`) where the map holds a depth;
//! coverage = covered / GT pixels; the relative error |d − gt| / gt is pooled over every
//! covered pixel of every sample, and its median (and 90th percentile) reported.

use std::path::{Path, PathBuf};

use depthsense_dataset::DataError;
use depthsense_dataset::{partition, read_depth, Dataset};
use depthsense_metrics::doc::Doc;
use depthsense_metrics::table::{Align, MdTable};
use depthsense_prep::layout::{IndexEntry, LIDAR_SPARSE_FILE, RADAR_HEIGHT_FILE, RADAR_RAW_FILE};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use depthsense_dataset::mer_maps::{derive_channels, read_mer_maps, THRESHOLDS};

/// One row of the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CoverageRow {
    pub map: String,
    /// Pixels holding a depth, mean per image (whether GT is there or not).
    pub pixels_per_image: f64,
    pub covered_gt_pixels: u64,
    pub gt_pixels: u64,
    /// covered / GT pixels.
    pub coverage: f64,
    pub median_rel_error: f64,
    pub p90_rel_error: f64,
}

/// The whole report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MerReport {
    pub data: PathBuf,
    pub split: String,
    pub images: usize,
    pub cap_m: f64,
    pub rows: Vec<CoverageRow>,
    /// The invocation that wrote the report's JSON (`mer report --json`), when recorded.
    #[serde(default)]
    pub command_line: Option<String>,
}

/// Per map of one sample: (name, pixels with depth, relative errors at covered GT pixels).
type SampleStats = Vec<(String, u64, Vec<f32>)>;

fn sample_stats(dir: &Path, cap_m: f32) -> Result<(u64, SampleStats), DataError> {
    let gt = read_depth(&dir.join(LIDAR_SPARSE_FILE))?;
    let raw = read_depth(&dir.join(RADAR_RAW_FILE))?;
    let height = read_depth(&dir.join(RADAR_HEIGHT_FILE))?;
    let (md, mc) = read_mer_maps(dir)?;
    let n = gt.depth_m.len();
    for (name, len) in [
        ("radar", raw.depth_m.len()),
        ("height", height.depth_m.len()),
    ] {
        if len != n || md.depth_m.len() != n {
            return Err(DataError::CoverageMapSizes {
                dir: dir.to_path_buf(),
                map: name,
            });
        }
    }
    let ch = derive_channels(&md.depth_m, &mc.depth_m);
    let mut maps: Vec<(String, &[f32])> = vec![
        ("raw".into(), &raw.depth_m),
        ("height-extended".into(), &height.depth_m),
    ];
    for (i, t) in THRESHOLDS.iter().enumerate() {
        maps.push((format!("MER θ = {t}"), &ch[i * n..(i + 1) * n]));
    }
    let valid = |g: f32| g > 0.0 && g <= cap_m;
    let gt_pixels = gt.depth_m.iter().filter(|g| valid(**g)).count() as u64;
    let stats = maps
        .into_iter()
        .map(|(name, m)| {
            let px = m.iter().filter(|d| **d > 0.0).count() as u64;
            let errs = m
                .iter()
                .zip(&gt.depth_m)
                .filter(|(d, g)| **d > 0.0 && valid(**g))
                .map(|(d, g)| (d - g).abs() / g)
                .collect();
            (name, px, errs)
        })
        .collect();
    Ok((gt_pixels, stats))
}

fn quantile(sorted: &[f32], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i] as f64
}

/// Samples of `split`: "held-out" = the test scenes of the train/val/test partition.
fn entries_of(ds: &Dataset, split: &str) -> Result<Vec<IndexEntry>, DataError> {
    let e = if split == "held-out" {
        partition(ds, 5)?.test
    } else {
        ds.split(split)
    };
    if e.is_empty() {
        return Err(DataError::EmptySplit {
            root: ds.root.clone(),
            split: split.to_string(),
            present: ds.split_names(),
        });
    }
    Ok(e)
}

/// Measure every map on the samples of `split` (GT ≤ `cap_m`).
pub fn mer_report(data: &Path, split: &str, cap_m: f64) -> Result<MerReport, DataError> {
    let ds = Dataset::open(data)?;
    let entries = entries_of(&ds, split)?;
    let per: Vec<(u64, SampleStats)> = entries
        .par_iter()
        .map(|e| sample_stats(&ds.sample_dir(e), cap_m as f32))
        .collect::<Result<_, _>>()?;
    let gt_pixels: u64 = per.iter().map(|p| p.0).sum();
    let names: Vec<String> = per[0].1.iter().map(|s| s.0.clone()).collect();
    let rows = names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let px: u64 = per.iter().map(|p| p.1[i].1).sum();
            let mut errs: Vec<f32> = per.iter().flat_map(|p| p.1[i].2.iter().copied()).collect();
            errs.sort_by(f32::total_cmp);
            CoverageRow {
                map: name.clone(),
                pixels_per_image: px as f64 / per.len() as f64,
                covered_gt_pixels: errs.len() as u64,
                gt_pixels,
                coverage: errs.len() as f64 / gt_pixels.max(1) as f64,
                median_rel_error: quantile(&errs, 0.5),
                p90_rel_error: quantile(&errs, 0.9),
            }
        })
        .collect();
    Ok(MerReport {
        data: data.to_path_buf(),
        split: split.to_string(),
        images: per.len(),
        cap_m,
        rows,
        command_line: None,
    })
}

/// The report as Markdown: a line, then the table ([`report_doc`] as text).
pub fn report_markdown(r: &MerReport) -> String {
    report_doc(r).to_markdown()
}

/// The report as a document: one paragraph (images, split, cap), then the coverage table.
pub fn report_doc(r: &MerReport) -> Doc {
    // A map that covers no GT pixel has no error to report: "–", never "NaN %".
    let pct = |v: f64, decimals: usize| {
        if v.is_finite() {
            format!("{:.*} %", decimals, 100.0 * v)
        } else {
            "–".to_string()
        }
    };
    let mut t = MdTable::new(&[
        ("radar map", Align::Left),
        ("pixels / image", Align::Right),
        ("GT pixels covered", Align::Right),
        ("coverage", Align::Right),
        ("median rel. error", Align::Right),
        ("p90 rel. error", Align::Right),
    ]);
    for x in &r.rows {
        t.row(&[
            x.map.to_string(),
            format!("{:.0}", x.pixels_per_image),
            x.covered_gt_pixels.to_string(),
            pct(x.coverage, 2),
            pct(x.median_rel_error, 2),
            pct(x.p90_rel_error, 1),
        ]);
    }
    let mut doc = Doc::new();
    doc.paragraph(format!(
        "{} images of split `{}`, sparse lidar GT ≤ {} m ({} GT pixels)",
        r.images,
        r.split,
        r.cap_m,
        r.rows.first().map_or(0, |x| x.gt_pixels)
    ))
    .table(t);
    doc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_map_without_covered_pixels_prints_no_nan() {
        let row = |map: &str, covered: u64, err: f64| CoverageRow {
            map: map.into(),
            pixels_per_image: 3.0,
            covered_gt_pixels: covered,
            gt_pixels: 100,
            coverage: covered as f64 / 100.0,
            median_rel_error: err,
            p90_rel_error: err,
        };
        let md = report_markdown(&MerReport {
            data: "p".into(),
            split: "test".into(),
            images: 2,
            cap_m: 80.0,
            rows: vec![row("raw", 5, 0.12), row("mer>0.95", 0, f64::NAN)],
            command_line: None,
        });
        assert!(!md.contains("NaN"), "{md}");
        assert!(md.contains("| mer>0.95 | 3 | 0 | 0.00 % | – | – |"), "{md}");
        assert!(
            md.contains("| raw | 3 | 5 | 5.00 % | 12.00 % | 12.0 % |"),
            "{md}"
        );
    }
}
