//! Summary statistics of a set of radar files, as used to compare the synthetic RADAR_FRONT
//! with the real one (`../shared/notes/training-init-evidence.md`, "The synthetic radar against
//! the real one"; `docs/design-synth.md`, "Radar statistics").
//!
//! Conventions (the same as the measurement in the note): the devkit's default filters
//! (SPEC §2: `invalid_state == 0`, `dyn_prop` in 0..=6, `ambig_state == 3`) decide "kept";
//! range is the horizontal distance in the sensor frame, `hypot(x, y)` (radar has z = 0);
//! percentiles are nearest-rank on the sorted values (index `round(q · (n − 1))`); the median
//! of points per file is the same nearest-rank p50 over files.

use depthsense_nuscenes::pcd::RadarPoint;

/// Statistics over a set of radar files.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RadarStats {
    pub files: usize,
    /// Points per file: median, min, max.
    pub points_median: f64,
    pub points_min: usize,
    pub points_max: usize,
    /// Fraction of all points that pass the devkit's default filters.
    pub kept_fraction: f64,
    /// Range (m) of the kept points: p10, p50, p90.
    pub range_kept_m: [f64; 3],
    /// RCS (dBsm) of the kept points: p10, p50, p90.
    pub rcs_kept_dbsm: [f64; 3],
}

/// Nearest-rank quantile of sorted values (NaN when empty).
pub fn quantile_sorted(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let i = (q.clamp(0.0, 1.0) * (v.len() - 1) as f64).round() as usize;
    v[i]
}

/// Statistics of `files`, each the full (unfiltered) point list of one radar file.
pub fn radar_stats<F: AsRef<[RadarPoint]>>(files: &[F]) -> RadarStats {
    let mut counts: Vec<f64> = Vec::with_capacity(files.len());
    let mut total = 0usize;
    let mut ranges = Vec::new();
    let mut rcs = Vec::new();
    for f in files {
        let pts = f.as_ref();
        counts.push(pts.len() as f64);
        total += pts.len();
        for p in pts.iter().filter(|p| p.passes_default_filters()) {
            ranges.push((p.x as f64).hypot(p.y as f64));
            rcs.push(p.rcs as f64);
        }
    }
    let kept = ranges.len();
    counts.sort_by(f64::total_cmp);
    ranges.sort_by(f64::total_cmp);
    rcs.sort_by(f64::total_cmp);
    let q3 = |v: &[f64]| {
        [
            quantile_sorted(v, 0.1),
            quantile_sorted(v, 0.5),
            quantile_sorted(v, 0.9),
        ]
    };
    RadarStats {
        files: files.len(),
        points_median: quantile_sorted(&counts, 0.5),
        points_min: counts.first().map_or(0, |c| *c as usize),
        points_max: counts.last().map_or(0, |c| *c as usize),
        kept_fraction: if total > 0 {
            kept as f64 / total as f64
        } else {
            f64::NAN
        },
        range_kept_m: q3(&ranges),
        rcs_kept_dbsm: q3(&rcs),
    }
}

impl std::fmt::Display for RadarStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} files, points median {} ({}–{}), kept {:.1} %, range p10/p50/p90 {:.1} / {:.1} / {:.1} m, RCS {:.1} / {:.1} / {:.1} dBsm",
            self.files,
            self.points_median,
            self.points_min,
            self.points_max,
            100.0 * self.kept_fraction,
            self.range_kept_m[0],
            self.range_kept_m[1],
            self.range_kept_m[2],
            self.rcs_kept_dbsm[0],
            self.rcs_kept_dbsm[1],
            self.rcs_kept_dbsm[2],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pt(x: f32, ok: bool, rcs: f32) -> RadarPoint {
        RadarPoint {
            x,
            y: 0.0,
            z: 0.0,
            dyn_prop: 1,
            id: 0,
            rcs,
            vx: 0.0,
            vy: 0.0,
            vx_comp: 0.0,
            vy_comp: 0.0,
            is_quality_valid: 1,
            ambig_state: 3,
            x_rms: 0,
            y_rms: 0,
            invalid_state: if ok { 0 } else { 1 },
            pdh0: 1,
            vx_rms: 0,
            vy_rms: 0,
        }
    }

    #[test]
    fn stats_of_a_fabricated_set() {
        let a: Vec<RadarPoint> = (1..=10)
            .map(|i| pt(i as f32, i % 2 == 0, i as f32))
            .collect();
        let b: Vec<RadarPoint> = vec![pt(50.0, true, -3.0), pt(60.0, false, 0.0)];
        let s = radar_stats(&[a, b, Vec::new()]);
        assert_eq!(s.files, 3);
        assert_eq!((s.points_min, s.points_max), (0, 10));
        assert_eq!(s.points_median, 2.0);
        // kept: 2, 4, 6, 8, 10, 50 of 12 points.
        assert!((s.kept_fraction - 0.5).abs() < 1e-12);
        // Nearest rank: index round(q · 5) of the six sorted values.
        assert_eq!(s.range_kept_m, [4.0, 8.0, 50.0]);
        assert_eq!(s.rcs_kept_dbsm, [2.0, 6.0, 10.0]);
    }
}
