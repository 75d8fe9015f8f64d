//! The words of `--device` without libtorch: `auto`, `cpu`, `cuda` (= `gpu` = `cuda:0`) and
//! `cuda:N`. The command line refuses anything else while it is parsed (`cli::parse_device`);
//! `depthsense_model::device::parse_device` turns a [`DeviceSpec`] into a libtorch device and
//! checks that the GPU asked for is there.

/// A device as the command line names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceSpec {
    /// CUDA device 0 when libtorch sees a GPU, else the CPU.
    Auto,
    Cpu,
    /// CUDA device N (`cuda` and `gpu` are device 0).
    Cuda(usize),
}

/// The device words, as help texts and errors list them.
pub const DEVICE_WORDS: &str = "auto, cpu, cuda or cuda:N";

/// A `--device` value that is not a device word (the one message for the command line's
/// refusal and `depthsense_model::device::parse_device`'s).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InvalidDevice(pub String);

impl InvalidDevice {
    /// The error for `s` as given (shown trimmed, lower-case).
    pub fn of(s: &str) -> Self {
        Self(s.trim().to_ascii_lowercase())
    }
}

impl std::fmt::Display for InvalidDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "invalid device `{}` (expected {DEVICE_WORDS})", self.0)
    }
}

impl std::error::Error for InvalidDevice {}

impl DeviceSpec {
    /// Parses a device word (ASCII case and surrounding blanks ignored); `None` for anything
    /// else.
    pub fn parse(s: &str) -> Option<Self> {
        let s = s.trim().to_ascii_lowercase();
        match s.as_str() {
            "auto" => Some(Self::Auto),
            "cpu" => Some(Self::Cpu),
            "cuda" | "gpu" => Some(Self::Cuda(0)),
            _ => s
                .strip_prefix("cuda:")
                .and_then(|n| n.parse::<usize>().ok())
                .map(Self::Cuda),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_words() {
        assert_eq!(DeviceSpec::parse("auto"), Some(DeviceSpec::Auto));
        assert_eq!(DeviceSpec::parse(" CPU "), Some(DeviceSpec::Cpu));
        assert_eq!(DeviceSpec::parse("gpu"), Some(DeviceSpec::Cuda(0)));
        assert_eq!(DeviceSpec::parse("cuda"), Some(DeviceSpec::Cuda(0)));
        assert_eq!(DeviceSpec::parse("cuda:3"), Some(DeviceSpec::Cuda(3)));
        for bad in ["tpu", "cuda:x", "cuda:", "cuda:-1", ""] {
            assert_eq!(DeviceSpec::parse(bad), None, "{bad}");
        }
    }
}

/// `--device`, one flag for every command that runs a network (flattened into their
/// arguments, and into [`crate::training::HardwareOptions`]): the same words, default and help
/// everywhere, refused while the command line is parsed ([`crate::cli::parse_device`]).
/// RUN/config.json records it as `"device"`.
#[derive(clap::Args, Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeviceArg {
    /// Device: auto (CUDA when available), cpu, cuda or cuda:N.
    #[arg(long = "device", id = "device", value_name = "DEVICE", default_value = "auto",
          value_parser = crate::cli::parse_device)]
    #[serde(rename = "device")]
    pub name: String,
}

impl Default for DeviceArg {
    fn default() -> Self {
        crate::training::defaults()
    }
}
