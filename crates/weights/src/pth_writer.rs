//! A `torch.save`-compatible state-dict writer (feature `pth-writer`): test support and fuzz
//! seeds only — no library path of the network writes `.pth` files. What
//! `torch.save(model.state_dict(), path)` produces: a zip (stored, not deflated) of
//! `archive/data.pkl` (an `OrderedDict` of `_rebuild_tensor_v2` entries), `byteorder`, the
//! storages `data/<i>` and `version`; `torch.load` reads it back, also with `weights_only=True`.

use std::io::Write;
use std::path::Path;

use crate::{HostTensor, WeightsError};

struct PickleWriter {
    out: Vec<u8>,
}

impl PickleWriter {
    fn op(&mut self, b: u8) {
        self.out.push(b);
    }
    fn string(&mut self, s: &str) {
        self.op(b'X');
        self.out.extend_from_slice(&(s.len() as u32).to_le_bytes());
        self.out.extend_from_slice(s.as_bytes());
    }
    fn int(&mut self, i: i64) {
        if let Ok(v) = i32::try_from(i) {
            self.op(b'J');
            self.out.extend_from_slice(&v.to_le_bytes());
        } else {
            self.op(0x8a);
            self.op(8);
            self.out.extend_from_slice(&i.to_le_bytes());
        }
    }
    fn global(&mut self, m: &str, n: &str) {
        self.op(b'c');
        self.out.extend_from_slice(format!("{m}\n{n}\n").as_bytes());
    }
    fn int_tuple(&mut self, xs: &[i64]) {
        self.op(b'(');
        for &x in xs {
            self.int(x);
        }
        self.op(b't');
    }
    /// One state-dict entry: `name` → `_rebuild_tensor_v2` of storage `key` (class `st`,
    /// `numel` elements), a contiguous view of `size`.
    fn tensor_entry(&mut self, name: &str, key: &str, st: &str, numel: usize, size: &[i64]) {
        let mut stride = vec![1i64; size.len()];
        for d in (0..size.len().saturating_sub(1)).rev() {
            stride[d] = stride[d + 1] * size[d + 1].max(1);
        }
        self.string(name);
        self.global("torch._utils", "_rebuild_tensor_v2");
        self.op(b'(');
        self.op(b'(');
        self.string("storage");
        self.global("torch", st);
        self.string(key);
        self.string("cpu");
        self.int(numel as i64);
        self.op(b't');
        self.op(b'Q');
        self.int(0);
        self.int_tuple(size);
        self.int_tuple(&stride);
        self.op(0x89);
        self.global("collections", "OrderedDict");
        self.op(b')');
        self.op(b'R');
        self.op(b't');
        self.op(b'R');
    }
}

/// The zip archive of a `torch.save` file: `archive/data.pkl`, `byteorder`, the storages
/// `data/<i>` and `version`, stored uncompressed.
fn torch_zip(path: &Path, pkl: &[u8], blobs: &[&[u8]]) -> Result<Vec<u8>, WeightsError> {
    let mut cursor = std::io::Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut cursor);
        let opts =
            zip::write::FileOptions::default().compression_method(zip::CompressionMethod::Stored);
        let mut put = |name: &str, data: &[u8]| -> Result<(), WeightsError> {
            z.start_file(format!("archive/{name}"), opts)
                .map_err(|e| WeightsError::format(path, format!("zip: {e}")))?;
            z.write_all(data).map_err(|e| WeightsError::io(path, e))
        };
        put("data.pkl", pkl)?;
        put("byteorder", b"little")?;
        for (i, b) in blobs.iter().enumerate() {
            put(&format!("data/{i}"), b)?;
        }
        put("version", b"3\n")?;
        z.finish()
            .map_err(|e| WeightsError::format(path, format!("zip: {e}")))?;
    }
    Ok(cursor.into_inner())
}

/// Writes named tensors as a `torch.save`-compatible zip file holding an `OrderedDict` state
/// dict (what `torch.save(model.state_dict(), path)` produces; `torch.load` reads it back,
/// also with `weights_only=True`). Written atomically.
pub fn write_torch_state_dict(
    path: &Path,
    tensors: &[(String, HostTensor)],
) -> Result<(), WeightsError> {
    let mut w = PickleWriter { out: vec![0x80, 2] };
    w.global("collections", "OrderedDict");
    w.op(b')');
    w.op(b'R');
    w.op(b'(');
    let mut blobs = Vec::new();
    for (i, (name, t)) in tensors.iter().enumerate() {
        let st = t.dtype.storage_name();
        w.tensor_entry(name, &i.to_string(), st, t.numel(), &t.shape);
        blobs.push(&t.data[..]);
    }
    w.op(b'u');
    w.op(b'.');
    let archive = torch_zip(path, &w.out, &blobs)?;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| WeightsError::io(dir, e))?;
    depthsense_base::fsutil::write_atomic(path, &archive).map_err(|e| WeightsError::io(path, e))
}
