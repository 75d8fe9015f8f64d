//! Reading a prepared sample's files (`depthsense_prep::layout`): meta.json, 16-bit depth
//! PNGs, the RGB image and the low-height mask, each error naming the file.

use std::path::Path;

use depthsense_nuscenes::depth_png::{decode_png, DepthMap};
use depthsense_prep::layout::{INDEX_FILE, LOWHEIGHT_MASK_FILE, META_FILE};

use crate::error::{DataError, SampleFolder};

/// `dir` is one prepared sample's folder (it holds `meta.json`); if not, an error that says
/// what it is instead (a prepared folder, another folder, nothing) and what to pass.
pub fn check_sample_dir(dir: &Path) -> Result<(), DataError> {
    if dir.join(META_FILE).exists() {
        return Ok(());
    }
    let found = if dir.join(INDEX_FILE).exists() {
        SampleFolder::Prepared
    } else if dir.is_dir() {
        SampleFolder::Other
    } else {
        SampleFolder::Missing
    };
    Err(DataError::NotASample {
        dir: dir.display().to_string(),
        found,
    })
}

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
    Ok(decode_png(&bytes, &path.display().to_string())?)
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
        return Err(DataError::MapSize {
            path: path.to_path_buf(),
            size: (map.width as usize, map.height as usize),
            image: (w, h),
        });
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
        return Err(DataError::MaskSize {
            path: mpath,
            pixels: m.len(),
            expected: w * h,
        });
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A map of another size than its image is refused with both sizes.
    #[test]
    fn a_map_of_another_size_names_both() {
        let map = DepthMap {
            width: 4,
            height: 2,
            depth_m: vec![0.0; 8],
        };
        assert!(check_size(&map, 4, 2, Path::new("s/radar.png")).is_ok());
        let e = check_size(&map, 8, 2, Path::new("s/radar.png")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "data: s/radar.png: map is 4x2 but the image is 8x2"
        );
        assert!(matches!(
            e,
            DataError::MapSize {
                size: (4, 2),
                image: (8, 2),
                ..
            }
        ));
    }

    /// A low-height mask of another size than its image is refused with both pixel counts; a
    /// depth PNG that cannot be decoded keeps the decoder's words behind `data: `.
    #[test]
    fn a_mask_of_another_size_and_a_broken_png_are_named() {
        let d = tempfile::tempdir().unwrap();
        let mask = d.path().join(LOWHEIGHT_MASK_FILE);
        image::RgbImage::new(2, 2).save(&mask).unwrap();
        assert_eq!(read_lowheight_mask(d.path(), 2, 2).unwrap().len(), 4);
        let e = read_lowheight_mask(d.path(), 4, 2).unwrap_err();
        assert!(matches!(
            &e,
            DataError::MaskSize { path, pixels: 4, expected: 8 } if path == &mask
        ));
        assert_eq!(
            e.to_string(),
            format!("data: {}: mask has 4 pixels, expected 8", mask.display())
        );
        let png = d.path().join("radar.png");
        std::fs::write(&png, b"not a png").unwrap();
        let e = read_depth(&png).unwrap_err();
        assert!(matches!(e, DataError::Png(_)), "{e:?}");
        assert!(
            e.to_string()
                .starts_with(&format!("data: {}: ", png.display())),
            "{e}"
        );
    }

    /// A folder passed as one sample that is not one says what it is and what to pass, in the
    /// words `predict --sample` has always used.
    #[test]
    fn a_folder_that_is_not_one_sample_says_what_it_is() {
        let d = tempfile::tempdir().unwrap();
        let prepared = d.path().join("toy");
        std::fs::create_dir(&prepared).unwrap();
        std::fs::write(prepared.join(INDEX_FILE), "{}").unwrap();
        let p = prepared.display();
        assert_eq!(
            check_sample_dir(&prepared).unwrap_err().to_string(),
            format!(
                "{p} is a prepared folder, not one sample: pass --sample {p}/<sample token> \
                 for one of its samples, or --data {p} for a split of them"
            )
        );
        let other = d.path().join("other");
        std::fs::create_dir(&other).unwrap();
        assert_eq!(
            check_sample_dir(&other).unwrap_err().to_string(),
            format!(
                "{}: not a prepared sample folder (no meta.json); --sample takes one \
                 PREPARED/<sample token> folder written by `depthsense prepare`",
                other.display()
            )
        );
        let missing = d.path().join("missing");
        let e = check_sample_dir(&missing).unwrap_err();
        assert!(matches!(
            e,
            DataError::NotASample {
                found: SampleFolder::Missing,
                ..
            }
        ));
        assert_eq!(
            e.to_string(),
            format!(
                "{}: no such folder; --sample takes one PREPARED/<sample token> folder \
                 written by `depthsense prepare`",
                missing.display()
            )
        );
        let sample = d.path().join("tok");
        std::fs::create_dir(&sample).unwrap();
        std::fs::write(sample.join(META_FILE), "{}").unwrap();
        assert!(check_sample_dir(&sample).is_ok());
    }

    /// A record that cannot be encoded names its file, the encoder's reason kept as the cause.
    #[test]
    fn an_encode_error_names_the_file() {
        use std::error::Error;
        let json = serde_json::from_str::<serde_json::Value>("{").unwrap_err();
        let why = json.to_string();
        let e = DataError::encode(Path::new("e/tables.json"), json);
        assert_eq!(
            e.to_string(),
            format!("e/tables.json: cannot encode: {why}")
        );
        assert_eq!(e.source().map(|s| s.to_string()), Some(why));
        let io = std::io::Error::other("Resource temporarily unavailable");
        let e = DataError::thread_start("loader threads", io);
        assert_eq!(
            e.to_string(),
            "cannot start loader threads: Resource temporarily unavailable"
        );
        assert!(e.source().is_some());
    }
}
