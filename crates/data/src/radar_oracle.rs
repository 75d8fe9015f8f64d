//! The oracle radar in the loader (issue 34, `train --radar-oracle`): a sample's radar maps
//! rebuilt from its `radar_points.bin` with every return's depth replaced by the lidar
//! target's ([`depthsense_prep::radar_oracle`] has the rule), quantised like the stored PNGs.
//! An upper bound on what radar could add: the returns' positions (and sparsity) are the
//! sensor's, their depths are right. Applied before any corruption; combining it with the
//! sensor-failure modes is refused.

use std::path::Path;

use depthsense_nuscenes::depth_png::DepthMap;
use depthsense_prep::radar_oracle::oracle_points;
use depthsense_prep::radar_points::RadarPoints;

use crate::radar_failure::quantised;
use depthsense_dataset::DataError;

/// (raw, height) oracle maps of the sample in `dir` whose training target (frame-sized,
/// metres, 0 = invalid) is `target_m`.
pub fn oracle_maps(
    dir: &Path,
    target_m: &[f32],
    width: usize,
    height: usize,
) -> Result<(DepthMap, DepthMap), DataError> {
    let points = RadarPoints::read_from_sample(dir)
        .map_err(|source| DataError::OracleRadarPoints { source })?;
    let (oracle, _) = oracle_points(&points, target_m, width, height);
    let maps = oracle.rasterise();
    Ok((quantised(&maps.raw), quantised(&maps.height)))
}
