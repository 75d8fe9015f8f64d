//! Reading, downscaling and encoding the images a section embeds.

use std::path::{Path, PathBuf};

use image::imageops::FilterType;

use super::found::Found;
use super::{ImageInfo, ReportOptions, Section, Skipped};

/// One image as embedded (PNG bytes) and copied next to report.md.
#[derive(Debug, Clone)]
pub struct Embedded {
    pub png: Vec<u8>,
    pub width: u32,
    pub height: u32,
}

/// Standard base64 (RFC 4648, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (c.get(1).copied().unwrap_or(0) as u32) << 8
            | c.get(2).copied().unwrap_or(0) as u32;
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= c.len() {
                s.push(A[(n >> shift & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// Read `path`; when wider than `max_width`, resize to that width (aspect kept) and re-encode
/// as PNG; else embed the file's own bytes when they are PNG.
pub fn embed(path: &Path, max_width: u32) -> Result<(Embedded, (u32, u32)), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    let img = image::load_from_memory(&bytes).map_err(|e| format!("not a readable image: {e}"))?;
    let (w, h) = (img.width(), img.height());
    if w == 0 || h == 0 {
        return Err("empty image".into());
    }
    let is_png = bytes.starts_with(b"\x89PNG");
    if w <= max_width && is_png {
        return Ok((
            Embedded {
                png: bytes,
                width: w,
                height: h,
            },
            (w, h),
        ));
    }
    let nw = w.min(max_width.max(1));
    let nh = ((h as u64 * nw as u64) / w as u64).max(1) as u32;
    let small = img.resize_exact(nw, nh, FilterType::Triangle).to_rgb8();
    let png =
        depthsense_viz::plot::encode_rgb(&small).map_err(|e| format!("cannot encode PNG: {e}"))?;
    Ok((
        Embedded {
            png,
            width: nw,
            height: nh,
        },
        (w, h),
    ))
}

/// Read the images of section number `index`; those that fail are skipped (with the reason)
/// and leave an empty grid cell.
pub fn load_section(
    f: Found,
    index: usize,
    opts: &ReportOptions,
    skipped: &mut Vec<Skipped>,
) -> Section {
    let anchor = format!("s{}-{}", index + 1, f.kind.slug());
    let mut images = vec![];
    let mut embedded = vec![];
    // Index in `f.images` → index in `images` (None: failed).
    let mut map = vec![];
    for (k, src) in f.images.iter().enumerate() {
        let width = if src.tile {
            opts.tile_width
        } else {
            opts.max_width
        };
        match embed(&src.path, width) {
            Ok((e, original)) => {
                map.push(Some(images.len()));
                images.push(info(&anchor, k, &src.path, &src.caption, original, &e));
                embedded.push(e);
            }
            Err(reason) => {
                map.push(None);
                skipped.push(Skipped {
                    path: src.path.clone(),
                    reason,
                });
            }
        }
    }
    let grid = f.grid.map(|mut g| {
        for (_, cells) in &mut g.rows {
            for c in cells.iter_mut() {
                *c = c.and_then(|i| map.get(i).copied().flatten());
            }
        }
        g
    });
    Section {
        kind: f.kind,
        title: f.kind.title().to_string(),
        anchor,
        source_dir: f.dir,
        files: f.files,
        command_line: f.command_line,
        inputs: f.inputs,
        doc: f.doc,
        grid,
        images,
        embedded,
    }
}

fn info(
    anchor: &str,
    k: usize,
    path: &Path,
    caption: &str,
    original: (u32, u32),
    e: &Embedded,
) -> ImageInfo {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let clean: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    ImageInfo {
        source: path.to_path_buf(),
        copy: PathBuf::from("img").join(format!("{anchor}-{k:02}-{clean}.png")),
        caption: caption.to_string(),
        original_size: original,
        embedded_size: (e.width, e.height),
        embedded_bytes: e.png.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }
}
