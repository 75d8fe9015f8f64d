//! depthsense-weights (layer 1, ARCHITECTURE.md): the byte formats of network weights, without
//! libtorch — every reader of untrusted weight files lives here, so that the fuzzer
//! (`depthsense-fuzz`) runs them without loading libtorch.
//!
//! - [`safetensors`]: our checkpoints' container (write and read, every length checked);
//! - [`pickle`]: the pickle machine of `torch.save` files (protocols 2–4, bounded against
//!   hostile input) and the walk that finds the tensors in what it built;
//! - [`torch_file`]: `torch.save` files (zip of torch ≥ 1.6 and the legacy format) read into
//!   contiguous host tensors;
//! - `pth_writer` (feature `pth-writer`): a `torch.save` state-dict writer for tests and fuzz
//!   seeds.
//!
//! Tensors are [`HostTensor`]s — dtype, shape and little-endian bytes in row-major order;
//! `depthsense_checkpoint` converts them to and from `tch` tensors (the edge).

use std::borrow::Cow;
use std::path::{Path, PathBuf};

pub mod pickle;
#[cfg(feature = "pth-writer")]
pub mod pth_writer;
pub mod safetensors;
pub mod torch_file;

/// Element types of weight files (safetensors names; `torch.save` storage classes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DType {
    F32,
    F64,
    F16,
    BF16,
    I64,
    I32,
    I16,
    I8,
    U8,
    Bool,
}

impl DType {
    /// Every dtype, in the order of the tables below.
    pub const ALL: [DType; 10] = [
        DType::F32,
        DType::F64,
        DType::F16,
        DType::BF16,
        DType::I64,
        DType::I32,
        DType::I16,
        DType::I8,
        DType::U8,
        DType::Bool,
    ];

    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            DType::F64 | DType::I64 => 8,
            DType::F32 | DType::I32 => 4,
            DType::F16 | DType::BF16 | DType::I16 => 2,
            DType::I8 | DType::U8 | DType::Bool => 1,
        }
    }

    /// The safetensors name (`F32`, …, `BOOL`).
    pub fn safetensors_name(self) -> &'static str {
        match self {
            DType::F32 => "F32",
            DType::F64 => "F64",
            DType::F16 => "F16",
            DType::BF16 => "BF16",
            DType::I64 => "I64",
            DType::I32 => "I32",
            DType::I16 => "I16",
            DType::I8 => "I8",
            DType::U8 => "U8",
            DType::Bool => "BOOL",
        }
    }

    /// The dtype of a safetensors name.
    pub fn from_safetensors_name(name: &str) -> Option<DType> {
        DType::ALL
            .into_iter()
            .find(|d| d.safetensors_name() == name)
    }

    /// The `torch.save` storage class (`FloatStorage`, …).
    pub fn storage_name(self) -> &'static str {
        match self {
            DType::F32 => "FloatStorage",
            DType::F64 => "DoubleStorage",
            DType::F16 => "HalfStorage",
            DType::BF16 => "BFloat16Storage",
            DType::I64 => "LongStorage",
            DType::I32 => "IntStorage",
            DType::I16 => "ShortStorage",
            DType::I8 => "CharStorage",
            DType::U8 => "ByteStorage",
            DType::Bool => "BoolStorage",
        }
    }

    /// The dtype of a storage class (`UntypedStorage`: bytes).
    pub fn from_storage_name(name: &str) -> Option<DType> {
        if name == "UntypedStorage" {
            return Some(DType::U8);
        }
        DType::ALL.into_iter().find(|d| d.storage_name() == name)
    }
}

/// A tensor in host memory: contiguous, row-major, little-endian; `data` holds exactly
/// `numel · dtype.size()` bytes (borrowed from a file's bytes where it can be).
#[derive(Debug, Clone, PartialEq)]
pub struct HostTensor<'a> {
    pub dtype: DType,
    pub shape: Vec<i64>,
    pub data: Cow<'a, [u8]>,
}

impl HostTensor<'_> {
    /// Number of elements (1 for a scalar).
    pub fn numel(&self) -> usize {
        self.data.len() / self.dtype.size()
    }

    /// The same tensor owning its bytes.
    pub fn into_owned(self) -> HostTensor<'static> {
        HostTensor {
            dtype: self.dtype,
            shape: self.shape,
            data: Cow::Owned(self.data.into_owned()),
        }
    }
}

/// A weight file that cannot be read or written: the file, and what is wrong with it.
#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    /// Reading or writing the file failed.
    #[error("{}: {source}", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file is truncated, foreign or otherwise not what was expected.
    #[error("{}: {msg}", .path.display())]
    Format { path: PathBuf, msg: String },
}

impl WeightsError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        WeightsError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
    pub fn format(path: &Path, msg: impl Into<String>) -> Self {
        WeightsError::Format {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dtype_tables_round_trip() {
        for d in DType::ALL {
            assert_eq!(DType::from_safetensors_name(d.safetensors_name()), Some(d));
            assert_eq!(DType::from_storage_name(d.storage_name()), Some(d));
        }
        assert_eq!(DType::from_storage_name("UntypedStorage"), Some(DType::U8));
        assert_eq!(DType::from_safetensors_name("F8_E4M3"), None);
        assert_eq!(DType::BF16.size(), 2);
    }
}
