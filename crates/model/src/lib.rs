//! The DepthSense network, heads and losses on libtorch (SPEC §6–7).
