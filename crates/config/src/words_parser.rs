//! The value parser of every enum flag: the words of the enum's vocabulary
//! (`depthsense_base::words::Words`, defined next to the enum in its library), so that an
//! unknown word is refused while the command line is parsed, `--help` lists the possible
//! values, and every command accepts the same words. (clap's `ValueEnum` would do the same, but
//! only on types of this crate: the enums live in libraries that do not depend on clap.)

use std::ffi::OsStr;
use std::marker::PhantomData;

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use depthsense_base::words::Words;

/// The parser of `T`'s words: `#[arg(long, value_parser = words::<Protocol>())]`.
pub fn words<T: Words + Send + Sync>() -> WordParser<T> {
    WordParser(PhantomData)
}

/// See [`words`].
pub struct WordParser<T>(PhantomData<fn() -> T>);

impl<T> Clone for WordParser<T> {
    fn clone(&self) -> Self {
        WordParser(PhantomData)
    }
}

impl<T: Words> WordParser<T> {
    /// Every value under its first word, the other words as (hidden) aliases.
    fn possible() -> Vec<PossibleValue> {
        T::names()
            .into_iter()
            .map(|name| PossibleValue::new(name).aliases(T::aliases(name)))
            .collect()
    }
}

impl<T: Words + Send + Sync> TypedValueParser for WordParser<T> {
    type Value = T;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &OsStr,
    ) -> Result<T, clap::Error> {
        if let Some(v) = value.to_str().and_then(T::from_word) {
            return Ok(v);
        }
        // Not a word (case ignored): clap's own refusal, which names the flag and lists the
        // possible values. (It cannot accept what `from_word` refused.)
        match PossibleValuesParser::new(Self::possible()).parse_ref(cmd, arg, value) {
            Err(e) => Err(e),
            Ok(_) => Err(clap::Error::new(clap::error::ErrorKind::InvalidValue).with_cmd(cmd)),
        }
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        Some(Box::new(Self::possible().into_iter()))
    }
}

#[cfg(test)]
mod tests {
    use crate::flags::{ExportFormat, Precision};
    use clap::Parser;

    #[derive(Parser)]
    struct Probe {
        #[arg(long, default_value = "onnx", value_parser = super::words::<ExportFormat>())]
        format: ExportFormat,
        #[arg(long, value_delimiter = ',', value_parser = super::words::<Precision>())]
        precision: Vec<Precision>,
    }

    #[test]
    fn words_parse_case_blind_with_aliases_and_refusals_list_the_names() {
        let p = Probe::try_parse_from(["x", "--format", "TorchScript", "--precision", "half,bf16"])
            .unwrap();
        assert_eq!(p.format, ExportFormat::TorchScript);
        assert_eq!(p.precision, [Precision::Fp16, Precision::Bf16]);
        assert_eq!(
            Probe::try_parse_from(["x"]).unwrap().format,
            ExportFormat::Onnx
        );
        let e = Probe::try_parse_from(["x", "--format", "onyx"])
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("'onyx'")
                && e.contains("--format")
                && e.contains("onnx, torchscript, pytorch"),
            "{e}"
        );
        let e = Probe::try_parse_from(["x", "--precision", "fp8"])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("fp32, bf16, fp16") && !e.contains("half"), "{e}");
    }
}
