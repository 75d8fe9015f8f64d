include!("../../build-support/torch_link.rs");

fn main() {
    // Only depthsense-net links libtorch; `depthsense`, the torch-free front, must not get
    // libtorch_cuda forced in (src/main.rs).
    link_torch_for(Some("depthsense-net"));
}
