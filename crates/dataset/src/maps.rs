//! Reading a prepared sample's files (`depthsense_prep::layout`): meta.json, 16-bit depth
//! PNGs, the RGB image and the low-height mask, each error naming the file.

use std::path::Path;

use depthsense_nuscenes::depth_png::{decode_png, DepthMap};
use depthsense_prep::layout::{LOWHEIGHT_MASK_FILE, META_FILE};

use crate::error::DataError;

/// A sample directory's `meta.json`.
pub fn read_meta(dir: &Path) -> Result<depthsense_prep::layout::SampleMeta, DataError> {
    let p = dir.join(META_FILE);
    serde_json::from_slice(&read_file(&p)?).map_err(|e| DataError::Parse {
        path: p.to_path_buf(),
        reason: e.to_string(),
    })
}

fn read_file(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

pub fn read_depth(path: &Path) -> Result<DepthMap, DataError> {
    let bytes = read_file(path)?;
    decode_png(&bytes, &path.display().to_string()).map_err(|e| DataError::Data(e.to_string()))
}

pub fn decode_rgb(path: &Path) -> Result<image::RgbImage, DataError> {
    decode_rgb_bytes(&read_file(path)?, path)
}

/// An image file's bytes (PNG, JPEG: the format is read from the bytes) as RGB8, decoded as
/// [`decode_rgb`] decodes a file; `path` names it in errors.
pub fn decode_rgb_bytes(bytes: &[u8], path: &Path) -> Result<image::RgbImage, DataError> {
    let img = image::load_from_memory(bytes).map_err(|e| DataError::Parse {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    Ok(img.to_rgb8())
}

pub fn check_size(map: &DepthMap, w: usize, h: usize, path: &Path) -> Result<(), DataError> {
    if map.width as usize != w || map.height as usize != h {
        return Err(DataError::Data(format!(
            "{}: map is {}x{} but the image is {w}x{h}",
            path.display(),
            map.width,
            map.height
        )));
    }
    Ok(())
}

/// A sample's low-height mask (SPEC §4) as w×h booleans, empty when the sample has none; a
/// mask of another size is an error naming the file.
pub fn read_lowheight_mask(dir: &Path, w: usize, h: usize) -> Result<Vec<bool>, DataError> {
    let mpath = dir.join(LOWHEIGHT_MASK_FILE);
    if !mpath.exists() {
        return Ok(Vec::new());
    }
    let m = decode_rgb_luma(&mpath)?;
    if m.len() != w * h {
        return Err(DataError::Data(format!(
            "{}: mask has {} pixels, expected {}",
            mpath.display(),
            m.len(),
            w * h
        )));
    }
    Ok(m)
}

fn decode_rgb_luma(path: &Path) -> Result<Vec<bool>, DataError> {
    let bytes = read_file(path)?;
    let img = image::load_from_memory(&bytes).map_err(|e| DataError::Parse {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    Ok(img.to_luma8().pixels().map(|p| p.0[0] > 127).collect())
}
