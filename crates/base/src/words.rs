//! Closed vocabularies: the words a flag, a `--set` key, a config file or a JSON field accepts
//! for an enum, each written once, next to the enum. The command line builds its value parsers
//! and its `[possible values: …]` from [`Words::WORDS`] (`crates/cli/src/cmd/words.rs`), the
//! `--set` registry its help from it, and the libraries their `FromStr` errors — so a word added
//! here is accepted, listed and refused with the same list everywhere.
//!
//! Libraries implement this trait rather than clap's `ValueEnum`: they stay free of clap, and
//! one enum serves the command line, `--set` and the files alike.

/// An enum whose values are named by a fixed list of words.
pub trait Words: Sized + Copy + PartialEq + 'static {
    /// What the words name, as messages say it (`protocol`).
    const WHAT: &'static str;
    /// Every accepted word with the value it names, in the order help texts list them. A value
    /// named by several words is written (and listed as a possible value) with its first word;
    /// the later ones are aliases.
    const WORDS: &'static [(&'static str, Self)];

    /// The value a word names, ASCII case ignored (`MASK` = `mask`).
    fn from_word(word: &str) -> Option<Self> {
        let word = word.trim();
        Self::WORDS
            .iter()
            .find(|(w, _)| w.eq_ignore_ascii_case(word))
            .map(|&(_, v)| v)
    }

    /// The first word of `self` (how it is written back).
    fn word(self) -> &'static str {
        Self::WORDS
            .iter()
            .find(|&&(_, v)| v == self)
            .map_or("", |&(w, _)| w)
    }

    /// Every word, aliases included, in list order.
    fn words() -> Vec<&'static str> {
        Self::WORDS.iter().map(|&(w, _)| w).collect()
    }

    /// The first word of every value, in list order (aliases left out).
    fn names() -> Vec<&'static str> {
        Self::WORDS
            .iter()
            .enumerate()
            .filter(|&(i, &(_, v))| Self::WORDS[..i].iter().all(|&(_, u)| u != v))
            .map(|(_, &(w, _))| w)
            .collect()
    }

    /// The words that name the same value as `name`, after it (its aliases).
    fn aliases(name: &str) -> Vec<&'static str> {
        let Some(value) = Self::from_word(name) else {
            return Vec::new();
        };
        Self::WORDS
            .iter()
            .filter(|&&(w, v)| v == value && w != name)
            .map(|&(w, _)| w)
            .collect()
    }

    /// Parses `word`, or says what is allowed: `unknown protocol "x" (allowed: mask, clamp)`.
    fn parse_word(word: &str) -> Result<Self, UnknownWord> {
        Self::from_word(word).ok_or_else(|| UnknownWord {
            what: Self::WHAT,
            word: word.to_string(),
            allowed: Self::words().join(", "),
        })
    }
}

/// A word outside its vocabulary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownWord {
    /// What the words name ([`Words::WHAT`]).
    pub what: &'static str,
    /// The word given.
    pub word: String,
    /// Every accepted word, comma separated.
    pub allowed: String,
}

impl std::fmt::Display for UnknownWord {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "unknown {} {:?} (allowed: {})",
            self.what, self.word, self.allowed
        )
    }
}

impl std::error::Error for UnknownWord {}

/// Checks a vocabulary: every word distinct (case ignored) and non-empty. For the tests of the
/// crates that define one.
pub fn check_vocabulary<T: Words + std::fmt::Debug>() -> Result<(), String> {
    let words = T::words();
    for (i, w) in words.iter().enumerate() {
        if w.is_empty() || w.trim() != *w {
            return Err(format!("{}: word {w:?} is empty or padded", T::WHAT));
        }
        if words[..i].iter().any(|u| u.eq_ignore_ascii_case(w)) {
            return Err(format!("{}: word {w:?} listed twice", T::WHAT));
        }
        let v = T::from_word(w).ok_or_else(|| format!("{}: {w:?} does not parse", T::WHAT))?;
        if T::from_word(v.word()) != Some(v) {
            return Err(format!("{}: {v:?} is not written back", T::WHAT));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Clone, Copy, PartialEq)]
    enum Colour {
        Red,
        Blue,
    }

    impl Words for Colour {
        const WHAT: &'static str = "colour";
        const WORDS: &'static [(&'static str, Self)] = &[
            ("red", Colour::Red),
            ("blue", Colour::Blue),
            ("azure", Colour::Blue),
        ];
    }

    #[test]
    fn words_names_aliases_and_refusals() {
        assert_eq!(Colour::from_word("RED"), Some(Colour::Red));
        assert_eq!(Colour::from_word(" azure "), Some(Colour::Blue));
        assert_eq!(Colour::Blue.word(), "blue");
        assert_eq!(Colour::names(), ["red", "blue"]);
        assert_eq!(Colour::words(), ["red", "blue", "azure"]);
        assert_eq!(Colour::aliases("blue"), ["azure"]);
        assert!(Colour::aliases("red").is_empty());
        let e = Colour::parse_word("green").unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown colour \"green\" (allowed: red, blue, azure)"
        );
        check_vocabulary::<Colour>().unwrap();
    }
}
