//! `--device`, one flag group for every command that runs a network (flattened into their
//! arguments): the same words, default and help everywhere, refused while the command line is
//! parsed (`depthsense_config::cli::parse_device`).

#[derive(clap::Args, Debug, Clone)]
pub struct DeviceArg {
    /// Device: auto (CUDA when available), cpu, cuda or cuda:N.
    #[arg(long = "device", id = "device", value_name = "DEVICE", default_value = "auto",
          value_parser = depthsense_config::cli::parse_device)]
    pub name: String,
}
