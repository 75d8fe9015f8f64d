//! nuScenes tables and indexes (SPEC §2).
//!
//! Tokens are 32-hex strings; they are stored as 128 bits ([`Token`], 16 bytes with a niche,
//! so that `Option<Token>` is 16 bytes too) so that 2.6 M `sample_data` rows load in seconds
//! with little memory. The big tables are read in chunks and their rows parsed in parallel
//! into borrowing structs; the small ones with a streaming sequence visitor, so the largest
//! intermediate is one chunk. File names are stored compactly ([`FileName`]), and the token
//! indexes hold only row numbers ([`RowIndex`]): loading generated v1.0-trainval-sized tables
//! peaks below 1 GB (BENCHMARKS.md).
//! Tokens that are not 32 hex digits are accepted too (hashed, with the text kept aside).
//!
//! Partial version folders are allowed: rows the data does not reference may be absent.
//! References are resolved when used, and a dangling one is a [`NuError::MissingToken`]
//! naming the row, the field and the missing token.

use std::collections::HashMap;
use std::fmt;
use std::num::NonZeroU64;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use serde::de::{Deserializer, SeqAccess, Visitor};
use serde::Deserialize;

use crate::error::{NuError, Result};

/// A nuScenes token (32 hex digits packed into 128 bits). The high half is never zero (a
/// token whose high 64 bits are zero is stored hashed, like non-hex tokens), which gives
/// `Option<Token>` a niche: 16 bytes instead of 32 for a `u128`. Alignment is 8.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Token {
    hi: NonZeroU64,
    lo: u64,
}

impl Default for Token {
    /// The token of the empty string (a placeholder "no token").
    fn default() -> Self {
        Token::from_bits(depthsense_base::hash::FNV128_OFFSET)
    }
}

/// Hex digit values; 0x80 marks a non-digit (upper case is not a nuScenes token).
static HEX: [u8; 256] = {
    let mut t = [0x80u8; 256];
    let mut i = 0;
    while i < 10 {
        t[b'0' as usize + i] = i as u8;
        i += 1;
    }
    let mut i = 0;
    while i < 6 {
        t[b'a' as usize + i] = 10 + i as u8;
        i += 1;
    }
    t
};

static HAS_EXOTIC: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
static EXOTIC: Mutex<Option<HashMap<u128, String>>> = Mutex::new(None);

impl Token {
    /// The token with these 128 bits, if its high half is not zero.
    fn from_u128(v: u128) -> Option<Token> {
        NonZeroU64::new((v >> 64) as u64).map(|hi| Token { hi, lo: v as u64 })
    }

    /// Like [`Token::from_u128`], with a zero high half replaced by 1 (for hashes).
    fn from_bits(v: u128) -> Token {
        Token::from_u128(v).unwrap_or(Token {
            hi: NonZeroU64::MIN,
            lo: v as u64,
        })
    }

    /// The 128 bits of the token.
    pub fn as_u128(self) -> u128 {
        ((self.hi.get() as u128) << 64) | self.lo as u128
    }

    /// Parse a token; `""` and `null` are handled by the callers as "no token".
    pub fn parse(s: &str) -> Token {
        Token::parse_bytes(s.as_bytes())
    }

    /// [`Token::parse`] on raw bytes (the big tables skip UTF-8 validation of tokens).
    pub fn parse_bytes(s: &[u8]) -> Token {
        if s.len() == 32 {
            let mut v: u128 = 0;
            let mut bad = 0u8;
            for &b in s {
                let d = HEX[b as usize];
                bad |= d;
                v = (v << 4) | (d & 0x0f) as u128;
            }
            if bad & 0x80 == 0 {
                if let Some(t) = Token::from_u128(v) {
                    return t;
                }
            }
        }
        // Non-hex token: FNV-1a 128-bit hash, text kept for display.
        let t = Token::from_bits(depthsense_base::hash::fnv1a128(s));
        if let Ok(mut g) = EXOTIC.lock() {
            g.get_or_insert_with(HashMap::new)
                .entry(t.as_u128())
                .or_insert_with(|| String::from_utf8_lossy(s).into_owned());
            HAS_EXOTIC.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        t
    }

    /// A well-mixed 64-bit hash (splitmix64 finaliser): every output bit depends on every
    /// input bit, so masking the low bits works for sequential and random tokens alike.
    fn hash64(self) -> u64 {
        depthsense_base::hash::splitmix64_mix(self.lo ^ self.hi.get().rotate_left(32))
    }
}

impl fmt::Display for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if HAS_EXOTIC.load(std::sync::atomic::Ordering::Relaxed) {
            if let Ok(g) = EXOTIC.lock() {
                if let Some(s) = g.as_ref().and_then(|m| m.get(&self.as_u128())) {
                    return f.write_str(s);
                }
            }
        }
        write!(f, "{:032x}", self.as_u128())
    }
}

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Token({self})")
    }
}

/// Hasher for [`Token`] keys: tokens are already uniformly random, so folding the 128 bits
/// (with a multiply for non-hex hashed tokens) is enough and much faster than SipHash.
#[derive(Default, Clone, Copy)]
pub struct TokenHasher(u64);

impl std::hash::Hasher for TokenHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = (self.0.rotate_left(5) ^ *b as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(29) ^ v).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
    fn write_u128(&mut self, v: u128) {
        self.0 = ((v as u64) ^ ((v >> 64) as u64)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

/// Token → row index of one table, holding only `u32` row numbers (4 bytes a slot instead of
/// 32 for a `HashMap<Token, u32>` entry): the token is compared against the row itself.
/// Open addressing, linear probing, load ≤ 0.5–0.75. When two rows share a token, the later
/// one wins (like repeated `HashMap::insert`).
#[derive(Default)]
pub struct RowIndex {
    slots: Vec<u32>,
}

const EMPTY_SLOT: u32 = u32::MAX;

impl RowIndex {
    /// Index `rows` by `tok`.
    pub fn build<T>(rows: &[T], tok: impl Fn(&T) -> Token) -> RowIndex {
        let n = rows.len().min(EMPTY_SLOT as usize - 1);
        let cap = (n + n / 3 + 1).next_power_of_two().max(8);
        let mut slots = vec![EMPTY_SLOT; cap];
        let mask = cap - 1;
        for (i, r) in rows.iter().take(n).enumerate() {
            let t = tok(r);
            let mut k = t.hash64() as usize & mask;
            loop {
                let s = slots[k];
                if s == EMPTY_SLOT || tok(&rows[s as usize]) == t {
                    slots[k] = i as u32;
                    break;
                }
                k = (k + 1) & mask;
            }
        }
        RowIndex { slots }
    }

    /// Row of `token`, given the same rows and key function as [`RowIndex::build`].
    pub fn get<T>(&self, rows: &[T], tok: impl Fn(&T) -> Token, token: Token) -> Option<usize> {
        if self.slots.is_empty() {
            return None;
        }
        let mask = self.slots.len() - 1;
        let mut k = token.hash64() as usize & mask;
        loop {
            let s = *self.slots.get(k)?;
            if s == EMPTY_SLOT {
                return None;
            }
            let row = rows.get(s as usize)?;
            if tok(row) == token {
                return Some(s as usize);
            }
            k = (k + 1) & mask;
        }
    }
}

/// The parts shared by many file names: `samples/CAM_FRONT/<log>__CAM_FRONT__` and `.jpg`.
#[derive(Debug, PartialEq, Eq, Hash)]
struct NameParts {
    prefix: Box<str>,
    suffix: Box<str>,
}

/// A sample_data file name relative to the dataroot, stored compactly: nuScenes names are
/// `<folder>/<channel>/<log>__<channel>__<timestamp>.<ext>`, so the prefix and extension are
/// shared between rows (one `Arc`) and the timestamp kept as a number; the text is built on
/// first use and cached. 32 bytes a row instead of ~110 for a `Box<str>` and its heap block.
/// Names of any other shape are kept as text. Derefs to `str`.
#[allow(clippy::box_collection)]
pub struct FileName {
    parts: Option<Arc<NameParts>>,
    // A thin pointer on purpose: `OnceLock<String>` would make every row 8 bytes larger.
    number: u64,
    text: OnceLock<Box<String>>,
}

thread_local! {
    /// Recently used name parts of this thread, by hash (bounded; only shares memory
    /// between rows, so a collision or a clear just costs one more `Arc`).
    static PARTS: std::cell::RefCell<HashMap<u64, Arc<NameParts>>> =
        std::cell::RefCell::new(HashMap::new());
}

impl FileName {
    /// Store `s` (compactly when it has the nuScenes shape).
    pub fn new(s: &str) -> FileName {
        if let Some((prefix, number, suffix)) = Self::split(s) {
            let key = {
                use std::hash::{Hash, Hasher};
                let mut h = std::collections::hash_map::DefaultHasher::new();
                (prefix, suffix).hash(&mut h);
                h.finish()
            };
            let parts = PARTS.with(|c| {
                let mut c = c.borrow_mut();
                if let Some(p) = c.get(&key) {
                    if &*p.prefix == prefix && &*p.suffix == suffix {
                        return p.clone();
                    }
                }
                if c.len() >= 4096 {
                    c.clear();
                }
                let p = Arc::new(NameParts {
                    prefix: prefix.into(),
                    suffix: suffix.into(),
                });
                c.insert(key, p.clone());
                p
            });
            return FileName {
                parts: Some(parts),
                number,
                text: OnceLock::new(),
            };
        }
        FileName {
            parts: None,
            number: 0,
            text: OnceLock::from(Box::new(s.to_string())),
        }
    }

    /// `(prefix through the last "__", timestamp, rest)` when the digits after the last "__"
    /// round-trip through a u64 (no sign, no leading zero).
    fn split(s: &str) -> Option<(&str, u64, &str)> {
        let at = s.rfind("__")? + 2;
        let rest = &s[at..];
        let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
        if digits == 0 || digits > 19 || (digits > 1 && rest.starts_with('0')) {
            return None;
        }
        let number: u64 = rest[..digits].parse().ok()?;
        Some((&s[..at], number, &rest[digits..]))
    }

    /// The name as text.
    pub fn as_str(&self) -> &str {
        self.text.get_or_init(|| {
            Box::new(match &self.parts {
                Some(p) => format!("{}{}{}", p.prefix, self.number, p.suffix),
                None => String::new(),
            })
        })
    }
}

impl std::ops::Deref for FileName {
    type Target = str;
    fn deref(&self) -> &str {
        self.as_str()
    }
}

impl AsRef<str> for FileName {
    fn as_ref(&self) -> &str {
        self.as_str()
    }
}

impl AsRef<Path> for FileName {
    fn as_ref(&self) -> &Path {
        Path::new(self.as_str())
    }
}

impl Clone for FileName {
    fn clone(&self) -> Self {
        FileName {
            parts: self.parts.clone(),
            number: self.number,
            text: match (&self.parts, self.text.get()) {
                (None, Some(t)) => OnceLock::from(t.clone()),
                _ => OnceLock::new(),
            },
        }
    }
}

impl PartialEq for FileName {
    fn eq(&self, other: &Self) -> bool {
        self.as_str() == other.as_str()
    }
}

impl Eq for FileName {}

impl fmt::Display for FileName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Debug for FileName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

impl From<&str> for FileName {
    fn from(s: &str) -> Self {
        FileName::new(s)
    }
}

/// A short list of tokens (annotation attributes): none or one inline, more on the heap.
#[derive(Clone, PartialEq, Eq, Default)]
pub enum TokenList {
    #[default]
    Empty,
    One(Token),
    Many(Box<[Token]>),
}

impl std::ops::Deref for TokenList {
    type Target = [Token];
    fn deref(&self) -> &[Token] {
        match self {
            TokenList::Empty => &[],
            TokenList::One(t) => std::slice::from_ref(t),
            TokenList::Many(v) => v,
        }
    }
}

impl FromIterator<Token> for TokenList {
    fn from_iter<I: IntoIterator<Item = Token>>(it: I) -> Self {
        let v: Vec<Token> = it.into_iter().collect();
        match v.len() {
            0 => TokenList::Empty,
            1 => TokenList::One(v[0]),
            _ => TokenList::Many(v.into_boxed_slice()),
        }
    }
}

impl fmt::Debug for TokenList {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

/// `HashMap` keyed by [`Token`] with [`TokenHasher`].
pub type TokenMap<V> = HashMap<Token, V, std::hash::BuildHasherDefault<TokenHasher>>;

fn opt_token_b(s: Option<&[u8]>) -> Option<Token> {
    match s {
        None | Some(b"") => None,
        Some(s) => Some(Token::parse_bytes(s)),
    }
}

fn opt_token(s: Option<&str>) -> Option<Token> {
    match s {
        None | Some("") => None,
        Some(s) => Some(Token::parse(s)),
    }
}

// ---------------------------------------------------------------- records

#[derive(Debug, Clone)]
pub struct Scene {
    pub token: Token,
    pub log_token: Token,
    pub nbr_samples: u32,
    pub first_sample_token: Option<Token>,
    pub last_sample_token: Option<Token>,
    pub name: String,
    pub description: String,
}

#[derive(Debug, Clone)]
pub struct Sample {
    pub token: Token,
    pub timestamp_us: i64,
    pub prev: Option<Token>,
    pub next: Option<Token>,
    pub scene_token: Token,
}

#[derive(Debug, Clone)]
pub struct SampleData {
    pub token: Token,
    pub sample_token: Option<Token>,
    pub ego_pose_token: Token,
    pub calibrated_sensor_token: Token,
    pub timestamp_us: i64,
    pub is_key_frame: bool,
    pub width: u32,
    pub height: u32,
    /// Relative to the dataroot.
    pub filename: FileName,
    pub prev: Option<Token>,
    pub next: Option<Token>,
}

#[derive(Debug, Clone)]
pub struct CalibratedSensor {
    pub token: Token,
    pub sensor_token: Token,
    pub translation: [f64; 3],
    /// w, x, y, z (SPEC §2).
    pub rotation: [f64; 4],
    /// Row-major 3x3; `None` for non-camera sensors.
    pub camera_intrinsic: Option<[[f64; 3]; 3]>,
}

#[derive(Debug, Clone)]
pub struct EgoPose {
    pub token: Token,
    pub timestamp_us: i64,
    /// w, x, y, z (SPEC §2).
    pub rotation: [f64; 4],
    pub translation: [f64; 3],
}

#[derive(Debug, Clone)]
pub struct Sensor {
    pub token: Token,
    pub channel: String,
    pub modality: String,
}

#[derive(Debug, Clone)]
pub struct Log {
    pub token: Token,
    pub logfile: String,
    pub vehicle: String,
    pub date_captured: String,
    pub location: String,
}

#[derive(Debug, Clone)]
pub struct SampleAnnotation {
    pub token: Token,
    pub sample_token: Token,
    pub instance_token: Token,
    pub attribute_tokens: TokenList,
    pub translation: [f64; 3],
    /// width, length, height (devkit order).
    pub size: [f64; 3],
    pub rotation: [f64; 4],
    pub prev: Option<Token>,
    pub next: Option<Token>,
}

#[derive(Debug, Clone)]
pub struct Instance {
    pub token: Token,
    pub category_token: Token,
}

#[derive(Debug, Clone)]
pub struct Category {
    pub token: Token,
    pub name: String,
}

#[derive(Debug, Clone)]
pub struct Attribute {
    pub token: Token,
    pub name: String,
}

// ------------------------------------------------------------ raw (borrowed) rows

#[derive(Deserialize)]
struct RawScene<'a> {
    #[serde(borrow)]
    token: &'a str,
    log_token: &'a str,
    #[serde(default)]
    nbr_samples: u32,
    first_sample_token: Option<&'a str>,
    last_sample_token: Option<&'a str>,
    #[serde(borrow, default)]
    name: std::borrow::Cow<'a, str>,
    #[serde(borrow, default)]
    description: std::borrow::Cow<'a, str>,
}

#[derive(Deserialize)]
struct RawSample<'a> {
    token: &'a str,
    timestamp: i64,
    prev: Option<&'a str>,
    next: Option<&'a str>,
    scene_token: &'a str,
}

#[derive(Deserialize)]
struct RawSampleData<'a> {
    token: &'a [u8],
    sample_token: Option<&'a [u8]>,
    ego_pose_token: &'a [u8],
    calibrated_sensor_token: &'a [u8],
    timestamp: i64,
    #[serde(default)]
    is_key_frame: bool,
    #[serde(default)]
    height: u32,
    #[serde(default)]
    width: u32,
    #[serde(borrow)]
    filename: std::borrow::Cow<'a, str>,
    prev: Option<&'a [u8]>,
    next: Option<&'a [u8]>,
}

#[derive(Deserialize)]
struct RawCalib<'a> {
    token: &'a str,
    sensor_token: &'a str,
    translation: [f64; 3],
    rotation: [f64; 4],
    #[serde(default)]
    camera_intrinsic: Vec<Vec<f64>>,
}

#[derive(Deserialize)]
struct RawEgo<'a> {
    token: &'a [u8],
    timestamp: i64,
    rotation: [f64; 4],
    translation: [f64; 3],
}

#[derive(Deserialize)]
struct RawSensor<'a> {
    token: &'a str,
    #[serde(borrow)]
    channel: std::borrow::Cow<'a, str>,
    #[serde(borrow, default)]
    modality: std::borrow::Cow<'a, str>,
}

#[derive(Deserialize)]
struct RawLog<'a> {
    token: &'a str,
    #[serde(borrow, default)]
    logfile: std::borrow::Cow<'a, str>,
    #[serde(borrow, default)]
    vehicle: std::borrow::Cow<'a, str>,
    #[serde(borrow, default)]
    date_captured: std::borrow::Cow<'a, str>,
    #[serde(borrow, default)]
    location: std::borrow::Cow<'a, str>,
}

#[derive(Deserialize)]
struct RawAnn<'a> {
    token: &'a [u8],
    sample_token: &'a [u8],
    instance_token: &'a [u8],
    #[serde(borrow, default)]
    attribute_tokens: Vec<&'a [u8]>,
    translation: [f64; 3],
    size: [f64; 3],
    rotation: [f64; 4],
    prev: Option<&'a [u8]>,
    next: Option<&'a [u8]>,
}

#[derive(Deserialize)]
struct RawInstance<'a> {
    token: &'a str,
    category_token: &'a str,
}

#[derive(Deserialize)]
struct RawNamed<'a> {
    token: &'a str,
    #[serde(borrow)]
    name: std::borrow::Cow<'a, str>,
}

// ------------------------------------------------------------ raw rows → records

impl RawScene<'_> {
    /// The stored [`Scene`] of this parsed row.
    fn into_record(self) -> Scene {
        Scene {
            token: Token::parse(self.token),
            log_token: Token::parse(self.log_token),
            nbr_samples: self.nbr_samples,
            first_sample_token: opt_token(self.first_sample_token),
            last_sample_token: opt_token(self.last_sample_token),
            name: self.name.into_owned(),
            description: self.description.into_owned(),
        }
    }
}

impl RawSample<'_> {
    /// The stored [`Sample`] of this parsed row.
    fn into_record(self) -> Sample {
        Sample {
            token: Token::parse(self.token),
            timestamp_us: self.timestamp,
            prev: opt_token(self.prev),
            next: opt_token(self.next),
            scene_token: Token::parse(self.scene_token),
        }
    }
}

impl RawSampleData<'_> {
    /// The stored [`SampleData`] of this parsed row.
    fn into_record(self) -> SampleData {
        SampleData {
            token: Token::parse_bytes(self.token),
            sample_token: opt_token_b(self.sample_token),
            ego_pose_token: Token::parse_bytes(self.ego_pose_token),
            calibrated_sensor_token: Token::parse_bytes(self.calibrated_sensor_token),
            timestamp_us: self.timestamp,
            is_key_frame: self.is_key_frame,
            width: self.width,
            height: self.height,
            filename: FileName::new(&self.filename),
            prev: opt_token_b(self.prev),
            next: opt_token_b(self.next),
        }
    }
}

impl RawCalib<'_> {
    /// The stored [`CalibratedSensor`] of this parsed row.
    fn into_record(self) -> CalibratedSensor {
        let k = &self.camera_intrinsic;
        let camera_intrinsic = if k.len() == 3 && k.iter().all(|row| row.len() == 3) {
            Some([
                [k[0][0], k[0][1], k[0][2]],
                [k[1][0], k[1][1], k[1][2]],
                [k[2][0], k[2][1], k[2][2]],
            ])
        } else {
            None
        };
        CalibratedSensor {
            token: Token::parse(self.token),
            sensor_token: Token::parse(self.sensor_token),
            translation: self.translation,
            rotation: self.rotation,
            camera_intrinsic,
        }
    }
}

impl RawEgo<'_> {
    /// The stored [`EgoPose`] of this parsed row.
    fn into_record(self) -> EgoPose {
        EgoPose {
            token: Token::parse_bytes(self.token),
            timestamp_us: self.timestamp,
            rotation: self.rotation,
            translation: self.translation,
        }
    }
}

impl RawSensor<'_> {
    /// The stored [`Sensor`] of this parsed row.
    fn into_record(self) -> Sensor {
        Sensor {
            token: Token::parse(self.token),
            channel: self.channel.into_owned(),
            modality: self.modality.into_owned(),
        }
    }
}

impl RawLog<'_> {
    /// The stored [`Log`] of this parsed row.
    fn into_record(self) -> Log {
        Log {
            token: Token::parse(self.token),
            logfile: self.logfile.into_owned(),
            vehicle: self.vehicle.into_owned(),
            date_captured: self.date_captured.into_owned(),
            location: self.location.into_owned(),
        }
    }
}

impl RawAnn<'_> {
    /// The stored [`SampleAnnotation`] of this parsed row.
    fn into_record(self) -> SampleAnnotation {
        SampleAnnotation {
            token: Token::parse_bytes(self.token),
            sample_token: Token::parse_bytes(self.sample_token),
            instance_token: Token::parse_bytes(self.instance_token),
            attribute_tokens: self
                .attribute_tokens
                .iter()
                .map(|t| Token::parse_bytes(t))
                .collect(),
            translation: self.translation,
            size: self.size,
            rotation: self.rotation,
            prev: opt_token_b(self.prev),
            next: opt_token_b(self.next),
        }
    }
}

impl RawInstance<'_> {
    /// The stored [`Instance`] of this parsed row.
    fn into_record(self) -> Instance {
        Instance {
            token: Token::parse(self.token),
            category_token: Token::parse(self.category_token),
        }
    }
}

/// Stream a JSON list, converting each borrowed row as it is parsed.
fn parse_rows<'de, R, T, F>(bytes: &'de [u8], path: &Path, f: F) -> Result<Vec<T>>
where
    R: Deserialize<'de>,
    F: FnMut(R) -> T,
{
    struct V<R, T, F>(F, std::marker::PhantomData<(R, T)>);
    impl<'de, R: Deserialize<'de>, T, F: FnMut(R) -> T> Visitor<'de> for V<R, T, F> {
        type Value = Vec<T>;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("a JSON list of table rows")
        }
        fn visit_seq<A: SeqAccess<'de>>(
            mut self,
            mut seq: A,
        ) -> std::result::Result<Vec<T>, A::Error> {
            let mut out = Vec::with_capacity(seq.size_hint().unwrap_or(0));
            while let Some(r) = seq.next_element::<R>()? {
                out.push((self.0)(r));
            }
            Ok(out)
        }
    }
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let rows = de
        .deserialize_seq(V(f, std::marker::PhantomData))
        .and_then(|v| de.end().map(|_| v))
        .map_err(|e| NuError::Json {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
    Ok(rows)
}

/// Bytes read per chunk by [`parse_table_chunked`].
pub const TABLE_CHUNK_BYTES: usize = 16 << 20;

/// Parse a big table file (a JSON list of objects) in chunks: each chunk is split into
/// complete top-level rows by a small scanner (strings and nesting aware), and the rows are
/// parsed in parallel by `parse`, which gets one row's bytes. Memory stays at one chunk plus
/// the converted rows; rows keep file order. `Ok(None)` when the file is absent and not
/// `required`.
fn parse_table_chunked<T, F>(
    src: &Source,
    name: &str,
    required: bool,
    parse: F,
) -> Result<Option<Vec<T>>>
where
    T: Send,
    F: Fn(&[u8]) -> serde_json::Result<T> + Sync,
{
    parse_table_chunked_sized(src, name, required, parse, src.chunk_bytes())
}

/// Where the tables come from: a version folder, or bytes in memory (fuzzing, tests).
enum Source<'a> {
    Dir(PathBuf),
    Memory {
        label: PathBuf,
        tables: &'a [(&'a str, &'a [u8])],
        chunk_bytes: usize,
    },
}

impl Source<'_> {
    fn path(&self, name: &str) -> PathBuf {
        match self {
            Source::Dir(d) => d.join(format!("{name}.json")),
            Source::Memory { label, .. } => label.join(format!("{name}.json")),
        }
    }

    fn chunk_bytes(&self) -> usize {
        match self {
            Source::Dir(_) => TABLE_CHUNK_BYTES,
            Source::Memory { chunk_bytes, .. } => (*chunk_bytes).max(1),
        }
    }

    /// A reader over table `name` and its length; `None` when absent.
    fn open(&self, name: &str) -> Result<Option<(Box<dyn std::io::Read + Send + '_>, u64)>> {
        match self {
            Source::Dir(_) => {
                let path = self.path(name);
                match std::fs::File::open(&path) {
                    Ok(f) => {
                        let len = f.metadata().map(|m| m.len()).unwrap_or(0);
                        Ok(Some((Box::new(f), len)))
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                    Err(e) => Err(NuError::io(&path, e)),
                }
            }
            Source::Memory { tables, .. } => {
                Ok(tables.iter().find(|(n, _)| *n == name).map(|(_, b)| {
                    (
                        Box::new(*b) as Box<dyn std::io::Read + Send>,
                        b.len() as u64,
                    )
                }))
            }
        }
    }

    /// The whole of table `name`; `None` when absent.
    fn read(&self, name: &str) -> Result<Option<std::borrow::Cow<'_, [u8]>>> {
        match self {
            Source::Dir(_) => {
                let p = self.path(name);
                match std::fs::read(&p) {
                    Ok(b) => Ok(Some(b.into())),
                    Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
                    Err(e) => Err(NuError::io(&p, e)),
                }
            }
            Source::Memory { tables, .. } => Ok(tables
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, b)| (*b).into())),
        }
    }
}

fn parse_table_chunked_sized<T, F>(
    src: &Source,
    name: &str,
    required: bool,
    parse: F,
    chunk_bytes: usize,
) -> Result<Option<Vec<T>>>
where
    T: Send,
    F: Fn(&[u8]) -> serde_json::Result<T> + Sync,
{
    let path = src.path(name);
    let Some((mut file, file_len)) = open_table(src, name, required, &path)? else {
        return Ok(None);
    };
    let mut st = ScanState::default();
    let mut out: Vec<T> = Vec::new();
    let mut cur = fill_and_scan(&mut file, &path, &[], &mut st, chunk_bytes, Vec::new())?;
    reserve_rows(&mut out, &cur, file_len);
    let mut spare: Vec<u8> = Vec::new();
    loop {
        let next_buf = std::mem::take(&mut spare);
        let tail: Vec<u8> = cur.buf[cur.keep_from.min(cur.buf.len())..].to_vec();
        if cur.eof && !tail.is_empty() {
            return Err(json_err(
                &path,
                format!("truncated: row {} is not complete", st.row_no),
            ));
        }
        // Parse this chunk's rows while the next chunk is read and scanned.
        let (parsed, next) = rayon::join(
            || parse_chunk_rows(&cur, &parse),
            || {
                if cur.eof {
                    None
                } else {
                    Some(fill_and_scan(
                        &mut file,
                        &path,
                        &tail,
                        &mut st,
                        chunk_bytes,
                        next_buf,
                    ))
                }
            },
        );
        for r in parsed.map_err(|reason| json_err(&path, reason))? {
            out.extend(r);
        }
        match next {
            None => break,
            Some(n) => spare = std::mem::replace(&mut cur, n?).buf,
        }
    }
    check_list_closed(&st, &path)?;
    Ok(Some(out))
}

/// A [`NuError::Json`] naming the table file.
fn json_err(path: &Path, reason: String) -> NuError {
    NuError::Json {
        path: path.display().to_string(),
        reason,
    }
}

/// A reader over table `name` and its length; `None` when absent and not `required`.
fn open_table<'s>(
    src: &'s Source,
    name: &str,
    required: bool,
    path: &Path,
) -> Result<Option<(Box<dyn std::io::Read + Send + 's>, u64)>> {
    match src.open(name)? {
        Some(f) => Ok(Some(f)),
        None if !required => Ok(None),
        None => Err(NuError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "table file not found"),
        )),
    }
}

/// Reserve the whole table from the first chunk's row density (avoids regrowth copies),
/// never more memory than the file has bytes (a hostile file of tiny rows would
/// otherwise reserve gigabytes before its first row fails to parse).
fn reserve_rows<T>(out: &mut Vec<T>, first: &Chunk, file_len: u64) {
    if !first.spans.is_empty() && first.keep_from > 0 {
        let est = (file_len as f64 * first.spans.len() as f64
            / first.keep_from.min(first.buf.len()) as f64
            * 1.01) as usize;
        let by_bytes = file_len as usize / std::mem::size_of::<T>().max(1);
        out.reserve(est.min(by_bytes).min(100_000_000));
    }
}

/// Parse a chunk's rows in parallel (2048 rows a task), in file order; an error names the
/// first failing row.
fn parse_chunk_rows<T, F>(cur: &Chunk, parse: &F) -> std::result::Result<Vec<Vec<T>>, String>
where
    T: Send,
    F: Fn(&[u8]) -> serde_json::Result<T> + Sync,
{
    use rayon::prelude::*;
    cur.spans
        .par_chunks(2048)
        .enumerate()
        .map(|(ci, chunk)| {
            chunk
                .iter()
                .enumerate()
                .map(|(k, &(a, b))| {
                    parse(&cur.buf[a..b])
                        .map_err(|e| format!("row {}: {e}", cur.first_row + ci * 2048 + k))
                })
                .collect()
        })
        .collect()
}

/// At the end of the file the list must have been opened and closed.
fn check_list_closed(st: &ScanState, path: &Path) -> Result<()> {
    if !st.finished {
        return Err(json_err(
            path,
            if st.started {
                format!("truncated: the list is not closed after {} rows", st.row_no)
            } else {
                "empty file: expected a JSON list".into()
            },
        ));
    }
    Ok(())
}

/// Row scanner state carried across chunks (always outside rows between chunks).
#[derive(Default)]
struct ScanState {
    started: bool,
    finished: bool,
    row_no: usize,
}

/// One chunk: its bytes, the complete rows in it, and where the incomplete tail starts.
struct Chunk {
    buf: Vec<u8>,
    spans: Vec<(usize, usize)>,
    keep_from: usize,
    first_row: usize,
    eof: bool,
}

/// Read up to `chunk_bytes` after `carry` (the previous chunk's incomplete row) and find the
/// complete top-level rows.
fn fill_and_scan(
    file: &mut dyn std::io::Read,
    path: &Path,
    carry: &[u8],
    st: &mut ScanState,
    chunk_bytes: usize,
    mut buf: Vec<u8>,
) -> Result<Chunk> {
    let eof = fill_chunk(file, path, carry, chunk_bytes, &mut buf)?;
    let first_row = st.row_no;
    let (spans, keep_from) = scan_rows(&buf, st, path)?;
    Ok(Chunk {
        buf,
        spans,
        keep_from,
        first_row,
        eof,
    })
}

/// Refill `buf` with `carry` and up to `chunk_bytes` more of `file`; true at end of file.
fn fill_chunk(
    file: &mut dyn std::io::Read,
    path: &Path,
    carry: &[u8],
    chunk_bytes: usize,
    buf: &mut Vec<u8>,
) -> Result<bool> {
    use std::io::Read;
    // Reuses the buffer of the chunk before last (no fresh pages to fault in).
    buf.clear();
    buf.reserve(carry.len() + chunk_bytes);
    buf.extend_from_slice(carry);
    // Read without zero-filling: `take` + `read_to_end` appends into spare capacity.
    let want = chunk_bytes as u64;
    let n = (&mut *file)
        .take(want)
        .read_to_end(buf)
        .map_err(|e| NuError::io(path, e))?;
    Ok((n as u64) < want)
}

/// Find the complete top-level rows of `buf` (spans of their bytes) and where the
/// incomplete tail starts (`buf.len()` when none), advancing `st` past them.
fn scan_rows(buf: &[u8], st: &mut ScanState, path: &Path) -> Result<(Vec<(usize, usize)>, usize)> {
    let mut spans: Vec<(usize, usize)> = Vec::new();
    let mut i = 0;
    let mut keep_from = buf.len();
    while i < buf.len() {
        let b = buf[i];
        if st.finished {
            if !b.is_ascii_whitespace() {
                return Err(json_err(
                    path,
                    format!("trailing characters after the list at row {}", st.row_no),
                ));
            }
            i += 1;
            continue;
        }
        if !st.started {
            match b {
                b'[' => st.started = true,
                b if b.is_ascii_whitespace() => {}
                _ => return Err(json_err(path, "expected a JSON list of table rows".into())),
            }
            i += 1;
            continue;
        }
        match b {
            b'{' => match object_end(buf, i) {
                Some(e) => {
                    spans.push((i, e));
                    st.row_no += 1;
                    i = e;
                }
                None => {
                    keep_from = i;
                    break;
                }
            },
            b']' => {
                st.finished = true;
                i += 1;
            }
            b',' => i += 1,
            b if b.is_ascii_whitespace() => i += 1,
            _ => {
                return Err(json_err(
                    path,
                    format!(
                        "row {}: expected an object, found {:?}",
                        st.row_no, b as char
                    ),
                ))
            }
        }
    }
    Ok((spans, keep_from))
}

/// End (exclusive) of the object that opens at `buf[start]`, or `None` when it does not
/// end within `buf`. Only braces and strings matter for finding the end of an object.
#[inline]
fn object_end(buf: &[u8], start: usize) -> Option<usize> {
    let mut i = start;
    let mut depth = 0usize;
    while let Some(k) = memchr::memchr3(b'"', b'{', b'}', &buf[i..]) {
        i += k;
        match buf[i] {
            b'"' => i = skip_string(buf, i + 1),
            b'{' => {
                depth += 1;
                i += 1;
            }
            _ => {
                depth -= 1;
                i += 1;
                if depth == 0 {
                    return Some(i);
                }
            }
        }
        if i >= buf.len() {
            break;
        }
    }
    None
}

/// Skip a string whose first byte is `buf[i]` (after the opening quote), honouring
/// backslash escapes: the position after the closing quote, or `≥ buf.len()` when the
/// string does not end within `buf`.
#[inline]
fn skip_string(buf: &[u8], mut i: usize) -> usize {
    loop {
        match memchr::memchr2(b'"', b'\\', &buf[i.min(buf.len())..]) {
            Some(k) if buf[i + k] == b'\\' => i += k + 2,
            Some(k) => return i + k + 1,
            None => return buf.len() + 1,
        }
        if i >= buf.len() {
            return i;
        }
    }
}

fn read_table<'s>(
    src: &'s Source,
    name: &str,
    required: bool,
) -> Result<Option<(PathBuf, std::borrow::Cow<'s, [u8]>)>> {
    let p = src.path(name);
    match src.read(name)? {
        Some(b) => Ok(Some((p, b))),
        None if !required => Ok(None),
        None => Err(NuError::io(
            &p,
            std::io::Error::new(std::io::ErrorKind::NotFound, "table file not found"),
        )),
    }
}

/// Key functions of the indexed tables (one per row type, so that index and lookup agree).
trait Keyed {
    fn key(&self) -> Token;
}

macro_rules! keyed {
    ($($t:ty),*) => {$(
        impl Keyed for $t {
            fn key(&self) -> Token {
                self.token
            }
        }
    )*};
}
keyed!(
    Scene,
    Sample,
    SampleData,
    CalibratedSensor,
    EgoPose,
    Sensor,
    Log,
    SampleAnnotation,
    Instance,
    Category,
    Attribute
);

fn index_of<T: Keyed>(rows: &[T]) -> RowIndex {
    RowIndex::build(rows, T::key)
}

fn lookup<'a, T: Keyed>(idx: &RowIndex, rows: &'a [T], token: Token) -> Option<&'a T> {
    idx.get(rows, T::key, token).and_then(|i| rows.get(i))
}

/// A loaded nuScenes version folder with its indexes.
pub struct NuScenes {
    pub dataroot: PathBuf,
    pub version: String,
    pub scene: Vec<Scene>,
    pub sample: Vec<Sample>,
    pub sample_data: Vec<SampleData>,
    pub calibrated_sensor: Vec<CalibratedSensor>,
    pub ego_pose: Vec<EgoPose>,
    pub sensor: Vec<Sensor>,
    pub log: Vec<Log>,
    /// `None` when the version has no annotations (e.g. v1.0-test, synthetic worlds).
    pub sample_annotation: Option<Vec<SampleAnnotation>>,
    pub instance: Vec<Instance>,
    pub category: Vec<Category>,
    pub attribute: Vec<Attribute>,

    scene_idx: RowIndex,
    sample_idx: RowIndex,
    sd_idx: RowIndex,
    calib_idx: RowIndex,
    ego_idx: RowIndex,
    sensor_idx: RowIndex,
    log_idx: RowIndex,
    ann_idx: RowIndex,
    instance_idx: RowIndex,
    category_idx: RowIndex,
    attribute_idx: RowIndex,
    /// sample → [(sensor row, keyframe sample_data row)].
    sample_keyframes: TokenMap<Vec<(u32, u32)>>,
    /// scene → sample indices ordered by timestamp.
    scene_samples: TokenMap<Vec<u32>>,
    /// sample → annotation indices.
    sample_anns: TokenMap<Vec<u32>>,
}

/// Row counts per table (for `inspect`).
pub type RowCounts = Vec<(&'static str, usize)>;

macro_rules! getter {
    ($fn:ident, $ty:ty, $vec:ident, $idx:ident, $name:literal) => {
        /// Row by token, or a `MissingToken` error naming the referring row.
        pub fn $fn(
            &self,
            token: Token,
            table: &'static str,
            from: Token,
            field: &'static str,
        ) -> Result<&$ty> {
            lookup(&self.$idx, &self.$vec, token).ok_or_else(|| NuError::MissingToken {
                table,
                token: from.to_string(),
                field,
                target: $name,
                missing: token.to_string(),
            })
        }
    };
}

/// The version folders of `dataroot` (its sub-folders holding `scene.json`), sorted.
pub fn version_folders(dataroot: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dataroot)
        .map(|rd| {
            rd.flatten()
                .filter(|e| e.path().join("scene.json").is_file())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

impl NuScenes {
    /// Load `dataroot/version/*.json`.
    pub fn load(dataroot: &Path, version: &str) -> Result<NuScenes> {
        let dir = dataroot.join(version);
        if !dir.is_dir() {
            return Err(NuError::VersionNotFound {
                dataroot: dataroot.display().to_string(),
                version: version.to_string(),
                found: version_folders(dataroot),
            });
        }
        Self::load_from(&Source::Dir(dir), dataroot, version)
    }

    /// Load tables given as bytes (`("sample_data", bytes)`, … without `.json`), read
    /// `chunk_bytes` at a time like files ([`TABLE_CHUNK_BYTES`] for the default). Errors
    /// name `<memory>/<version>/<table>.json`. For fuzzing and tests: every byte of a table
    /// goes through the same code as [`NuScenes::load`].
    pub fn from_memory(
        version: &str,
        tables: &[(&str, &[u8])],
        chunk_bytes: usize,
    ) -> Result<NuScenes> {
        let label = Path::new("<memory>").join(version);
        let src = Source::Memory {
            label: label.clone(),
            tables,
            chunk_bytes,
        };
        Self::load_from(&src, Path::new("<memory>"), version)
    }

    fn load_from(src: &Source, dataroot: &Path, version: &str) -> Result<NuScenes> {
        // The big tables are parsed chunk by chunk, rows in parallel.
        let sample_data = parse_table_chunked(src, "sample_data", true, |b| {
            serde_json::from_slice::<RawSampleData>(b).map(RawSampleData::into_record)
        })?
        .unwrap_or_default();
        let ego_pose = parse_table_chunked(src, "ego_pose", true, |b| {
            serde_json::from_slice::<RawEgo>(b).map(RawEgo::into_record)
        })?
        .unwrap_or_default();
        let sample_annotation = parse_table_chunked(src, "sample_annotation", false, |b| {
            serde_json::from_slice::<RawAnn>(b).map(RawAnn::into_record)
        })?;
        let mut small = Self::load_small(src)?;
        small.sample_annotation = sample_annotation;
        Ok(Self::assemble(
            dataroot,
            version,
            small,
            sample_data,
            ego_pose,
        ))
    }

    fn load_small(src: &Source) -> Result<Small> {
        let need = |n: &str| -> Result<(PathBuf, std::borrow::Cow<'_, [u8]>)> {
            Ok(read_table(src, n, true)?.unwrap_or_default())
        };
        let (p, b) = need("scene")?;
        let scene = parse_rows(&b, &p, RawScene::into_record)?;
        let (p, b) = need("sample")?;
        let sample = parse_rows(&b, &p, RawSample::into_record)?;
        let (p, b) = need("calibrated_sensor")?;
        let calibrated_sensor = parse_rows(&b, &p, RawCalib::into_record)?;
        let (p, b) = need("sensor")?;
        let sensor = parse_rows(&b, &p, RawSensor::into_record)?;
        let (p, b) = need("log")?;
        let log = parse_rows(&b, &p, RawLog::into_record)?;
        let instance = match read_table(src, "instance", false)? {
            Some((p, b)) => parse_rows(&b, &p, RawInstance::into_record)?,
            None => Vec::new(),
        };
        let named = |n: &str| -> Result<Vec<(Token, String)>> {
            match read_table(src, n, false)? {
                Some((p, b)) => parse_rows(&b, &p, |r: RawNamed| {
                    (Token::parse(r.token), r.name.into_owned())
                }),
                None => Ok(Vec::new()),
            }
        };
        let category = named("category")?
            .into_iter()
            .map(|(token, name)| Category { token, name })
            .collect();
        let attribute = named("attribute")?
            .into_iter()
            .map(|(token, name)| Attribute { token, name })
            .collect();
        Ok(Small {
            scene,
            sample,
            calibrated_sensor,
            sensor,
            log,
            sample_annotation: None,
            instance,
            category,
            attribute,
        })
    }

    fn assemble(
        dataroot: &Path,
        version: &str,
        s: Small,
        sample_data: Vec<SampleData>,
        ego_pose: Vec<EgoPose>,
    ) -> NuScenes {
        let ((sd_idx, ego_idx), (sample_idx, calib_idx)) = rayon::join(
            || rayon::join(|| index_of(&sample_data), || index_of(&ego_pose)),
            || (index_of(&s.sample), index_of(&s.calibrated_sensor)),
        );
        let sensor_idx = index_of(&s.sensor);
        let sample_keyframes = sample_keyframes(&sample_data, &s, &calib_idx, &sensor_idx);
        let scene_samples = scene_samples(&s.sample);
        let (sample_anns, ann_idx) = match &s.sample_annotation {
            Some(a) => (sample_anns(a), index_of(a)),
            None => (TokenMap::default(), RowIndex::default()),
        };
        NuScenes {
            dataroot: dataroot.to_path_buf(),
            version: version.to_string(),
            scene_idx: index_of(&s.scene),
            log_idx: index_of(&s.log),
            instance_idx: index_of(&s.instance),
            category_idx: index_of(&s.category),
            attribute_idx: index_of(&s.attribute),
            sample_idx,
            sd_idx,
            calib_idx,
            ego_idx,
            sensor_idx,
            ann_idx,
            sample_keyframes,
            scene_samples,
            sample_anns,
            scene: s.scene,
            sample: s.sample,
            sample_data,
            calibrated_sensor: s.calibrated_sensor,
            ego_pose,
            sensor: s.sensor,
            log: s.log,
            sample_annotation: s.sample_annotation,
            instance: s.instance,
            category: s.category,
            attribute: s.attribute,
        }
    }

    getter!(get_scene, Scene, scene, scene_idx, "scene");
    getter!(get_sample, Sample, sample, sample_idx, "sample");
    getter!(
        get_sample_data,
        SampleData,
        sample_data,
        sd_idx,
        "sample_data"
    );
    getter!(
        get_calibrated_sensor,
        CalibratedSensor,
        calibrated_sensor,
        calib_idx,
        "calibrated_sensor"
    );
    getter!(get_ego_pose, EgoPose, ego_pose, ego_idx, "ego_pose");
    getter!(get_sensor, Sensor, sensor, sensor_idx, "sensor");
    getter!(get_log, Log, log, log_idx, "log");
    getter!(get_instance, Instance, instance, instance_idx, "instance");
    getter!(get_category, Category, category, category_idx, "category");
    getter!(
        get_attribute,
        Attribute,
        attribute,
        attribute_idx,
        "attribute"
    );

    /// Annotation by token (None when absent).
    pub fn annotation(&self, token: Token) -> Option<&SampleAnnotation> {
        lookup(&self.ann_idx, self.sample_annotation.as_deref()?, token)
    }

    /// Sample-data row by token, if present.
    pub fn sample_data_opt(&self, token: Token) -> Option<&SampleData> {
        lookup(&self.sd_idx, &self.sample_data, token)
    }

    /// The keyframe sample_data of `channel` for `sample`.
    pub fn keyframe(&self, sample: Token, channel: &str) -> Option<&SampleData> {
        self.sample_keyframes
            .get(&sample)?
            .iter()
            .find(|&&(si, _)| self.sensor[si as usize].channel == channel)
            .map(|&(_, i)| &self.sample_data[i as usize])
    }

    /// Channels with a keyframe in `sample`.
    pub fn keyframe_channels(&self, sample: Token) -> Vec<&str> {
        self.sample_keyframes
            .get(&sample)
            .map(|v| {
                v.iter()
                    .map(|&(si, _)| self.sensor[si as usize].channel.as_str())
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Samples of `scene` ordered by timestamp.
    pub fn scene_samples(&self, scene: Token) -> Vec<&Sample> {
        self.scene_samples
            .get(&scene)
            .map(|v| v.iter().map(|&i| &self.sample[i as usize]).collect())
            .unwrap_or_default()
    }

    /// Annotations of `sample` (empty without annotations).
    pub fn sample_annotations(&self, sample: Token) -> Vec<&SampleAnnotation> {
        match (&self.sample_annotation, self.sample_anns.get(&sample)) {
            (Some(a), Some(v)) => v.iter().map(|&i| &a[i as usize]).collect(),
            _ => Vec::new(),
        }
    }

    /// Channel name of a sample_data row (through calibrated_sensor → sensor).
    pub fn channel_of(&self, sd: &SampleData) -> Result<&str> {
        let cs = self.get_calibrated_sensor(
            sd.calibrated_sensor_token,
            "sample_data",
            sd.token,
            "calibrated_sensor_token",
        )?;
        let s = self.get_sensor(
            cs.sensor_token,
            "calibrated_sensor",
            cs.token,
            "sensor_token",
        )?;
        Ok(&s.channel)
    }

    /// Up to `n` sweeps going backwards (`prev`) from `sd`, starting with `sd` itself.
    /// The chain ends early at the first prev that is empty or absent from the table.
    pub fn sweeps_back<'a>(&'a self, sd: &'a SampleData, n: usize) -> Vec<&'a SampleData> {
        self.chain(sd, n, |s| s.prev)
    }

    /// Up to `n` sweeps going forwards (`next`), starting with `sd` itself.
    pub fn sweeps_forward<'a>(&'a self, sd: &'a SampleData, n: usize) -> Vec<&'a SampleData> {
        self.chain(sd, n, |s| s.next)
    }

    fn chain<'a>(
        &'a self,
        sd: &'a SampleData,
        n: usize,
        step: impl Fn(&SampleData) -> Option<Token>,
    ) -> Vec<&'a SampleData> {
        let mut out = Vec::with_capacity(n);
        let mut cur = Some(sd);
        while let Some(s) = cur {
            if out.len() >= n {
                break;
            }
            out.push(s);
            cur = step(s).and_then(|t| self.sample_data_opt(t));
        }
        out
    }

    /// Absolute path of a sample_data file.
    pub fn path_of(&self, sd: &SampleData) -> PathBuf {
        self.dataroot.join(&*sd.filename)
    }

    /// Row counts per table.
    pub fn row_counts(&self) -> RowCounts {
        vec![
            ("scene", self.scene.len()),
            ("sample", self.sample.len()),
            ("sample_data", self.sample_data.len()),
            ("calibrated_sensor", self.calibrated_sensor.len()),
            ("ego_pose", self.ego_pose.len()),
            ("sensor", self.sensor.len()),
            ("log", self.log.len()),
            (
                "sample_annotation",
                self.sample_annotation.as_ref().map_or(0, |a| a.len()),
            ),
            ("instance", self.instance.len()),
            ("category", self.category.len()),
            ("attribute", self.attribute.len()),
        ]
    }
}

/// sample → [(sensor row, keyframe sample_data row)], the sensor found through the
/// keyframe's calibrated sensor; keyframes without a sample or sensor are left out.
fn sample_keyframes(
    sample_data: &[SampleData],
    s: &Small,
    calib_idx: &RowIndex,
    sensor_idx: &RowIndex,
) -> TokenMap<Vec<(u32, u32)>> {
    let mut sample_keyframes: TokenMap<Vec<(u32, u32)>> = TokenMap::default();
    for (i, sd) in sample_data.iter().enumerate() {
        if !sd.is_key_frame {
            continue;
        }
        // Sensor row of the keyframe (through its calibrated sensor).
        let sensor = calib_idx
            .get(&s.calibrated_sensor, Keyed::key, sd.calibrated_sensor_token)
            .and_then(|c| {
                sensor_idx.get(&s.sensor, Keyed::key, s.calibrated_sensor[c].sensor_token)
            });
        if let (Some(st), Some(si)) = (sd.sample_token, sensor) {
            sample_keyframes
                .entry(st)
                .or_default()
                .push((si as u32, i as u32));
        }
    }
    sample_keyframes
}

/// scene → sample rows ordered by (timestamp, row).
fn scene_samples(sample: &[Sample]) -> TokenMap<Vec<u32>> {
    let mut scene_samples: TokenMap<Vec<u32>> = TokenMap::default();
    for (i, smp) in sample.iter().enumerate() {
        scene_samples
            .entry(smp.scene_token)
            .or_default()
            .push(i as u32);
    }
    for v in scene_samples.values_mut() {
        v.sort_by_key(|&i| (sample[i as usize].timestamp_us, i));
    }
    scene_samples
}

/// sample → annotation rows, in table order.
fn sample_anns(anns: &[SampleAnnotation]) -> TokenMap<Vec<u32>> {
    let mut sample_anns: TokenMap<Vec<u32>> = TokenMap::default();
    for (i, r) in anns.iter().enumerate() {
        sample_anns
            .entry(r.sample_token)
            .or_default()
            .push(i as u32);
    }
    sample_anns
}

struct Small {
    scene: Vec<Scene>,
    sample: Vec<Sample>,
    calibrated_sensor: Vec<CalibratedSensor>,
    sensor: Vec<Sensor>,
    log: Vec<Log>,
    sample_annotation: Option<Vec<SampleAnnotation>>,
    instance: Vec<Instance>,
    category: Vec<Category>,
    attribute: Vec<Attribute>,
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn kf0() -> Option<PathBuf> {
        depthsense_testkit::fixture("nuscenes-kf0")
    }

    #[test]
    fn token_round_trip() {
        let s = "ca9a282c9e77460f8360f564131a8af5";
        assert_eq!(Token::parse(s).to_string(), s);
        let t = Token::parse("synthetic-scene-0");
        assert_eq!(t.to_string(), "synthetic-scene-0");
        assert_ne!(t, Token::parse("synthetic-scene-1"));
    }

    #[test]
    fn loads_partial_fixture_with_indexes() {
        let Some(root) = kf0() else { return };
        let nu = NuScenes::load(&root, "v1.0-mini").unwrap();
        assert_eq!(nu.sample.len(), 1);
        assert_eq!(nu.sample_data.len(), 3);
        assert!(nu.sample_annotation.is_none());
        let st = Token::parse("ca9a282c9e77460f8360f564131a8af5");
        let cam = nu.keyframe(st, "CAM_FRONT").unwrap();
        assert_eq!(cam.timestamp_us, 1532402927612460);
        assert_eq!(nu.channel_of(cam).unwrap(), "CAM_FRONT");
        let lidar = nu.keyframe(st, "LIDAR_TOP").unwrap();
        assert!(lidar.next.is_none()); // JSON null
        let radar = nu.keyframe(st, "RADAR_FRONT").unwrap();
        // next points at a row absent from the partial table: the chain stops there.
        assert!(radar.next.is_some());
        assert_eq!(nu.sweeps_forward(radar, 5).len(), 1);
        assert_eq!(nu.sweeps_back(radar, 5).len(), 1);
        let scene = &nu.scene[0];
        assert_eq!(nu.scene_samples(scene.token).len(), 1);
        assert_eq!(
            nu.get_log(scene.log_token, "scene", scene.token, "log_token")
                .unwrap()
                .location,
            "singapore-onenorth"
        );
    }

    #[test]
    fn chunked_parser_handles_strings_braces_and_chunk_edges() {
        let dir = tempfile::tempdir().unwrap();
        let mut text = String::from(" [\n");
        let names: Vec<String> = (0..50).map(|i| format!("a{{b}}\\\"c\\\\ ,[{i}]")).collect();
        for (i, n) in names.iter().enumerate() {
            if i > 0 {
                text.push_str(",\n");
            }
            text.push_str(&format!(
                "{{\"token\": \"{i}\", \"name\": \"{n}\", \"nested\": {{\"x\": [1, {{}}]}}}}"
            ));
        }
        text.push_str("\n]\n");
        std::fs::write(dir.path().join("t.json"), &text).unwrap();
        let src = Source::Dir(dir.path().to_path_buf());
        #[derive(Deserialize)]
        struct R {
            name: String,
        }
        let expect: Vec<String> = serde_json::from_str::<Vec<serde_json::Value>>(&text)
            .unwrap()
            .iter()
            .map(|v| v["name"].as_str().unwrap().to_string())
            .collect();
        for chunk in [7, 16, 61, 1000, 1 << 20] {
            let rows = parse_table_chunked_sized(
                &src,
                "t",
                true,
                |b| serde_json::from_slice::<R>(b).map(|r| r.name),
                chunk,
            )
            .unwrap()
            .unwrap();
            assert_eq!(rows, expect, "chunk {chunk}");
        }
        // Truncated and malformed files name the file.
        std::fs::write(dir.path().join("t.json"), &text[..text.len() / 2]).unwrap();
        let err =
            parse_table_chunked_sized(&src, "t", true, |b| serde_json::from_slice::<R>(b), 64)
                .err()
                .unwrap()
                .to_string();
        assert!(err.contains("t.json") && err.contains("truncated"), "{err}");
        std::fs::write(dir.path().join("t.json"), "{}").unwrap();
        assert!(
            parse_table_chunked_sized(&src, "t", true, |b| serde_json::from_slice::<R>(b), 64)
                .is_err()
        );
        assert!(parse_table_chunked_sized(
            &src,
            "absent",
            false,
            |b| serde_json::from_slice::<R>(b),
            64
        )
        .unwrap()
        .is_none());
    }

    #[test]
    fn compact_rows_keep_their_size() {
        // issue 10: trainval-sized tables must load in ≤ 1 GB.
        assert_eq!(std::mem::size_of::<Token>(), 16);
        assert_eq!(std::mem::size_of::<Option<Token>>(), 16);
        assert_eq!(std::mem::size_of::<FileName>(), 32);
        assert!(std::mem::size_of::<SampleData>() <= 152);
        assert!(std::mem::size_of::<SampleAnnotation>() <= 184);
        assert_eq!(std::mem::size_of::<EgoPose>(), 80);
    }

    #[test]
    fn tokens_with_a_zero_high_half_round_trip() {
        for s in [
            "0000000000000000ffffffffffffffff",
            "00000000000000000000000000000000",
            "00000001000000000000000000000000",
            "ffffffffffffffffffffffffffffffff",
        ] {
            let t = Token::parse(s);
            assert_eq!(t.to_string(), s);
            assert_eq!(Some(t), opt_token(Some(s)));
        }
        assert_ne!(
            Token::parse("00000000000000000000000000000000"),
            Token::parse("00000000000000000000000000000001")
        );
        assert_eq!(opt_token(Some("")), None);
        let _ = Token::default().to_string();
    }

    #[test]
    fn file_names_round_trip() {
        for s in [
            "samples/CAM_FRONT/n015-2018-07-24-11-22-45+0800__CAM_FRONT__1532402927612460.jpg",
            "sweeps/LIDAR_TOP/n008-2018-08-01-15-16-36-0400__LIDAR_TOP__1533151603547590.pcd.bin",
            "sweeps/X/log__X__0.pcd",
            "sweeps/X/log__X__007.pcd",
            "sweeps/X/log__X__99999999999999999999.pcd",
            "sweeps/X/log__X__18446744073709551615",
            "sweeps/X/log__X__.pcd",
            "sweeps/X/plain.pcd",
            "__1",
            "",
            "ünï__42__ç",
        ] {
            let f = FileName::new(s);
            assert_eq!(&*f, s);
            assert_eq!(f.clone().to_string(), s);
            assert_eq!(format!("{f:?}"), format!("{s:?}"));
            assert_eq!(f, FileName::from(s));
        }
    }

    #[test]
    fn row_index_finds_every_row_and_nothing_else() {
        let rows: Vec<Sensor> = (0..1000)
            .map(|i| Sensor {
                token: Token::parse(&format!("{:032x}", (i as u128 + 1) << 64 | i as u128)),
                channel: i.to_string(),
                modality: String::new(),
            })
            .collect();
        let idx = index_of(&rows);
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(idx.get(&rows, Keyed::key, r.token), Some(i));
        }
        assert_eq!(idx.get(&rows, Keyed::key, Token::parse("nope")), None);
        // duplicates: the later row wins, like HashMap::insert
        let dup = vec![rows[3].clone(), rows[5].clone(), rows[3].clone()];
        assert_eq!(index_of(&dup).get(&dup, Keyed::key, rows[3].token), Some(2));
        let empty: Vec<Sensor> = Vec::new();
        assert_eq!(
            index_of(&empty).get(&empty, Keyed::key, rows[0].token),
            None
        );
    }

    #[test]
    fn memory_tables_load_like_files() {
        let Some(root) = kf0() else { return };
        let dir = root.join("v1.0-mini");
        let names = [
            "scene",
            "sample",
            "sample_data",
            "calibrated_sensor",
            "ego_pose",
            "sensor",
            "log",
            "instance",
            "category",
            "attribute",
        ];
        let bytes: Vec<(&str, Vec<u8>)> = names
            .iter()
            .filter_map(|n| Some((*n, std::fs::read(dir.join(format!("{n}.json"))).ok()?)))
            .collect();
        let tables: Vec<(&str, &[u8])> = bytes.iter().map(|(n, b)| (*n, &b[..])).collect();
        let disk = NuScenes::load(&root, "v1.0-mini").unwrap();
        for chunk in [1, 17, 4096, TABLE_CHUNK_BYTES] {
            let mem = NuScenes::from_memory("v1.0-mini", &tables, chunk).unwrap();
            assert_eq!(mem.row_counts(), disk.row_counts());
            for (a, b) in mem.sample_data.iter().zip(&disk.sample_data) {
                assert_eq!(
                    (a.token, &a.filename, a.prev),
                    (b.token, &b.filename, b.prev)
                );
            }
            let st = Token::parse("ca9a282c9e77460f8360f564131a8af5");
            assert_eq!(
                mem.keyframe(st, "LIDAR_TOP").map(|s| s.token),
                disk.keyframe(st, "LIDAR_TOP").map(|s| s.token)
            );
        }
        // a missing required table names it
        let err = NuScenes::from_memory("v", &tables[..1], 64)
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("<memory>/v/"), "{err}");
    }

    #[test]
    fn hostile_tables_are_errors_without_big_reservations() {
        // Many tiny rows: the reservation from the first chunk's density is capped by the
        // file's byte length, and the first row fails to parse.
        let mut sd = b"[".to_vec();
        for _ in 0..200_000 {
            sd.extend_from_slice(b"{},");
        }
        sd.extend_from_slice(b"{}]");
        let tables: [(&str, &[u8]); 7] = [
            ("sample_data", &sd),
            ("ego_pose", b"[]"),
            ("scene", b"[]"),
            ("sample", b"[]"),
            ("calibrated_sensor", b"[]"),
            ("sensor", b"[]"),
            ("log", b"[]"),
        ];
        let err = NuScenes::from_memory("v", &tables, 4096)
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("sample_data.json") && err.contains("row 0"),
            "{err}"
        );
        // deep nesting, unterminated strings, trailing garbage, wrong types
        for bad in [
            &b"[{\"token\": [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[]}]"[..],
            &b"[{\"token\": \"abc"[..],
            &b"[] x"[..],
            &b"[{\"token\": 1e999999}]"[..],
            &b"[{}}]"[..],
            &b"]"[..],
            &b""[..],
        ] {
            let mut t = tables;
            t[0] = ("sample_data", bad);
            let err = NuScenes::from_memory("v", &t, 8).err().unwrap().to_string();
            assert!(err.contains("sample_data.json"), "{err}");
        }
    }

    #[test]
    fn missing_token_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let v = dir.path().join("v");
        std::fs::create_dir_all(&v).unwrap();
        for t in [
            "scene",
            "sample",
            "calibrated_sensor",
            "ego_pose",
            "sensor",
            "log",
        ] {
            std::fs::write(v.join(format!("{t}.json")), "[]").unwrap();
        }
        std::fs::write(
            v.join("sample_data.json"),
            r#"[{"token":"aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa","sample_token":"","ego_pose_token":"bbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbb","calibrated_sensor_token":"cccccccccccccccccccccccccccccccc","timestamp":1,"is_key_frame":false,"filename":"x","prev":"","next":""}]"#,
        )
        .unwrap();
        let nu = NuScenes::load(dir.path(), "v").unwrap();
        let err = nu.channel_of(&nu.sample_data[0]).unwrap_err().to_string();
        assert!(
            err.contains("sample_data row aaaaaaaa")
                && err.contains("calibrated_sensor_token")
                && err.contains("cccccccc"),
            "{err}"
        );
        std::fs::write(v.join("sample.json"), "[{\"token\": 3}]").unwrap();
        let err = NuScenes::load(dir.path(), "v").err().unwrap().to_string();
        assert!(err.contains("sample.json"), "{err}");
        assert!(NuScenes::load(dir.path(), "nope").is_err());
    }
}
