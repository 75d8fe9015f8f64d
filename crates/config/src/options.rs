//! Every `--set KEY=VALUE` key: the one registry that [`ModelConfig::set_option`] dispatches
//! through and that the `--set` help text of every command prints ([`crate::cli::set_help`]).

use depthsense_base::words::Words;

use crate::{
    AttentionGate, ConfigError, DecoderKind, Fusion, HeadKind, ModelConfig, RadarBranchKind,
    RadarInput, StemKind,
};

/// The values a key takes.
#[derive(Debug, Clone, Copy)]
pub enum Values {
    /// A number; the text says what it counts.
    Number(&'static str),
    /// on|off (also 1/0, true/false, yes/no).
    Switch,
    /// One of these words (`Words::words` of the field's enum, `depthsense_base::words`).
    Choice(fn() -> Vec<&'static str>),
}

/// One key of `--set`.
pub struct OptionKey {
    /// The key as help texts print it.
    pub key: &'static str,
    /// Other spellings accepted (`_` for `-` is always accepted).
    pub aliases: &'static [&'static str],
    pub values: Values,
    /// The field it sets, for help texts.
    pub about: &'static str,
    set: fn(&mut ModelConfig, &str, &str) -> Result<(), ConfigError>,
}

impl OptionKey {
    /// `key (values): about`, as the help texts list it.
    pub fn describe(&self) -> String {
        let values = match self.values {
            Values::Number(what) => what.to_string(),
            Values::Switch => "on|off".to_string(),
            Values::Choice(words) => words().join("|"),
        };
        format!("{} ({values}): {}", self.key, self.about)
    }
}

/// Every key, in the order help texts list them.
pub const OPTIONS: &[OptionKey] = &[
    OptionKey {
        key: "backbone",
        aliases: &["backbone-depth", "depth"],
        values: Values::Number("18|34|50|101"),
        about: "RGB encoder depth",
        set: |c, k, v| {
            c.backbone_depth = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "width",
        aliases: &["backbone-width"],
        values: Values::Number("channels"),
        about: "RGB encoder base width (64 = torchvision)",
        set: |c, k, v| {
            c.backbone_width = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "stem",
        aliases: &[],
        values: Values::Choice(StemKind::words),
        about: "RGB encoder stem",
        set: |c, k, v| {
            c.stem = choice::<StemKind>(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "decoder",
        aliases: &[],
        values: Values::Choice(DecoderKind::words),
        about: "image decoder",
        set: |c, k, v| {
            c.decoder = choice::<DecoderKind>(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "decoder-channels",
        aliases: &[],
        values: Values::Number("channels"),
        about: "channels of each decoder level",
        set: |c, k, v| {
            c.decoder_channels = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "fusion",
        aliases: &[],
        values: Values::Choice(Fusion::words),
        about: "how radar enters the network (none = rgb = RGB only)",
        set: |c, k, v| {
            c.fusion = choice::<Fusion>(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "attention",
        aliases: &[],
        values: Values::Switch,
        about: "spatial attention of late fusion",
        set: |c, k, v| {
            c.attention = switch(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "attention-gate",
        aliases: &[],
        values: Values::Choice(AttentionGate::words),
        about: "the attention's gate: 2σ(s) or ½ + σ(s)",
        set: |c, k, v| {
            c.attention_gate = choice::<AttentionGate>(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-input",
        aliases: &[],
        values: Values::Choice(RadarInput::words),
        about: "which radar map(s) feed the radar channels (sets radar-channels)",
        set: |c, _, v| {
            c.radar_input = v.parse()?;
            c.radar_channels = c.radar_input.channels() as i64;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-channels",
        aliases: &[],
        values: Values::Number("1|2|7"),
        about: "radar input channels",
        set: |c, k, v| {
            c.radar_channels = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-in-metres",
        aliases: &["radar-in-meters"],
        values: Values::Switch,
        about: "radar enters in metres as the authors' code feeds it (default: scaled by 1/β)",
        set: |c, k, v| {
            c.radar_in_metres = switch(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-branch",
        aliases: &[],
        values: Values::Choice(RadarBranchKind::words),
        about: "radar branch of late fusion",
        set: |c, k, v| {
            c.radar_branch = choice::<RadarBranchKind>(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-width",
        aliases: &[],
        values: Values::Number("channels"),
        about: "radar branch base width",
        set: |c, k, v| {
            c.radar_width = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-out-channels",
        aliases: &[],
        values: Values::Number("channels"),
        about: "radar features entering fusion (bottleneck branch)",
        set: |c, k, v| {
            c.radar_out_channels = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-skip",
        aliases: &["radar-skip-channels"],
        values: Values::Number("channels"),
        about: "high-resolution radar path of late fusion (0 = none, the paper)",
        set: |c, k, v| {
            c.radar_skip_channels = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "head",
        aliases: &["loss"],
        values: Values::Choice(HeadKind::words),
        about: "output head and its loss",
        set: |c, k, v| {
            c.head = choice::<HeadKind>(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "head-channels",
        aliases: &[],
        values: Values::Number("channels"),
        about: "hidden channels of the head",
        set: |c, k, v| {
            c.head_channels = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "head-pre-dropout",
        aliases: &[],
        values: Values::Switch,
        about: "Dropout2d before the head's first conv as well (released)",
        set: |c, k, v| {
            c.head_pre_dropout = switch(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "dropout",
        aliases: &[],
        values: Values::Number("probability"),
        about: "Dropout2d in the head",
        set: |c, k, v| {
            c.dropout = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "clamp-logits",
        aliases: &[],
        values: Values::Switch,
        about: "the released code's logit clamp (SPEC §7; for the authors' weights)",
        set: |c, k, v| {
            c.clamp_logits = switch(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "bins",
        aliases: &[],
        values: Values::Number("K"),
        about: "ordinal SID bins",
        set: |c, k, v| {
            c.sid.bins = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "alpha",
        aliases: &["alpha-m"],
        values: Values::Number("metres"),
        about: "first SID threshold",
        set: |c, k, v| {
            c.sid.alpha_m = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "beta",
        aliases: &["beta-m"],
        values: Values::Number("metres"),
        about: "last SID threshold",
        set: |c, k, v| {
            c.sid.beta_m = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "decode-offset",
        aliases: &["decode-offset-m"],
        values: Values::Number("metres"),
        about: "subtracted from decoded depths (released: 0.3)",
        set: |c, k, v| {
            c.sid.decode_offset_m = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "align-corners",
        aliases: &[],
        values: Values::Switch,
        about: "align_corners of the head's bilinear upsampling",
        set: |c, k, v| {
            c.align_corners = switch(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "input-downscale",
        aliases: &[],
        values: Values::Number("1..8"),
        about: "the network sees its inputs downscaled by this factor (1 = full resolution)",
        set: |c, k, v| {
            c.input_downscale = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "radar-downscale",
        aliases: &[],
        values: Values::Number("1..8"),
        about: "the radar map's own factor (default: input-downscale)",
        set: |c, k, v| {
            c.radar_downscale = Some(num(k, v)?);
            Ok(())
        },
    },
    OptionKey {
        key: "out-height",
        aliases: &[],
        values: Values::Number("pixels"),
        about: "output height (train sets it from the data)",
        set: |c, k, v| {
            c.out_height = num(k, v)?;
            Ok(())
        },
    },
    OptionKey {
        key: "out-width",
        aliases: &[],
        values: Values::Number("pixels"),
        about: "output width (train sets it from the data)",
        set: |c, k, v| {
            c.out_width = num(k, v)?;
            Ok(())
        },
    },
];

/// The key called `key` or one of its aliases (`_` read as `-`, ASCII case ignored).
pub fn find(key: &str) -> Option<&'static OptionKey> {
    let k = key.trim().replace('_', "-").to_ascii_lowercase();
    OPTIONS
        .iter()
        .find(|o| o.key == k || o.aliases.contains(&k.as_str()))
}

/// Every key, in [`OPTIONS`] order.
pub fn keys() -> Vec<&'static str> {
    OPTIONS.iter().map(|o| o.key).collect()
}

impl ModelConfig {
    /// Sets one option by name (`--set key=value`, [`OPTIONS`]) without checking the whole
    /// config; [`ModelConfig::set_option`] checks it.
    pub fn apply_option(&mut self, key: &str, value: &str) -> Result<(), ConfigError> {
        let opt = find(key).ok_or_else(|| {
            let hint =
                closest(key.trim()).map_or(String::new(), |k| format!(" (did you mean `{k}`?)"));
            ConfigError::Invalid(format!(
                "unknown option `{}`{hint}; the keys are: {}",
                key.trim(),
                keys().join(", ")
            ))
        })?;
        (opt.set)(self, key.trim(), value.trim())
    }

    /// Sets one option by name, then validates the config.
    pub fn set_option(&mut self, key: &str, value: &str) -> Result<(), ConfigError> {
        self.apply_option(key, value)?;
        self.validate()
    }

    /// Applies `key=value` strings in order.
    pub fn with_options<S: AsRef<str>>(
        mut self,
        options: &[S],
    ) -> Result<ModelConfig, ConfigError> {
        for o in options {
            let (k, v) = split_key_value(o.as_ref())?;
            self.set_option(k, v)?;
        }
        Ok(self)
    }
}

/// The key (or alias) nearest to a mistyped `key`, when at most two edits away.
fn closest(key: &str) -> Option<&'static str> {
    let k = key.replace('_', "-").to_ascii_lowercase();
    OPTIONS
        .iter()
        .flat_map(|o| std::iter::once(o.key).chain(o.aliases.iter().copied()))
        .map(|name| (edit_distance(&k, name), name))
        .filter(|(d, _)| *d <= 2)
        .min()
        .map(|(_, name)| name)
}

/// Levenshtein distance (insertions, deletions, substitutions).
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}

/// `key=value` → (key, value).
pub fn split_key_value(o: &str) -> Result<(&str, &str), ConfigError> {
    o.split_once('=')
        .ok_or_else(|| ConfigError::Invalid(format!("`{o}`: expected KEY=VALUE")))
}

fn switch(key: &str, v: &str) -> Result<bool, ConfigError> {
    match v.to_ascii_lowercase().as_str() {
        "1" | "true" | "on" | "yes" => Ok(true),
        "0" | "false" | "off" | "no" => Ok(false),
        _ => Err(ConfigError::Invalid(format!("{key}={v}: expected on/off"))),
    }
}

fn num<T: std::str::FromStr>(key: &str, v: &str) -> Result<T, ConfigError> {
    v.parse()
        .map_err(|_| ConfigError::Invalid(format!("{key}={v}: not a number")))
}

/// The value of an enum option: `v` (ASCII case ignored) looked up in `names`.
fn choice<T: Words>(key: &str, v: &str) -> Result<T, ConfigError> {
    T::from_word(v).ok_or_else(|| {
        ConfigError::Invalid(format!(
            "{key}={v}: unknown value (expected {})",
            T::words().join(", ")
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_choice_vocabulary_holds_together() {
        use depthsense_base::words::check_vocabulary;
        check_vocabulary::<Fusion>().unwrap();
        check_vocabulary::<HeadKind>().unwrap();
        check_vocabulary::<StemKind>().unwrap();
        check_vocabulary::<DecoderKind>().unwrap();
        check_vocabulary::<RadarBranchKind>().unwrap();
        check_vocabulary::<AttentionGate>().unwrap();
        check_vocabulary::<RadarInput>().unwrap();
        // The words a key lists are the words it accepts, its enum's list.
        let fusion = OPTIONS.iter().find(|o| o.key == "fusion").unwrap();
        assert_eq!(
            fusion.describe(),
            format!("fusion (late|early|none|rgb): {}", fusion.about)
        );
        assert_eq!(RadarInput::RawHeight.name(), "raw-height");
    }

    /// Values of every key that the paper's network accepts; at least one differs from its.
    fn samples(o: &OptionKey) -> Vec<String> {
        match o.values {
            Values::Choice(words) => words().iter().map(|w| w.to_string()).collect(),
            Values::Switch => vec!["on".into(), "off".into()],
            Values::Number(_) => vec![match o.key {
                "backbone" => "50".into(),
                "radar-channels" => "2".into(),
                "dropout" => "0.25".into(),
                "alpha" => "2".into(),
                "input-downscale" | "radar-downscale" => "2".into(),
                _ => "16".into(),
            }],
        }
    }

    #[test]
    fn every_key_and_alias_sets_a_valid_value_and_every_listed_word_is_accepted() {
        for o in OPTIONS {
            for name in std::iter::once(o.key).chain(o.aliases.iter().copied()) {
                let mut changed = false;
                for v in samples(o) {
                    let mut c = ModelConfig::paper();
                    c.set_option(name, &v)
                        .unwrap_or_else(|e| panic!("{name}={v}: {e}"));
                    changed |= c != ModelConfig::paper();
                }
                assert!(changed, "{name} changed nothing");
            }
        }
        let mut c = ModelConfig::paper();
        assert!(c.set_option("input_downscale", "2").is_ok(), "_ for -");
        let e = c.set_option("colour", "red").unwrap_err().to_string();
        assert!(e.contains("`colour`") && e.contains("radar-skip"), "{e}");
        assert!(!e.contains("did you mean"), "{e}");
        let e = c.set_option("radar-skipp", "8").unwrap_err().to_string();
        assert!(e.contains("did you mean `radar-skip`?"), "{e}");
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        let e = c.set_option("fusion", "middle").unwrap_err().to_string();
        assert!(e.contains("late, early, none, rgb"), "{e}");
    }

    #[test]
    fn keys_are_unique_across_names_and_aliases() {
        let mut all: Vec<&str> = OPTIONS
            .iter()
            .flat_map(|o| std::iter::once(o.key).chain(o.aliases.iter().copied()))
            .collect();
        let n = all.len();
        all.sort();
        all.dedup();
        assert_eq!(all.len(), n);
    }
}
