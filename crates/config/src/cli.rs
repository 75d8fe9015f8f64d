//! What the command line builds from the registries: value parsers that refuse an unknown preset
//! or `--set` key while the command line is parsed (before anything runs), and the help texts
//! that list them. Every command that takes `--config`/`--configs`/`--set` uses these.

use crate::options::{self, OPTIONS};
use crate::{presets, ModelConfig};

/// `--config` / `--configs`: a preset name, or a path (a model-config JSON, an export sidecar or
/// a depthsense checkpoint; read, and a missing one named, when the command runs). A bare word
/// that is neither a preset nor an existing file is refused here, naming the presets.
pub fn parse_config_spec(s: &str) -> Result<String, String> {
    let looks_like_a_path = s.contains('/') || s.contains('.');
    if looks_like_a_path || presets::find(s).is_some() || std::path::Path::new(s).exists() {
        return Ok(s.to_string());
    }
    Err(crate::ConfigError::UnknownPreset(s.to_string()).to_string())
}

/// `--device`: auto, cpu, cuda or cuda:N ([`crate::device::DeviceSpec`]); whether that GPU is
/// there is checked when the command runs.
pub fn parse_device(s: &str) -> Result<String, String> {
    match crate::device::DeviceSpec::parse(s) {
        Some(_) => Ok(s.to_string()),
        None => Err(crate::device::InvalidDevice::of(s).to_string()),
    }
}

/// `--set KEY=VALUE`: a known key (or alias) with a value of its form; whether the whole
/// configuration holds together is checked when the command builds it.
pub fn parse_set(s: &str) -> Result<String, String> {
    let (k, v) = options::split_key_value(s).map_err(|e| e.to_string())?;
    let mut scratch = ModelConfig::paper();
    scratch.apply_option(k, v).map_err(|e| e.to_string())?;
    Ok(s.to_string())
}

/// A value parser for one `--set` key's values, for flags that set that key alone
/// (`train --fusion`, `--head`, `--radar-input`): the same words as `--set KEY=…`.
pub fn parse_value(key: &'static str) -> impl Fn(&str) -> Result<String, String> + Clone {
    move |v: &str| {
        let mut scratch = ModelConfig::paper();
        scratch
            .apply_option(key, v)
            .map(|_| v.to_string())
            .map_err(|e| e.to_string())
    }
}

/// `{lead}: late, early, none or rgb`: the words of key `key` ([`OPTIONS`]).
pub fn value_help(key: &str, lead: &str) -> String {
    let words = match options::find(key).map(|o| o.values) {
        Some(options::Values::Choice(words)) => words().join(", "),
        _ => String::new(),
    };
    format!("{lead}: {words}")
}

/// The presets as help texts list them: `paper, released, tiny, tiny-wide`.
pub fn preset_list() -> String {
    presets::names().join(", ")
}

/// Help of a `--config`-like flag: `{lead}: a preset (paper, released, tiny, tiny-wide){tail}`.
pub fn config_help(lead: &str, tail: &str) -> String {
    format!("{lead}: a preset ({}){tail}", preset_list())
}

/// Help of every `--set`: what it does, then every key with its values.
pub fn set_help() -> String {
    let keys: Vec<String> = OPTIONS
        .iter()
        .map(|o| format!("  {}", o.describe()))
        .collect();
    format!(
        "Override one model-config option, KEY=VALUE (repeatable, applied in order). Keys:\n{}",
        keys.join("\n")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parsers_accept_the_registries_words_and_name_them_when_refusing() {
        for p in presets::PRESETS {
            assert_eq!(parse_config_spec(p.name).unwrap(), p.name);
        }
        let e = parse_config_spec("tiny-wider").unwrap_err();
        assert!(e.contains("tiny-wide") && e.contains("`tiny-wider`"), "{e}");
        assert!(
            parse_config_spec("configs/mine.json").is_ok(),
            "paths are read later"
        );
        for o in OPTIONS {
            assert!(
                set_help().contains(o.key),
                "{} missing from --set help",
                o.key
            );
        }
        assert!(parse_set("radar-skip=8").is_ok());
        assert!(parse_set("input_downscale=2").is_ok());
        let e = parse_set("radar-skipp=8").unwrap_err();
        assert!(
            e.contains("`radar-skipp`") && e.contains("radar-skip"),
            "{e}"
        );
        assert!(parse_set("fusion=middle").unwrap_err().contains("late"));
        assert!(parse_set("width").unwrap_err().contains("KEY=VALUE"));
    }
}
