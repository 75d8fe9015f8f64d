//! The safetensors container of our checkpoints: an 8-byte little-endian header length, a
//! JSON header (`__metadata__` strings; per tensor its dtype, shape and `data_offsets`), then
//! the data. [`serialize`] writes the tensors sorted by name at consecutive offsets, the
//! header padded with spaces to a multiple of 8; [`parse`] checks every length and offset, so
//! that a truncated or foreign file is a clear error, never a panic or a huge allocation.
//!
//! Our own ~100 lines rather than the `safetensors` crate: its writer orders and pads the
//! header differently (so a checkpoint's bytes, and the SHA-256 that `export` records, would
//! change) and its errors do not name the tensor at fault. The crate checks both directions
//! in the tests.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::Path;

use crate::{DType, HostTensor, WeightsError};

/// The tensors of a file (in header order) and its metadata.
pub type Parsed<'a> = (Vec<(String, HostTensor<'a>)>, BTreeMap<String, String>);

/// Safetensors bytes of named tensors with string metadata.
pub fn serialize(tensors: &[(String, HostTensor)], metadata: &BTreeMap<String, String>) -> Vec<u8> {
    let mut header = serde_json::Map::new();
    header.insert(
        "__metadata__".into(),
        serde_json::to_value(metadata).unwrap_or_default(),
    );
    let mut sorted: Vec<&(String, HostTensor)> = tensors.iter().collect();
    sorted.sort_by(|a, b| a.0.cmp(&b.0));
    let mut offset = 0usize;
    for (name, t) in &sorted {
        let end = offset + t.data.len();
        header.insert(
            name.clone(),
            serde_json::json!({
                "dtype": t.dtype.safetensors_name(),
                "shape": t.shape,
                "data_offsets": [offset, end],
            }),
        );
        offset = end;
    }
    let mut h = serde_json::to_vec(&serde_json::Value::Object(header)).unwrap_or_default();
    while !h.len().is_multiple_of(8) {
        h.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + h.len() + offset);
    out.extend_from_slice(&(h.len() as u64).to_le_bytes());
    out.extend_from_slice(&h);
    for (_, t) in sorted {
        out.extend_from_slice(&t.data);
    }
    out
}

/// The header's length from a file's first 8 bytes, checked against the file's `total` length
/// (bytes) and a 100 MiB cap, so that a foreign or truncated file is an error, never a huge
/// allocation.
fn header_len(path: &Path, first8: &[u8], total: u64) -> Result<usize, WeightsError> {
    let bad = |m: String| WeightsError::format(path, m);
    let n = match <[u8; 8]>::try_from(first8) {
        Ok(b) if total >= 8 => u64::from_le_bytes(b),
        _ => return Err(bad(format!("not a safetensors file ({total} bytes)"))),
    };
    if n > total - 8 || n > 100 << 20 {
        return Err(bad(format!(
            "not a safetensors file or truncated: header length {n} but the file has {total} bytes"
        )));
    }
    Ok(n as usize)
}

/// The JSON header of `bytes[8..]` (`n` bytes, see [`header_len`]).
fn header_json(
    path: &Path,
    text: &[u8],
) -> Result<serde_json::Map<String, serde_json::Value>, WeightsError> {
    serde_json::from_slice(text).map_err(|e| {
        WeightsError::format(
            path,
            format!("not a safetensors file: header is not JSON ({e})"),
        )
    })
}

/// The JSON header of safetensors `bytes` and the data section after it.
fn split<'b>(
    path: &Path,
    bytes: &'b [u8],
) -> Result<(serde_json::Map<String, serde_json::Value>, &'b [u8]), WeightsError> {
    let n = header_len(path, &bytes[..bytes.len().min(8)], bytes.len() as u64)?;
    let header = header_json(path, &bytes[8..8 + n])?;
    Ok((header, &bytes[8 + n..]))
}

/// The `__metadata__` strings of a header.
fn metadata_of(header: &serde_json::Map<String, serde_json::Value>) -> BTreeMap<String, String> {
    let mut meta = BTreeMap::new();
    if let Some(m) = header.get("__metadata__").and_then(|v| v.as_object()) {
        for (k, v) in m {
            meta.insert(k.clone(), v.as_str().unwrap_or_default().to_string());
        }
    }
    meta
}

/// The metadata of the safetensors file at `path`, reading its header only (8 bytes and the
/// JSON): a model config or a training state without the tensors' hundreds of megabytes.
/// Of the tensors' entries only their extent is checked — a file cut inside its data section
/// is an error here too; [`parse`] checks each entry whole when the tensors are read.
pub fn read_metadata(path: &Path) -> Result<BTreeMap<String, String>, WeightsError> {
    use std::io::Read;
    let io = |e| WeightsError::io(path, e);
    let mut f = std::fs::File::open(path).map_err(io)?;
    let total = f.metadata().map_err(io)?.len();
    let mut first8 = Vec::with_capacity(8);
    (&mut f).take(8).read_to_end(&mut first8).map_err(io)?;
    let n = header_len(path, &first8, total)?;
    let mut text = vec![0u8; n];
    f.read_exact(&mut text).map_err(io)?;
    let header = header_json(path, &text)?;
    let data_len = total - 8 - n as u64;
    if let Some((name, end)) = last_tensor_end(&header).filter(|&(_, end)| end > data_len) {
        return Err(truncated(path, name, end, data_len));
    }
    Ok(metadata_of(&header))
}

/// A file whose data section (`data_len` bytes) ends before tensor `name`'s end.
fn truncated(path: &Path, name: &str, end: u64, data_len: u64) -> WeightsError {
    WeightsError::format(
        path,
        format!(
            "truncated: tensor {name} ends at byte {end} of the data section but it holds only \
             {data_len} bytes"
        ),
    )
}

/// The tensor entry of `header` whose `data_offsets` end last, with that end (entries without
/// readable offsets are left to [`parse`]).
fn last_tensor_end(header: &serde_json::Map<String, serde_json::Value>) -> Option<(&str, u64)> {
    header
        .iter()
        .filter(|(name, _)| *name != "__metadata__")
        .filter_map(|(name, v)| {
            let end = v.get("data_offsets")?.as_array()?.get(1)?.as_u64()?;
            Some((name.as_str(), end))
        })
        .max_by_key(|&(_, end)| end)
}

/// Tensor `name` of a safetensors header: its entry `v` checked against the `data` section.
fn tensor<'b>(
    path: &Path,
    name: &str,
    v: &serde_json::Value,
    data: &'b [u8],
) -> Result<HostTensor<'b>, WeightsError> {
    let bad = |m: String| WeightsError::format(path, m);
    let dtype_s = v.get("dtype").and_then(|d| d.as_str()).unwrap_or("");
    let dtype = DType::from_safetensors_name(dtype_s)
        .ok_or_else(|| bad(format!("tensor {name}: unsupported dtype `{dtype_s}`")))?;
    // Every dimension must be a non-negative integer; the element count and byte length
    // are computed in checked arithmetic (issue 10: sizes come from the file).
    let shape: Vec<i64> = v
        .get("shape")
        .and_then(|s| s.as_array())
        .and_then(|a| {
            a.iter()
                .map(|x| x.as_i64().filter(|&d| d >= 0))
                .collect::<Option<Vec<i64>>>()
        })
        .ok_or_else(|| {
            bad(format!(
                "tensor {name}: no shape, or a dimension that is not a non-negative integer"
            ))
        })?;
    let offs: Vec<usize> = v
        .get("data_offsets")
        .and_then(|s| s.as_array())
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_u64().map(|u| u as usize))
                .collect()
        })
        .unwrap_or_default();
    if offs.len() != 2 || offs[0] > offs[1] {
        return Err(bad(format!("tensor {name}: bad data_offsets")));
    }
    let nbytes = shape
        .iter()
        .try_fold(dtype.size() as u64, |a, &d| a.checked_mul(d as u64))
        .ok_or_else(|| bad(format!("tensor {name}: shape {shape:?} overflows")))?;
    if (offs[1] - offs[0]) as u64 != nbytes {
        return Err(bad(format!(
            "tensor {name}: {} bytes for shape {shape:?} {dtype_s}",
            offs[1] - offs[0]
        )));
    }
    if offs[1] > data.len() {
        return Err(truncated(path, name, offs[1] as u64, data.len() as u64));
    }
    Ok(HostTensor {
        dtype,
        shape,
        data: Cow::Borrowed(&data[offs[0]..offs[1]]),
    })
}

/// Parses safetensors bytes: (tensors in header order, metadata), the tensors borrowing
/// `bytes`. `path` only names the file in errors.
pub fn parse<'b>(path: &Path, bytes: &'b [u8]) -> Result<Parsed<'b>, WeightsError> {
    let (header, data) = split(path, bytes)?;
    let mut out = Vec::new();
    for (name, v) in &header {
        if name != "__metadata__" {
            out.push((name.clone(), tensor(path, name, v, data)?));
        }
    }
    Ok((out, metadata_of(&header)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<(String, HostTensor<'static>)> {
        let f: Vec<u8> = [1.0f32, -2.5, 3.25, 0.0, 7.0, 8.5]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let i: Vec<u8> = [7i64, -8].iter().flat_map(|x| x.to_le_bytes()).collect();
        vec![
            (
                "w".into(),
                HostTensor {
                    dtype: DType::F32,
                    shape: vec![2, 3],
                    data: Cow::Owned(f),
                },
            ),
            (
                "b.idx".into(),
                HostTensor {
                    dtype: DType::I64,
                    shape: vec![2],
                    data: Cow::Owned(i),
                },
            ),
            (
                "flag".into(),
                HostTensor {
                    dtype: DType::Bool,
                    shape: vec![],
                    data: Cow::Owned(vec![1]),
                },
            ),
        ]
    }

    #[test]
    fn round_trip_and_the_reference_crate_agrees_both_ways() {
        let tensors = sample();
        let meta = BTreeMap::from([("format".to_string(), "x".to_string())]);
        let bytes = serialize(&tensors, &meta);
        let (back, meta_back) = parse(Path::new("t"), &bytes).unwrap();
        assert_eq!(meta_back, meta);
        let mut want = tensors.clone();
        want.sort_by(|a, b| a.0.cmp(&b.0));
        assert_eq!(back, want, "sorted by name at consecutive offsets");

        // the `safetensors` crate reads our bytes …
        let st = ::safetensors::SafeTensors::deserialize(&bytes).unwrap();
        for (name, t) in &tensors {
            let v = st.tensor(name).unwrap();
            assert_eq!(v.data(), &t.data[..], "{name}");
            let shape: Vec<i64> = v.shape().iter().map(|&d| d as i64).collect();
            assert_eq!(shape, t.shape);
        }
        // … and we read its bytes
        let views: Vec<(String, ::safetensors::tensor::TensorView)> = tensors
            .iter()
            .map(|(n, t)| {
                let dt = match t.dtype {
                    DType::F32 => ::safetensors::Dtype::F32,
                    DType::I64 => ::safetensors::Dtype::I64,
                    _ => ::safetensors::Dtype::BOOL,
                };
                let shape = t.shape.iter().map(|&d| d as usize).collect();
                (
                    n.clone(),
                    ::safetensors::tensor::TensorView::new(dt, shape, &t.data).unwrap(),
                )
            })
            .collect();
        let theirs = ::safetensors::serialize(views, &None).unwrap();
        let (ours, _) = parse(Path::new("theirs"), &theirs).unwrap();
        for (name, t) in &tensors {
            let got = ours.iter().find(|(n, _)| n == name).unwrap();
            assert_eq!(&got.1, t, "{name}");
        }
    }

    #[test]
    fn truncation_and_bad_headers_are_named_errors() {
        let bytes = serialize(&sample(), &BTreeMap::new());
        for cut in [0, 7, 8, 20, bytes.len() - 1] {
            let e = parse(Path::new("cut.safetensors"), &bytes[..cut]).unwrap_err();
            assert!(e.to_string().starts_with("cut.safetensors: "), "{e}");
        }
        let e = parse(Path::new("cut"), &bytes[..bytes.len() - 1])
            .unwrap_err()
            .to_string();
        assert!(e.contains("truncated: tensor w ends at byte"), "{e}");
    }

    /// The header alone gives the metadata that the whole parse gives; a file cut inside its
    /// header or its data, or with a header length beyond its end, is an error naming it.
    #[test]
    fn the_metadata_is_read_from_the_header_alone() {
        let d = tempfile::tempdir().unwrap();
        let meta: BTreeMap<String, String> = [("format", "x"), ("depthsense.config", "{}")]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        let bytes = serialize(&sample(), &meta);
        let path = d.path().join("m.safetensors");
        std::fs::write(&path, &bytes).unwrap();
        assert_eq!(read_metadata(&path).unwrap(), meta);
        assert_eq!(parse(&path, &bytes).unwrap().1, meta);
        // The data section is not read, but its length is checked against the entries: a file
        // cut inside it is refused as parse refuses it (a checkpoint whose write was cut short
        // is not said finished).
        let n = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        for cut in [n, bytes.len() - 1] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let e = read_metadata(&path).unwrap_err().to_string();
            let parsed = parse(&path, &bytes[..cut]).unwrap_err().to_string();
            let truncated = format!("{}: truncated: tensor ", path.display());
            assert!(e.starts_with(&truncated), "{cut}: {e}");
            assert!(parsed.starts_with(&truncated), "{cut}: {parsed}");
        }
        for cut in [0, 5, 8, n - 1] {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let e = read_metadata(&path).unwrap_err().to_string();
            assert!(
                e.starts_with(&format!("{}: ", path.display())),
                "{cut}: {e}"
            );
        }
        let e = read_metadata(&d.path().join("none")).unwrap_err();
        assert!(matches!(e, WeightsError::Io { .. }), "{e}");
    }
}
