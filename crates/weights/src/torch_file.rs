//! `torch.save` files read into host tensors: the zip format of torch ≥ 1.6 (an archive
//! holding `<name>/data.pkl` and the raw little-endian storages `<name>/data/<key>`) and the
//! legacy format (magic number, protocol, sys-info and object pickles, the storage-key list,
//! then each storage as an 8-byte element count + raw data). Every size in a file is checked
//! against the bytes present before anything is allocated from it (issue 10); a strided view
//! is gathered on the host into a contiguous tensor.

use std::borrow::Cow;
use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use crate::pickle::{collect_tensors, parse_pickle, parse_pickle_at, TensorRef, Value};
use crate::{DType, HostTensor, WeightsError};

/// The magic number opening legacy (pre-1.6) `torch.save` files, little-endian.
const LEGACY_MAGIC: [u8; 10] = [0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19];

/// Reads every tensor of a `torch.save` file onto the CPU (dotted names, file order): the zip
/// format of torch ≥ 1.6 and the legacy format (magic number, protocol, sys-info and object
/// pickles, the storage-key list, then each storage as an 8-byte element count + raw data).
pub fn read_torch_file(path: &Path) -> Result<Vec<(String, HostTensor<'static>)>, WeightsError> {
    let bytes = std::fs::read(path).map_err(|e| WeightsError::io(path, e))?;
    read_torch_bytes(path, &bytes)
}

/// [`read_torch_file`] on bytes already in memory; `path` only names the file in errors.
/// Every size in the file is checked against the bytes present before anything is
/// allocated from it (issue 10).
pub fn read_torch_bytes(
    path: &Path,
    bytes: &[u8],
) -> Result<Vec<(String, HostTensor<'static>)>, WeightsError> {
    if bytes.starts_with(b"PK") {
        read_zip(path, bytes)
    } else if bytes.first() == Some(&0x80) {
        read_legacy(path, bytes)
    } else {
        Err(WeightsError::format(
            path,
            "not a torch.save file (neither a zip archive nor a legacy pickle)",
        ))
    }
}

/// Record `name` of a `torch.save` zip archive (`archive_len` bytes in all), read in full.
fn read_record(
    path: &Path,
    zip: &mut zip::ZipArchive<std::io::Cursor<&[u8]>>,
    archive_len: usize,
    name: &str,
) -> Result<Vec<u8>, WeightsError> {
    let mut e = zip
        .by_name(name)
        .map_err(|e| WeightsError::format(path, format!("missing record {name}: {e}")))?;
    // The declared size is only a hint: never allocate more than deflate can produce
    // from the archive, and never read past the declared size.
    let declared = e.size();
    let possible = (archive_len as u64).saturating_mul(1100);
    if declared > possible {
        return Err(WeightsError::format(
            path,
            format!("record {name} claims {declared} bytes, more than a {archive_len} byte archive can hold"),
        ));
    }
    let mut buf = Vec::with_capacity(declared.min(archive_len as u64) as usize);
    (&mut e)
        .take(declared.saturating_add(1))
        .read_to_end(&mut buf)
        .map_err(|e| {
            WeightsError::format(path, format!("record {name} unreadable (truncated?): {e}"))
        })?;
    if buf.len() as u64 != declared {
        return Err(WeightsError::format(
            path,
            format!(
                "record {name} holds {} bytes, its header says {declared}",
                buf.len()
            ),
        ));
    }
    Ok(buf)
}

fn read_zip(path: &Path, bytes: &[u8]) -> Result<Vec<(String, HostTensor<'static>)>, WeightsError> {
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(|e| {
        WeightsError::format(
            path,
            format!("not a readable zip archive (truncated?): {e}"),
        )
    })?;
    let pkl_name = zip
        .file_names()
        .find(|n| *n == "data.pkl" || n.ends_with("/data.pkl"))
        .map(str::to_string)
        .ok_or_else(|| {
            WeightsError::format(path, "zip archive without data.pkl: not a torch.save file")
        })?;
    let prefix = pkl_name.trim_end_matches("data.pkl").to_string();
    let mut read_entry = |name: &str| read_record(path, &mut zip, bytes.len(), name);
    if let Ok(order) = read_entry(&format!("{prefix}byteorder")) {
        if order.trim_ascii() != b"little" {
            return Err(WeightsError::format(
                path,
                "big-endian torch.save files are not supported",
            ));
        }
    }
    let pkl = read_entry(&pkl_name)?;
    let value =
        parse_pickle(&pkl).map_err(|e| WeightsError::format(path, format!("{pkl_name}: {e}")))?;
    let refs = collect_tensors(&value);
    let mut storages: HashMap<String, Vec<u8>> = HashMap::new();
    for (_, t) in &refs {
        if !storages.contains_key(&t.storage_key) {
            let data = read_entry(&format!("{prefix}data/{}", t.storage_key))?;
            storages.insert(t.storage_key.clone(), data);
        }
    }
    materialize(path, refs, &storages)
}

fn read_legacy(
    path: &Path,
    bytes: &[u8],
) -> Result<Vec<(String, HostTensor<'static>)>, WeightsError> {
    let bad = |m: String| WeightsError::format(path, format!("legacy torch.save file: {m}"));
    let (magic, pos) = parse_pickle_at(bytes, 0).map_err(|e| bad(e.to_string()))?;
    if !matches!(&magic, Value::Bytes(b) if b[..] == LEGACY_MAGIC) {
        return Err(bad("wrong magic number (not a torch.save file)".into()));
    }
    let (_protocol, pos) = parse_pickle_at(bytes, pos).map_err(|e| bad(e.to_string()))?;
    let (_sys_info, pos) = parse_pickle_at(bytes, pos).map_err(|e| bad(e.to_string()))?;
    let (value, pos) = parse_pickle_at(bytes, pos).map_err(|e| bad(e.to_string()))?;
    let (keys, mut pos) = parse_pickle_at(bytes, pos).map_err(|e| bad(e.to_string()))?;
    let keys = match keys {
        Value::List(k) => k,
        _ => return Err(bad("storage key list missing".into())),
    };
    let refs = collect_tensors(&value);
    let types: HashMap<&str, &str> = refs
        .iter()
        .map(|(_, t)| (t.storage_key.as_str(), t.storage_type.as_str()))
        .collect();
    let mut storages = HashMap::new();
    for k in keys {
        let Value::Str(key) = k else {
            return Err(bad("non-string storage key".into()));
        };
        let es = types
            .get(key.as_str())
            .and_then(|t| DType::from_storage_name(t))
            .map_or(1, DType::size);
        if pos + 8 > bytes.len() {
            return Err(bad(format!("truncated before storage {key}")));
        }
        let numel = u64::from_le_bytes(bytes[pos..pos + 8].try_into().unwrap_or([0; 8])) as usize;
        pos += 8;
        let len = numel.checked_mul(es).filter(|&l| l <= bytes.len() - pos);
        let Some(len) = len else {
            return Err(bad(format!(
                "truncated: storage {key} needs {numel}×{es} bytes"
            )));
        };
        storages.insert(key, bytes[pos..pos + len].to_vec());
        pos += len;
    }
    materialize(path, refs, &storages)
}

/// Checks the strided view `t` against a storage of `numel` elements, in checked
/// arithmetic: every number here comes from the file (issue 10). Returns whether the view is
/// empty, or why it is refused.
fn check_view(t: &TensorRef, numel: usize) -> Result<bool, &'static str> {
    if t.size.len() != t.stride.len() {
        return Err("has sizes and strides of different lengths");
    }
    if t.offset < 0 || t.size.iter().any(|&s| s < 0) || t.stride.iter().any(|&s| s < 0) {
        return Err("has a negative size, stride or offset");
    }
    let empty = t.size.contains(&0);
    let view_numel = t
        .size
        .iter()
        .try_fold(1i64, |a, &s| a.checked_mul(s))
        .ok_or("has more elements than fit in 64 bits")?;
    let last = t
        .size
        .iter()
        .zip(&t.stride)
        .try_fold(t.offset, |a, (&s, &st)| {
            (s - 1)
                .max(0)
                .checked_mul(st)
                .and_then(|x| a.checked_add(x))
        })
        .ok_or("overflows")?;
    if !empty && last as u64 >= numel as u64 {
        return Err("exceeds its storage (truncated?)");
    }
    // Stride-0 views would let a few bytes expand into any amount of memory.
    if view_numel as u64 > (numel as u64).max(1 << 16) {
        return Err("expands beyond its storage");
    }
    Ok(empty)
}

fn materialize(
    path: &Path,
    refs: Vec<(String, TensorRef)>,
    storages: &HashMap<String, Vec<u8>>,
) -> Result<Vec<(String, HostTensor<'static>)>, WeightsError> {
    if refs.is_empty() {
        return Err(WeightsError::format(path, "the pickle holds no tensors"));
    }
    let mut out = Vec::with_capacity(refs.len());
    for (name, t) in refs {
        let dtype = DType::from_storage_name(&t.storage_type).ok_or_else(|| {
            WeightsError::format(
                path,
                format!("tensor {name}: unsupported storage {}", t.storage_type),
            )
        })?;
        let data = storages.get(&t.storage_key).ok_or_else(|| {
            WeightsError::format(
                path,
                format!("tensor {name}: storage {} missing", t.storage_key),
            )
        })?;
        let es = dtype.size();
        let numel = data.len() / es;
        let empty = check_view(&t, numel).map_err(|why| {
            WeightsError::format(
                path,
                format!(
                    "tensor {name}: view {:?}/{:?}+{} {why} (storage of {numel} elements)",
                    t.size, t.stride, t.offset
                ),
            )
        })?;
        let bytes = if empty {
            Vec::new()
        } else {
            gather(&data[..numel * es], es, &t)
        };
        out.push((
            name,
            HostTensor {
                dtype,
                shape: t.size,
                data: Cow::Owned(bytes),
            },
        ));
    }
    Ok(out)
}

/// The elements of the strided view `t` of `storage` (elements of `es` bytes) in row-major
/// order. `t` passed [`check_view`]: every index lies inside `storage`.
fn gather(storage: &[u8], es: usize, t: &TensorRef) -> Vec<u8> {
    let size: Vec<usize> = t.size.iter().map(|&s| s as usize).collect();
    let stride: Vec<usize> = t.stride.iter().map(|&s| s as usize).collect();
    let numel: usize = size.iter().product();
    let mut out = Vec::with_capacity(numel * es);
    let contiguous = {
        let mut want = 1usize;
        let mut ok = true;
        for d in (0..size.len()).rev() {
            if size[d] > 1 && stride[d] != want {
                ok = false;
            }
            want *= size[d];
        }
        ok
    };
    let offset = t.offset as usize;
    if contiguous {
        out.extend_from_slice(&storage[offset * es..(offset + numel) * es]);
        return out;
    }
    let mut index = vec![0usize; size.len()];
    for _ in 0..numel {
        let at = offset + index.iter().zip(&stride).map(|(i, s)| i * s).sum::<usize>();
        out.extend_from_slice(&storage[at * es..(at + 1) * es]);
        for d in (0..size.len()).rev() {
            index[d] += 1;
            if index[d] < size[d] {
                break;
            }
            index[d] = 0;
        }
    }
    out
}

/// Is `path` a `torch.save` file (zip or legacy pickle) rather than a safetensors file?
/// Decided by content: zip files start with `PK\x03\x04`, legacy `torch.save` pickles with
/// the protocol opcode 0x80; a safetensors file starts with its header length.
pub fn is_torch_file(path: &Path) -> Result<bool, WeightsError> {
    let mut head = [0u8; 9];
    let mut f = std::fs::File::open(path).map_err(|e| WeightsError::io(path, e))?;
    let len = f.metadata().map_err(|e| WeightsError::io(path, e))?.len();
    let n = f.read(&mut head).map_err(|e| WeightsError::io(path, e))?;
    // A safetensors file first: its header length (little-endian u64) may well start with the
    // byte 0x80 (a header of 128 + 256·k bytes), the legacy pickle's first opcode.
    let header_len = u64::from_le_bytes([
        head[0], head[1], head[2], head[3], head[4], head[5], head[6], head[7],
    ]);
    if n == 9 && head[8] == b'{' && header_len >= 2 && header_len <= len.saturating_sub(8) {
        return Ok(false);
    }
    let zip = n >= 4 && head[..4] == *b"PK\x03\x04";
    // PROTO 2..5: what torch.save's legacy format starts with.
    let legacy_pickle = n >= 2 && head[0] == 0x80 && (2..=5).contains(&head[1]);
    Ok(zip || legacy_pickle)
}
