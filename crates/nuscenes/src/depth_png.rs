//! KITTI-style 16-bit depth PNGs (SPEC §3): value = round(depth_m × 256), 0 = no data.
//!
//! Shared by `prep` (training-frame maps), `synth` (rendered truth) and `train`
//! (predictions), so that every map in the project has one encoding.

use std::path::{Path, PathBuf};

use depthsense_base::fsutil::write_atomic;

/// Scale between metres and the stored 16-bit value.
pub const DEPTH_SCALE: f32 = 256.0;
/// Largest depth a 16-bit map can hold (65535 / 256 ≈ 255.996 m).
pub const MAX_DEPTH_M: f32 = u16::MAX as f32 / DEPTH_SCALE;

#[derive(Debug, thiserror::Error)]
pub enum DepthPngError {
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot decode PNG: {reason}")]
    Decode { path: String, reason: String },
    #[error("{path}: expected a 16-bit single-channel PNG, found {found}")]
    Format { path: String, found: String },
    #[error("depth map has {got} values but {width}x{height} needs {want}")]
    Size {
        width: u32,
        height: u32,
        got: usize,
        want: usize,
    },
}

/// A depth map in metres, row-major, `0.0` where there is no data.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    pub width: u32,
    pub height: u32,
    pub depth_m: Vec<f32>,
}

impl DepthMap {
    pub fn zeros(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            depth_m: vec![0.0; width as usize * height as usize],
        }
    }

    /// Depth at pixel (u = column, v = row).
    pub fn at(&self, u: u32, v: u32) -> f32 {
        self.depth_m[v as usize * self.width as usize + u as usize]
    }

    /// Number of pixels holding data.
    pub fn valid_count(&self) -> usize {
        self.depth_m.iter().filter(|d| **d > 0.0).count()
    }
}

/// Metres → stored value. Non-finite and non-positive depths become 0 (no data);
/// depths beyond [`MAX_DEPTH_M`] saturate.
pub fn encode_value(depth_m: f32) -> u16 {
    if !depth_m.is_finite() || depth_m <= 0.0 {
        return 0;
    }
    // A tiny positive depth must not turn into "no data".
    (depth_m * DEPTH_SCALE).round().clamp(1.0, u16::MAX as f32) as u16
}

/// Stored value → metres.
pub fn decode_value(value: u16) -> f32 {
    value as f32 / DEPTH_SCALE
}

/// Encode a depth map as 16-bit grayscale PNG bytes (default compression: smallest files).
pub fn encode_png(map: &DepthMap) -> Result<Vec<u8>, DepthPngError> {
    encode_with(map, image::codecs::png::CompressionType::Default)
}

/// Like [`encode_png`] but with the PNG encoder's fast compression (larger files, several
/// times faster to write; decodes to the same values). Used by `prepare`.
pub fn encode_png_fast(map: &DepthMap) -> Result<Vec<u8>, DepthPngError> {
    encode_with(map, image::codecs::png::CompressionType::Fast)
}

fn encode_with(
    map: &DepthMap,
    compression: image::codecs::png::CompressionType,
) -> Result<Vec<u8>, DepthPngError> {
    let values: Vec<u16> = map.depth_m.iter().map(|&d| encode_value(d)).collect();
    encode_u16(map.width, map.height, &values, compression)
}

/// A 16-bit grey PNG of stored values (row-major `width × height`, e.g. [`encode_value`]s),
/// written as [`encode_png_fast`] writes a map: for callers that already hold stored values.
pub fn encode_png16_fast(
    width: u32,
    height: u32,
    values: &[u16],
) -> Result<Vec<u8>, DepthPngError> {
    encode_u16(
        width,
        height,
        values,
        image::codecs::png::CompressionType::Fast,
    )
}

fn encode_u16(
    width: u32,
    height: u32,
    values: &[u16],
    compression: image::codecs::png::CompressionType,
) -> Result<Vec<u8>, DepthPngError> {
    use image::ImageEncoder;
    let want = width as usize * height as usize;
    if values.len() != want {
        return Err(DepthPngError::Size {
            width,
            height,
            got: values.len(),
            want,
        });
    }
    // `image` takes 16-bit samples in native byte order and writes them big-endian.
    let raw: Vec<u8> = values.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let mut out = Vec::with_capacity(values.len());
    image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        compression,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(&raw, width, height, image::ExtendedColorType::L16)
    .map_err(|e| DepthPngError::Decode {
        path: "<memory>".into(),
        reason: e.to_string(),
    })?;
    Ok(out)
}

/// Write a depth map atomically (temp file + rename).
pub fn write_depth_png(path: &Path, map: &DepthMap) -> Result<(), DepthPngError> {
    let bytes = encode_png(map)?;
    write_atomic(path, &bytes).map_err(|source| DepthPngError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Largest decoded/compressed size ratio accepted (deflate's own limit is about 1032:1).
const MAX_INFLATE_RATIO: u64 = 1100;
/// Decoded bytes always allowed, whatever the file size.
const MIN_DECODE_BUDGET: u64 = 1 << 20;
/// Decoded bytes never exceeded.
const MAX_DECODE_BUDGET: u64 = 512 << 20;

/// Decode 16-bit PNG bytes into metres. `name` only labels errors.
///
/// The image size in the header is checked against the file length before anything is
/// allocated (issue 10): a PNG cannot inflate to more than ~1100× its length, so a tiny file
/// claiming 30000×30000 pixels is refused with an error, not a 1.8 GB allocation.
pub fn decode_png(bytes: &[u8], name: &str) -> Result<DepthMap, DepthPngError> {
    let decode_err = |reason: String| DepthPngError::Decode {
        path: name.to_string(),
        reason,
    };
    let budget = (bytes.len() as u64)
        .saturating_mul(MAX_INFLATE_RATIO)
        .clamp(MIN_DECODE_BUDGET, MAX_DECODE_BUDGET);
    // IHDR is the first chunk: signature (8), length (4), "IHDR" (4), width, height (BE u32).
    if bytes.len() >= 24 && &bytes[12..16] == b"IHDR" {
        let w = u32::from_be_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]) as u64;
        let h = u32::from_be_bytes([bytes[20], bytes[21], bytes[22], bytes[23]]) as u64;
        // ≥ 2 bytes per pixel for the 16-bit maps this reader accepts.
        let need = w.saturating_mul(h).saturating_mul(2);
        if need > budget {
            return Err(decode_err(format!(
                "header claims {w}x{h} pixels, more than a {} byte PNG can hold",
                bytes.len()
            )));
        }
    }
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(budget.saturating_mul(2));
    let mut reader =
        image::ImageReader::with_format(std::io::Cursor::new(bytes), image::ImageFormat::Png);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| decode_err(e.to_string()))?;
    let found = format!("{:?}", img.color());
    let luma = match img {
        image::DynamicImage::ImageLuma16(buf) => buf,
        _ => {
            return Err(DepthPngError::Format {
                path: name.to_string(),
                found,
            })
        }
    };
    let (width, height) = luma.dimensions();
    let depth_m = luma.into_raw().into_iter().map(decode_value).collect();
    Ok(DepthMap {
        width,
        height,
        depth_m,
    })
}

/// Read a 16-bit depth PNG into metres.
pub fn read_depth_png(path: &Path) -> Result<DepthMap, DepthPngError> {
    let bytes = std::fs::read(path).map_err(|source| DepthPngError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode_png(&bytes, &path.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_encoder_decodes_to_the_same_values() {
        let mut m = DepthMap::zeros(37, 5);
        for (i, d) in m.depth_m.iter_mut().enumerate() {
            *d = if i % 3 == 0 { 0.0 } else { i as f32 * 1.37 };
        }
        let a = decode_png(&encode_png(&m).unwrap(), "a").unwrap();
        let b = decode_png(&encode_png_fast(&m).unwrap(), "b").unwrap();
        assert_eq!(a, b);
        assert_eq!(b.at(1, 0), (1.37f32 * 256.0).round() / 256.0);
    }

    #[test]
    fn value_scale_is_256_per_metre() {
        assert_eq!(encode_value(1.0), 256);
        assert_eq!(encode_value(10.5), 2688);
        assert_eq!(encode_value(0.0), 0);
        assert_eq!(encode_value(-3.0), 0);
        assert_eq!(encode_value(f32::NAN), 0);
        assert_eq!(encode_value(1e-4), 1);
        assert_eq!(encode_value(1000.0), u16::MAX);
        assert_eq!(decode_value(2688), 10.5);
    }

    #[test]
    fn png_round_trip_keeps_quantised_depths() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.png");
        let mut map = DepthMap::zeros(5, 3);
        map.depth_m[0] = 1.0;
        map.depth_m[7] = 42.123;
        map.depth_m[14] = 79.99;
        write_depth_png(&path, &map).unwrap();
        let back = read_depth_png(&path).unwrap();
        assert_eq!((back.width, back.height), (5, 3));
        for (a, b) in map.depth_m.iter().zip(&back.depth_m) {
            assert!((a - b).abs() <= 0.5 / DEPTH_SCALE, "{a} vs {b}");
        }
        assert_eq!(back.valid_count(), 3);
        assert_eq!(back.at(2, 1), (42.123f32 * 256.0).round() / 256.0);
    }

    #[test]
    fn hostile_png_headers_are_errors_not_allocations() {
        // issue 10 defect 4: a valid tiny PNG whose IHDR claims 30000×30000 (and 2^32-1
        // squared) pixels; the CRC is fixed up so that only the size is wrong.
        let good = encode_png(&DepthMap::zeros(4, 3)).unwrap();
        for (w, h) in [(30_000u32, 30_000u32), (u32::MAX, u32::MAX), (1 << 20, 2)] {
            let mut b = good.clone();
            b[16..20].copy_from_slice(&w.to_be_bytes());
            b[20..24].copy_from_slice(&h.to_be_bytes());
            let crc = crc32(&b[12..29]);
            b[29..33].copy_from_slice(&crc.to_be_bytes());
            let err = decode_png(&b, "huge.png").unwrap_err().to_string();
            assert!(err.contains("huge.png"), "{err}");
        }
        // truncated files and garbage name the file
        for cut in [0, 7, 8, 20, 33, good.len() / 2] {
            let err = decode_png(&good[..cut], "cut.png").unwrap_err().to_string();
            assert!(err.contains("cut.png"), "{err}");
        }
    }

    fn crc32(data: &[u8]) -> u32 {
        let mut c = 0xffff_ffffu32;
        for &b in data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }

    #[test]
    fn eight_bit_png_is_rejected_with_its_name() {
        let img = image::GrayImage::new(2, 2);
        let mut bytes = std::io::Cursor::new(Vec::new());
        img.write_to(&mut bytes, image::ImageFormat::Png).unwrap();
        let err = decode_png(bytes.get_ref(), "x/y.png").unwrap_err();
        assert!(err.to_string().contains("x/y.png"), "{err}");
    }
}
