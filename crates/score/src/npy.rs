//! NumPy `.npy` files of float depth maps (format versions 1–3, little-endian `<f4` or
//! `<f8`, C order; shapes (H, W), (1, H, W) or (1, 1, H, W)). Just enough for
//! `eval --predictions` and `predict --data … --format npy`.

use std::path::Path;

use depthsense_dataset::DataError;

const MAGIC: &[u8] = b"\x93NUMPY";

fn bad(path: &Path, why: impl Into<String>) -> DataError {
    DataError::Parse {
        path: path.to_path_buf(),
        reason: why.into(),
    }
}

/// The `.npy` bytes of a float32 (H, W) array.
pub fn encode_f32(data: &[f32], height: usize, width: usize) -> Vec<u8> {
    let dict =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({height}, {width}), }}");
    // magic(6) + version(2) + len(2) + dict + padding + '\n' ≡ 0 (mod 64)
    let unpadded = MAGIC.len() + 2 + 2 + dict.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    let header = format!("{dict}{}\n", " ".repeat(pad));
    let mut out = Vec::with_capacity(10 + header.len() + 4 * data.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Text of `key` in a header dict: `'key': value` up to the next top-level comma.
fn dict_value<'a>(dict: &'a str, key: &str) -> Option<&'a str> {
    let at = dict.find(&format!("'{key}'"))? + key.len() + 2;
    let rest = dict[at..].trim_start().strip_prefix(':')?.trim_start();
    if let Some(r) = rest.strip_prefix('(') {
        return r.find(')').map(|e| &r[..e]);
    }
    let end = rest.find([',', '}']).unwrap_or(rest.len());
    Some(rest[..end].trim().trim_matches('\''))
}

/// Decode a `.npy` float array as (values, height, width).
pub fn decode(bytes: &[u8], path: &Path) -> Result<(Vec<f32>, usize, usize), DataError> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(bad(path, "not a .npy file (magic missing)"));
    }
    let (hlen, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(bad(path, format!("unsupported .npy version {v}"))),
    };
    let dict = bytes
        .get(start..start + hlen)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or_else(|| bad(path, "truncated header"))?;
    let descr = dict_value(dict, "descr").ok_or_else(|| bad(path, "no descr"))?;
    if dict_value(dict, "fortran_order") != Some("False") {
        return Err(bad(path, "Fortran-ordered arrays are not supported"));
    }
    let shape: Vec<usize> = dict_value(dict, "shape")
        .ok_or_else(|| bad(path, "no shape"))?
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|e| bad(path, format!("shape: {e}")))?;
    let (h, w) = match shape.as_slice() {
        [h, w] | [1, h, w] | [1, 1, h, w] => (*h, *w),
        s => return Err(bad(path, format!("shape {s:?} is not (H, W)"))),
    };
    let body = &bytes[start + hlen..];
    // Checked: the shape is read from the file (a huge one must not wrap to a small size).
    let size = |item: usize| h.checked_mul(w).and_then(|n| n.checked_mul(item));
    let values: Vec<f32> = match descr {
        "<f4" if size(4) == Some(body.len()) => body
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        "<f8" if size(8) == Some(body.len()) => body
            .chunks_exact(8)
            .map(|c| {
                let mut a = [0u8; 8];
                a.copy_from_slice(c);
                f64::from_le_bytes(a) as f32
            })
            .collect(),
        "<f4" | "<f8" => {
            return Err(bad(
                path,
                format!("{} data bytes for shape {shape:?} {descr}", body.len()),
            ))
        }
        d => return Err(bad(path, format!("dtype {d} (want <f4 or <f8)"))),
    };
    Ok((values, h, w))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_header_alignment() {
        let v = [1.5f32, -2.0, 80.25, 0.0, 3.0, 7.0];
        let b = encode_f32(&v, 2, 3);
        let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let (d, h, w) = decode(&b, Path::new("x.npy")).unwrap();
        assert_eq!((h, w), (2, 3));
        assert_eq!(d, v);
        // f8, (1, H, W), as numpy writes it
        let dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (1, 1, 2), }";
        let mut b = MAGIC.to_vec();
        b.extend_from_slice(&[1, 0]);
        b.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        b.extend_from_slice(dict.as_bytes());
        b.extend_from_slice(&2.5f64.to_le_bytes());
        b.extend_from_slice(&4.0f64.to_le_bytes());
        let (d, h, w) = decode(&b, Path::new("y.npy")).unwrap();
        assert_eq!((d, h, w), (vec![2.5, 4.0], 1, 2));
        let e = decode(&b[..b.len() - 1], Path::new("z.npy")).unwrap_err();
        assert!(e.to_string().contains("z.npy"), "{e}");
    }

    #[test]
    fn a_shape_whose_size_overflows_is_refused() {
        // 2^32 × 2^32 × 4 wraps to 0 in usize: with 0 data bytes an unchecked product matched.
        let dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296), }";
        let mut b = MAGIC.to_vec();
        b.extend_from_slice(&[1, 0]);
        b.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        b.extend_from_slice(dict.as_bytes());
        let e = decode(&b, Path::new("huge.npy")).unwrap_err().to_string();
        assert!(e.contains("huge.npy") && e.contains("data bytes"), "{e}");
    }
}
