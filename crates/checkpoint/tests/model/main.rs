//! The network's one integration-test binary, in `checkpoint`: the lowest crate that sees both
//! the network and its files on disk, so that `model` needs no dev-dependency on `checkpoint`
//! (each test binary links libtorch, and linking dominates the test build; issue 35):
//! - `model`: the network, heads, losses, checkpoints and imports;
//! - `sid_goldens`: SID thresholds and the ordinal decoding against golden values;
//! - `torch_reference_params`: parameter counts and outputs against the PyTorch reference;
//! - `import_by_value`: torchvision / released imports checked value by value;
//! - `released_reference`: the authors' checkpoint layout (`support::reference`);
//! - `torch_ext`: the libtorch shim (pinned copies, CUDA autocast) that `model` uses.

mod import_by_value;
mod model;
mod released_reference;
mod sid_goldens;
mod support;
mod torch_ext;
mod torch_reference_params;
