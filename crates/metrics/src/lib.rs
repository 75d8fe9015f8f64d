//! Depth metrics and report tables (SPEC §9). Pure Rust, no torch.
