//! The edge between the torch-free weight formats (`depthsense_weights`: safetensors,
//! `torch.save`, host tensors) and libtorch: host tensors to `tch` tensors and back, and the
//! two format calls the network's checkpoints make through it.

use std::collections::BTreeMap;
use std::path::Path;

use depthsense_weights::{DType, HostTensor};
use tch::{Device, Kind, Tensor};

use depthsense_model::ModelError;

/// Tensors of a file (header order) and its string metadata.
pub type Parsed = (Vec<(String, Tensor)>, BTreeMap<String, String>);

fn kind_of(d: DType) -> Kind {
    match d {
        DType::F32 => Kind::Float,
        DType::F64 => Kind::Double,
        DType::F16 => Kind::Half,
        DType::BF16 => Kind::BFloat16,
        DType::I64 => Kind::Int64,
        DType::I32 => Kind::Int,
        DType::I16 => Kind::Int16,
        DType::I8 => Kind::Int8,
        DType::U8 => Kind::Uint8,
        DType::Bool => Kind::Bool,
    }
}

fn dtype_of(k: Kind) -> Option<DType> {
    DType::ALL.into_iter().find(|&d| kind_of(d) == k)
}

/// A host tensor as a CPU tensor (one copy).
pub fn to_tch(t: &HostTensor) -> Result<Tensor, ModelError> {
    Ok(Tensor::f_from_data_size(
        &t.data,
        &t.shape,
        kind_of(t.dtype),
    )?)
}

/// Named host tensors as CPU tensors.
pub fn all_to_tch(tensors: &[(String, HostTensor)]) -> Result<Vec<(String, Tensor)>, ModelError> {
    tensors
        .iter()
        .map(|(n, t)| Ok((n.clone(), to_tch(t)?)))
        .collect()
}

/// The bytes of tensor `name` in host memory (detached, on the CPU, contiguous).
pub fn to_host(name: &str, t: &Tensor) -> Result<HostTensor<'static>, ModelError> {
    let t = t.detach().to_device(Device::Cpu).contiguous();
    let dtype = dtype_of(t.kind()).ok_or_else(|| ModelError::UnsavableDtype {
        name: name.to_string(),
        kind: t.kind(),
    })?;
    let numel = t.numel();
    let mut data = vec![0u8; numel * dtype.size()];
    t.f_copy_data_u8(&mut data, numel)?;
    Ok(HostTensor {
        dtype,
        shape: t.size(),
        data: data.into(),
    })
}

/// Named tensors in host memory.
pub fn all_to_host(
    tensors: &[(String, Tensor)],
) -> Result<Vec<(String, HostTensor<'static>)>, ModelError> {
    tensors
        .iter()
        .map(|(n, t)| Ok((n.clone(), to_host(n, t)?)))
        .collect()
}

/// Safetensors bytes of named tensors with string metadata.
pub fn safetensors_bytes(
    tensors: &[(String, Tensor)],
    metadata: &BTreeMap<String, String>,
) -> Result<Vec<u8>, ModelError> {
    Ok(depthsense_weights::safetensors::serialize(
        &all_to_host(tensors)?,
        metadata,
    ))
}

/// Parses safetensors bytes into CPU tensors and the metadata; every length and offset is
/// checked (`depthsense_weights::safetensors::parse`).
pub fn parse_safetensors(path: &Path, bytes: &[u8]) -> Result<Parsed, ModelError> {
    let (tensors, meta) = depthsense_weights::safetensors::parse(path, bytes)?;
    Ok((all_to_tch(&tensors)?, meta))
}

/// Every tensor of a `torch.save` file (zip or legacy) onto the CPU, dotted names, file order.
pub fn read_torch_file(path: &Path) -> Result<Vec<(String, Tensor)>, ModelError> {
    all_to_tch(&depthsense_weights::torch_file::read_torch_file(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn host_and_tch_round_trip_every_dtype() {
        for d in DType::ALL {
            let k = kind_of(d);
            assert_eq!(dtype_of(k), Some(d));
            assert_eq!(k.elt_size_in_bytes(), d.size(), "{d:?}");
            let t = Tensor::arange(6, (Kind::Int64, Device::Cpu))
                .to_kind(k)
                .reshape([2, 3]);
            let h = to_host("t", &t).unwrap();
            assert_eq!(h.shape, vec![2, 3]);
            assert!(to_tch(&h).unwrap().equal(&t), "{d:?}");
        }
        assert!(dtype_of(Kind::ComplexFloat).is_none());
    }
}
