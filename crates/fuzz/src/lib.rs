//! A mutation fuzzer for every reader of untrusted bytes that runs on stable Rust (issue 10).
//!
//! Each [`Reader`] gets seeds — the real nuScenes fixtures where they exist, in-memory
//! encodings made by the project's own writers otherwise — and every execution feeds one
//! structurally mutated seed (bit flips, byte inserts/deletes, chunk copies, splices with
//! another seed, interesting integers written over binary fields and over decimal numbers in
//! text headers). Each execution runs under `catch_unwind` and is timed: a panic is a crash, an
//! execution longer than the hang limit is a hang; both save the input. An abort (allocation
//! failure, stack overflow) ends the process, so a finished run also proves there were none.

use std::io::Write;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use depthsense_weights::pickle::{collect_tensors, parse_pickle};
use depthsense_weights::safetensors::{parse as parse_safetensors, serialize as safetensors_bytes};
use depthsense_weights::torch_file::read_torch_bytes;
use depthsense_weights::{DType, HostTensor};

use depthsense_nuscenes::depth_png::{decode_png, encode_png, encode_png_fast, DepthMap};
use depthsense_nuscenes::geometry::Camera;
use depthsense_nuscenes::pcd::{
    encode_lidar_pcd_bin, encode_radar_pcd_ascii, encode_radar_pcd_binary,
    encode_radar_pcd_binary_compressed, parse_lidar_pcd_bin, parse_pcd, parse_radar_pcd,
    RadarPoint,
};
use depthsense_nuscenes::NuScenes;
use depthsense_prep::radar_points::RadarPoints;

/// The readers under test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reader {
    /// Radar `.pcd`, `DATA binary` (seeds: the real radar fixtures).
    PcdBinary,
    /// `.pcd`, `DATA ascii` (seeds: fixture points re-encoded).
    PcdAscii,
    /// `.pcd`, `DATA binary_compressed` with LZF (seeds: fixture points re-encoded).
    PcdBinaryCompressed,
    /// LIDAR_TOP `.pcd.bin` (seeds: slices of the real scan).
    PcdBin,
    /// The table JSON files through the chunked loader (seeds: the kf0 tables).
    TableJson,
    /// `torch.save` files, zip and legacy (seeds: real `torch.save` outputs + the writer).
    Pth,
    /// The pickle machine alone (seeds: the pickles inside those files).
    Pickle,
    /// Safetensors checkpoints (seeds: the checkpoint writer).
    Safetensors,
    /// 16-bit depth PNGs (seeds: the depth-map encoder).
    DepthPng,
    /// `.npy` float arrays that `score` reads (seeds: its encoder).
    Npy,
    /// A prepared sample's `radar_points.bin` (seeds: its encoder).
    RadarPointsBin,
}

impl Reader {
    pub const ALL: [Reader; 11] = [
        Reader::PcdBinary,
        Reader::PcdAscii,
        Reader::PcdBinaryCompressed,
        Reader::PcdBin,
        Reader::TableJson,
        Reader::Pth,
        Reader::Pickle,
        Reader::Safetensors,
        Reader::DepthPng,
        Reader::Npy,
        Reader::RadarPointsBin,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Reader::PcdBinary => "pcd-binary",
            Reader::PcdAscii => "pcd-ascii",
            Reader::PcdBinaryCompressed => "pcd-binary-compressed",
            Reader::PcdBin => "pcd-bin",
            Reader::TableJson => "table-json",
            Reader::Pth => "pth",
            Reader::Pickle => "pickle",
            Reader::Safetensors => "safetensors",
            Reader::DepthPng => "depth-png",
            Reader::Npy => "npy",
            Reader::RadarPointsBin => "radar-points-bin",
        }
    }

    pub fn from_name(s: &str) -> Option<Reader> {
        Reader::ALL.into_iter().find(|r| r.name() == s)
    }

    /// Does this reader need the fixtures for its seeds?
    pub fn needs_fixtures(self) -> bool {
        matches!(self, Reader::PcdBinary | Reader::PcdBin | Reader::TableJson)
    }

    /// Text formats get decimal numbers replaced as well.
    fn is_text(self) -> bool {
        matches!(
            self,
            Reader::PcdBinary
                | Reader::PcdAscii
                | Reader::PcdBinaryCompressed
                | Reader::TableJson
                | Reader::Safetensors
                | Reader::Npy
        )
    }
}

/// A small deterministic RNG (xorshift64*).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
    fn chance(&mut self, one_in: usize) -> bool {
        self.below(one_in) == 0
    }
}

const INTERESTING: [u64; 16] = [
    0,
    1,
    2,
    7,
    8,
    0x7f,
    0x80,
    0xff,
    0x7fff,
    0xffff,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    1 << 32,
    0x7fff_ffff_ffff_ffff,
    u64::MAX,
];

const INTERESTING_TEXT: [&str; 16] = [
    "0",
    "1",
    "-1",
    "43",
    "255",
    "65536",
    "4294967295",
    "4294967296",
    "1000000000000",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999999",
    "1e999",
    "nan",
    "",
];

const TOKENS: [&str; 14] = [
    "DATA ascii\n",
    "DATA binary\n",
    "DATA binary_compressed\n",
    "COUNT 1000000000000\n",
    "SIZE 8\n",
    "TYPE U\n",
    "\n",
    " ",
    "{",
    "}",
    "[",
    "]",
    "\"",
    "\\",
];

/// Apply 1–8 stacked mutations to `data` (`others` are splice partners).
pub fn mutate(data: &mut Vec<u8>, others: &[Vec<u8>], text: bool, rng: &mut Rng) {
    let n = 1 + rng.below(8);
    for _ in 0..n {
        mutate_once(data, others, text, rng);
    }
    // Keep inputs small enough for millions of executions.
    data.truncate(1 << 20);
}

/// One mutation, drawn from 10 kinds (12 for text formats); a kind that does not apply to
/// `data` (e.g. a bit flip of an empty input) leaves it unchanged.
fn mutate_once(data: &mut Vec<u8>, others: &[Vec<u8>], text: bool, rng: &mut Rng) {
    let len = data.len();
    match rng.below(if text { 12 } else { 10 }) {
        0 if len > 0 => {
            let i = rng.below(len);
            data[i] ^= 1 << rng.below(8);
        }
        1 if len > 0 => {
            let i = rng.below(len);
            data[i] = rng.next_u64() as u8;
        }
        2 => {
            let i = rng.below(len + 1);
            data.insert(i, rng.next_u64() as u8);
        }
        3 if len > 0 => {
            let i = rng.below(len);
            let k = 1 + rng.below((len - i).min(64));
            data.drain(i..i + k);
        }
        4 if len > 0 => copy_chunk(data, rng),
        5 if !others.is_empty() => splice_other(data, others, rng),
        6 | 7 if len > 0 => write_interesting_int(data, rng),
        8 if len > 0 => {
            let i = rng.below(len);
            data.truncate(i);
        }
        9 => {
            let t = TOKENS[rng.below(TOKENS.len())].as_bytes();
            let i = rng.below(len + 1);
            data.splice(i..i, t.iter().copied());
        }
        10 | 11 => replace_decimal(data, rng),
        _ => {}
    }
}

/// Copy a chunk elsewhere (duplicates records, headers, opcodes); `data` is not empty.
fn copy_chunk(data: &mut Vec<u8>, rng: &mut Rng) {
    let len = data.len();
    let i = rng.below(len);
    let k = 1 + rng.below((len - i).min(256));
    let chunk = data[i..i + k].to_vec();
    let at = rng.below(len + 1);
    data.splice(at..at, chunk);
}

/// Splice: our head + another seed's tail; `others` is not empty.
fn splice_other(data: &mut Vec<u8>, others: &[Vec<u8>], rng: &mut Rng) {
    let o = &others[rng.below(others.len())];
    let cut = rng.below(data.len() + 1);
    let from = rng.below(o.len() + 1);
    data.truncate(cut);
    data.extend_from_slice(&o[from..]);
}

/// An interesting integer over a binary field (1, 2, 4 or 8 bytes, LE or BE).
fn write_interesting_int(data: &mut [u8], rng: &mut Rng) {
    let len = data.len();
    let w = [1usize, 2, 4, 8][rng.below(4)];
    if len >= w {
        let i = rng.below(len - w + 1);
        let v = INTERESTING[rng.below(INTERESTING.len())]
            .wrapping_add(rng.below(3) as u64)
            .wrapping_sub(1);
        let b = if rng.chance(2) {
            v.to_le_bytes()
        } else {
            v.to_be_bytes()
        };
        let src = if rng.chance(2) { &b[..w] } else { &b[8 - w..] };
        data[i..i + w].copy_from_slice(src);
    }
}

/// Replace a decimal number (header values, JSON numbers) by an interesting one.
fn replace_decimal(data: &mut Vec<u8>, rng: &mut Rng) {
    let starts: Vec<usize> = (0..data.len())
        .filter(|&i| data[i].is_ascii_digit() && (i == 0 || !data[i - 1].is_ascii_digit()))
        .take(4096)
        .collect();
    if !starts.is_empty() {
        let s = starts[rng.below(starts.len())];
        let e = s + data[s..].iter().take_while(|b| b.is_ascii_digit()).count();
        let v = INTERESTING_TEXT[rng.below(INTERESTING_TEXT.len())];
        data.splice(s..e, v.bytes());
    }
}

/// Seeds of one reader; `None` when it needs fixtures that are absent.
pub fn seeds(reader: Reader, fixtures: &Path) -> Option<Vec<Vec<u8>>> {
    Some(match reader {
        Reader::PcdBinary => {
            let f = radar_files(fixtures);
            if f.is_empty() {
                return None;
            }
            f
        }
        Reader::PcdAscii => radar_points(&radar_files(fixtures))
            .iter()
            .map(|pts| encode_radar_pcd_ascii(&pts[..pts.len().min(24)]))
            .collect(),
        Reader::PcdBinaryCompressed => pcd_binary_compressed_seeds(fixtures),
        Reader::PcdBin => pcd_bin_seeds(fixtures)?,
        Reader::TableJson => table_json_seeds(fixtures)?,
        Reader::Pth => torch_seeds(),
        Reader::Pickle => torch_seeds()
            .iter()
            .filter_map(|b| inner_pickle(b))
            .collect(),
        Reader::Safetensors => safetensors_seeds()?,
        Reader::DepthPng => depth_png_seeds()?,
        Reader::Npy => npy_seeds(),
        Reader::RadarPointsBin => radar_points_bin_seeds(),
    })
}

/// The radar `.pcd` files of the fixtures: `radar-front-mini` (sorted), then the kf0
/// RADAR_FRONT samples; empty when the fixtures are absent.
fn radar_files(fixtures: &Path) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let mut paths: Vec<PathBuf> = std::fs::read_dir(fixtures.join("radar-front-mini"))
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    paths.sort();
    if let Ok(rd) = std::fs::read_dir(fixtures.join("nuscenes-kf0/samples/RADAR_FRONT")) {
        paths.extend(rd.filter_map(|e| e.ok().map(|e| e.path())));
    }
    for p in paths {
        if let Ok(b) = std::fs::read(&p) {
            out.push(b);
        }
    }
    out
}

/// The points of the first 16 radar files that parse, plus a synthetic cloud and an empty one.
fn radar_points(files: &[Vec<u8>]) -> Vec<Vec<RadarPoint>> {
    let mut v: Vec<Vec<RadarPoint>> = files
        .iter()
        .take(16)
        .filter_map(|b| parse_radar_pcd(b, "seed").ok().map(|s| s.points))
        .collect();
    v.push(synthetic_points());
    v.push(Vec::new());
    v
}

/// The radar points re-encoded with LZF, a stream with real back-references, and one
/// uncompressed binary file.
fn pcd_binary_compressed_seeds(fixtures: &Path) -> Vec<Vec<u8>> {
    let mut v: Vec<Vec<u8>> = radar_points(&radar_files(fixtures))
        .iter()
        .map(|pts| encode_radar_pcd_binary_compressed(pts))
        .collect();
    if let Some(real) = back_reference_seed() {
        v.push(real);
    }
    v.push(encode_radar_pcd_binary(&synthetic_points()));
    v
}

/// A stream with real back-references: "ab" then copies.
fn back_reference_seed() -> Option<Vec<u8>> {
    let pts = vec![RadarPoint::default(); 40];
    let mut real = encode_radar_pcd_binary_compressed(&pts);
    let h = real
        .windows(22)
        .position(|w| w == b"DATA binary_compressed")?;
    let body = h + 23;
    let raw_len = 43 * 40;
    let mut comp = vec![0u8, 0u8];
    let mut left = raw_len - 1;
    // one literal zero, then back-references of offset 1
    while left > 0 {
        let l = left.min(264);
        if l < 3 {
            comp.push((l - 1) as u8);
            comp.extend(std::iter::repeat_n(0u8, l));
        } else if l <= 8 {
            comp.push(((l - 2) << 5) as u8);
            comp.push(0);
        } else {
            comp.push(7 << 5);
            comp.push((l - 9) as u8);
            comp.push(0);
        }
        left -= l;
    }
    real.truncate(body);
    real.extend_from_slice(&(comp.len() as u32).to_le_bytes());
    real.extend_from_slice(&(raw_len as u32).to_le_bytes());
    real.extend_from_slice(&comp);
    Some(real)
}

/// Eight 200-point slices of the first kf0 LIDAR_TOP scan, plus a one-point scan with a NaN.
fn pcd_bin_seeds(fixtures: &Path) -> Option<Vec<Vec<u8>>> {
    let p = std::fs::read_dir(fixtures.join("nuscenes-kf0/samples/LIDAR_TOP"))
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.to_string_lossy().ends_with(".pcd.bin"))?;
    let full = std::fs::read(p).ok()?;
    let mut v: Vec<Vec<u8>> = (0..8)
        .map(|k| {
            let a = (k * 4099 * 20) % full.len().max(1);
            let a = a - a % 20;
            full[a..(a + 20 * 200).min(full.len())].to_vec()
        })
        .collect();
    v.push(encode_lidar_pcd_bin(&[[1.0, f32::NAN, 0.0, 0.0, 0.0]]));
    Some(v)
}

/// The kf0 tables of [`TABLES`] as one seed.
fn table_json_seeds(fixtures: &Path) -> Option<Vec<Vec<u8>>> {
    let dir = fixtures.join("nuscenes-kf0/v1.0-mini");
    let mut v = Vec::new();
    for t in TABLES {
        v.push(std::fs::read(dir.join(format!("{t}.json"))).ok()?);
    }
    // one seed = all tables joined by a NUL separator (mutations may hit any table)
    Some(vec![v.join(&b'\0')])
}

/// A host tensor of little-endian bytes.
fn host(dtype: DType, data: Vec<u8>, shape: &[i64]) -> HostTensor<'static> {
    HostTensor {
        dtype,
        shape: shape.to_vec(),
        data: data.into(),
    }
}

/// A float32 host tensor.
fn f32s(values: &[f32], shape: &[i64]) -> HostTensor<'static> {
    host(
        DType::F32,
        values.iter().flat_map(|x| x.to_le_bytes()).collect(),
        shape,
    )
}

/// Two checkpoints from the safetensors writer: three dtypes with metadata, one tensor without.
fn safetensors_seeds() -> Option<Vec<Vec<u8>>> {
    let mut meta = std::collections::BTreeMap::new();
    meta.insert("config".to_string(), "{\"a\": 1}".to_string());
    let tensors = vec![
        (
            "w".to_string(),
            f32s(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], &[2, 3]),
        ),
        (
            "b".to_string(),
            host(
                DType::I64,
                [7i64, 8].iter().flat_map(|x| x.to_le_bytes()).collect(),
                &[2],
            ),
        ),
        (
            "s".to_string(),
            host(DType::F64, 1.5f64.to_le_bytes().to_vec(), &[]),
        ),
    ];
    Some(vec![
        safetensors_bytes(&tensors, &meta),
        safetensors_bytes(&tensors[..1], &Default::default()),
    ])
}

/// Four small depth maps (a third of the pixels without depth), each through both encoders.
fn depth_png_seeds() -> Option<Vec<Vec<u8>>> {
    let mut v = Vec::new();
    for (w, h) in [(7u32, 5u32), (16, 3), (1, 1), (33, 9)] {
        let mut m = DepthMap::zeros(w, h);
        for (i, d) in m.depth_m.iter_mut().enumerate() {
            *d = if i % 3 == 0 { 0.0 } else { i as f32 * 0.77 };
        }
        v.push(encode_png(&m).ok()?);
        v.push(encode_png_fast(&m).ok()?);
    }
    Some(v)
}

fn npy_seeds() -> Vec<Vec<u8>> {
    [(2usize, 3usize), (1, 1), (5, 7)]
        .iter()
        .map(|&(h, w)| {
            let v: Vec<f32> = (0..h * w).map(|i| i as f32 * 0.5 - 1.0).collect();
            depthsense_score::npy::encode_f32(&v, h, w)
        })
        .collect()
}

fn radar_points_bin_seeds() -> Vec<Vec<u8>> {
    let camera = Camera {
        fx: 1266.4,
        fy: 1266.4,
        cx: 816.3,
        cy: 491.5,
        width: 1600,
        height: 900,
    };
    let mut one = RadarPoints::new(camera);
    one.push_sweep(
        "RADAR_FRONT",
        0,
        [0.0, 1.0, -1.5],
        &[[0.0, 0.5, 10.0], [1.0, 0.3, 20.0]],
    );
    let mut two = one.clone();
    two.push_sweep(
        "RADAR_FRONT_LEFT",
        1,
        [-0.5, 1.0, -1.0],
        &[[-3.0, 0.4, 15.0]],
    );
    vec![
        RadarPoints::new(camera).encode(),
        one.encode(),
        two.encode(),
    ]
}

const TABLES: [&str; 7] = [
    "scene",
    "sample",
    "sample_data",
    "calibrated_sensor",
    "ego_pose",
    "sensor",
    "log",
];

fn synthetic_points() -> Vec<RadarPoint> {
    (0..9)
        .map(|i| RadarPoint {
            x: 10.0 + i as f32,
            y: -1.5 * i as f32,
            dyn_prop: (i % 8) as i8,
            id: i as i16,
            rcs: 3.5,
            ambig_state: 3,
            ..Default::default()
        })
        .collect()
}

/// Real `torch.save` files of the model crate's tests plus one written by the project.
fn torch_seeds() -> Vec<Vec<u8>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../checkpoint/tests/data");
    let mut v: Vec<Vec<u8>> = std::fs::read_dir(&dir)
        .map(|rd| {
            let mut p: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
            p.sort();
            p.iter().filter_map(|p| std::fs::read(p).ok()).collect()
        })
        .unwrap_or_default();
    if let Ok(tmp) = std::env::temp_dir().canonicalize() {
        let p = tmp.join(format!("depthsense-fuzz-seed-{}.pth", std::process::id()));
        let t = f32s(&[1.0, 2.0, 3.0, 4.0], &[2, 2]);
        if depthsense_weights::pth_writer::write_torch_state_dict(&p, &[("a.w".into(), t)]).is_ok()
        {
            if let Ok(b) = std::fs::read(&p) {
                v.push(b);
            }
        }
        let _ = std::fs::remove_file(&p);
    }
    v
}

/// The pickle of a `torch.save` file: `data.pkl` of a zip (stored), or the legacy stream.
fn inner_pickle(b: &[u8]) -> Option<Vec<u8>> {
    if b.first() == Some(&0x80) {
        return Some(b.to_vec());
    }
    let at = b.windows(8).position(|w| w == b"data.pkl")? + 8;
    // local header: the name is followed by the extra field, then the data; find the pickle
    // by its protocol opcode and take everything up to and including STOP.
    let start = at + b[at..].iter().position(|&x| x == 0x80)?;
    // The pickle runs up to the next local header "PK\x03\x04".
    let next = b[start..]
        .windows(4)
        .position(|w| w == b"PK\x03\x04")
        .map_or(b.len(), |k| start + k);
    Some(b[start..next].to_vec())
}

/// Outcome of one execution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// The reader accepted the input.
    Accepted,
    /// The reader returned an error.
    Rejected,
}

/// Run `reader` on `input` (may panic: the caller catches).
pub fn execute(reader: Reader, input: &[u8], rng_hint: u64) -> Outcome {
    let ok = match reader {
        Reader::PcdBinary | Reader::PcdAscii | Reader::PcdBinaryCompressed => {
            let a = parse_radar_pcd(input, "fuzz.pcd").is_ok();
            let b = parse_pcd(input, "fuzz.pcd").is_ok();
            a || b
        }
        Reader::PcdBin => parse_lidar_pcd_bin(input, "fuzz.pcd.bin").is_ok(),
        Reader::TableJson => {
            let parts: Vec<&[u8]> = input.split(|&b| b == 0).collect();
            let tables: Vec<(&str, &[u8])> = TABLES
                .iter()
                .zip(parts.iter().chain(std::iter::repeat(&&b"[]"[..])))
                .map(|(n, b)| (*n, *b))
                .collect();
            let chunk = [7usize, 64, 1000, 1 << 20][(rng_hint % 4) as usize];
            match NuScenes::from_memory("v1.0-fuzz", &tables, chunk) {
                Ok(nu) => {
                    // walk what prepare walks
                    for s in &nu.sample {
                        for ch in nu.keyframe_channels(s.token) {
                            if let Some(sd) = nu.keyframe(s.token, ch) {
                                let _ = nu.channel_of(sd);
                                let _ = nu.sweeps_back(sd, 3);
                                let _ = depthsense_nuscenes::geometry::ego_from_sensor(&nu, sd);
                            }
                        }
                    }
                    true
                }
                Err(_) => false,
            }
        }
        Reader::Pth => read_torch_bytes(Path::new("fuzz.pth"), input).is_ok(),
        Reader::Pickle => match parse_pickle(input) {
            Ok(v) => {
                let _ = collect_tensors(&v);
                true
            }
            Err(_) => false,
        },
        Reader::Safetensors => parse_safetensors(Path::new("fuzz.safetensors"), input).is_ok(),
        Reader::DepthPng => decode_png(input, "fuzz.png").is_ok(),
        Reader::Npy => depthsense_score::npy::decode(input, Path::new("fuzz.npy")).is_ok(),
        Reader::RadarPointsBin => {
            RadarPoints::decode(input, Path::new("fuzz/radar_points.bin")).is_ok()
        }
    };
    if ok {
        Outcome::Accepted
    } else {
        Outcome::Rejected
    }
}

/// Settings of a run.
#[derive(Debug, Clone)]
pub struct Config {
    pub readers: Vec<Reader>,
    /// Executions per reader.
    pub execs: u64,
    /// Wall-clock budget per reader (whichever of `execs` and this comes first).
    pub seconds: f64,
    pub seed: u64,
    pub fixtures: PathBuf,
    /// Where crashing and hanging inputs are saved (`None`: not saved).
    pub crash_dir: Option<PathBuf>,
    /// An execution longer than this is a hang.
    pub hang: Duration,
    /// Print progress to stderr every this many seconds (0: never).
    pub progress_s: f64,
}

/// Per-reader result.
#[derive(Debug, Clone, Default)]
pub struct ReaderStats {
    pub reader: &'static str,
    pub skipped: Option<String>,
    pub seeds: usize,
    pub execs: u64,
    pub accepted: u64,
    pub rejected: u64,
    pub crashes: u64,
    pub hangs: u64,
    pub seconds: f64,
    pub slowest_exec_ms: f64,
    pub first_crash: Option<String>,
    pub saved: Vec<String>,
}

impl ReaderStats {
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "reader": self.reader,
            "skipped": self.skipped,
            "seeds": self.seeds,
            "execs": self.execs,
            "accepted": self.accepted,
            "rejected": self.rejected,
            "crashes": self.crashes,
            "hangs": self.hangs,
            "aborts": 0,
            "seconds": self.seconds,
            "execs_per_s": if self.seconds > 0.0 { self.execs as f64 / self.seconds } else { 0.0 },
            "slowest_exec_ms": self.slowest_exec_ms,
            "first_crash": self.first_crash,
            "saved_inputs": self.saved,
        })
    }
}

thread_local! {
    static LAST_PANIC: std::cell::RefCell<Option<String>> = const { std::cell::RefCell::new(None) };
}

/// Install a panic hook that records the message instead of printing it (crashes are
/// reported in the JSON and their inputs saved).
pub fn quiet_panics() {
    std::panic::set_hook(Box::new(|info| {
        let msg = format!("{info}");
        LAST_PANIC.with(|p| *p.borrow_mut() = Some(msg));
    }));
}

/// Fuzz one reader.
pub fn fuzz_reader(reader: Reader, cfg: &Config) -> ReaderStats {
    let mut st = ReaderStats {
        reader: reader.name(),
        ..Default::default()
    };
    let seeds = match reader_seeds(reader, cfg) {
        Ok(seeds) => seeds,
        Err(why) => {
            st.skipped = Some(why);
            return st;
        }
    };
    st.seeds = seeds.len();
    let mut rng = Rng::new(cfg.seed ^ (reader as u64).wrapping_mul(0x1234_5678_9abc_def1));
    let t0 = Instant::now();
    let mut last_progress = t0;
    let mut input = Vec::new();
    while st.execs < cfg.execs {
        if st.execs.is_multiple_of(64) && t0.elapsed().as_secs_f64() >= cfg.seconds {
            break;
        }
        input.clear();
        input.extend_from_slice(&seeds[rng.below(seeds.len())]);
        // 1 in 64 executions runs an unmutated seed (keeps the happy path exercised)
        if !rng.chance(64) {
            mutate(&mut input, &seeds, reader.is_text(), &mut rng);
        }
        let hint = rng.next_u64();
        let t = Instant::now();
        let r = std::panic::catch_unwind(AssertUnwindSafe(|| execute(reader, &input, hint)));
        let dt = t.elapsed();
        if let (Some(kind), Some(dir)) = (st.record(r.ok(), dt, cfg.hang), &cfg.crash_dir) {
            st.save_input(dir, kind, &input);
        }
        if cfg.progress_s > 0.0 && last_progress.elapsed().as_secs_f64() >= cfg.progress_s {
            last_progress = Instant::now();
            st.print_progress(t0);
        }
    }
    st.seconds = t0.elapsed().as_secs_f64();
    st
}

/// The seeds of `reader`, or why it is skipped (fixtures absent, no seeds).
fn reader_seeds(reader: Reader, cfg: &Config) -> Result<Vec<Vec<u8>>, String> {
    let Some(seeds) = seeds(reader, &cfg.fixtures) else {
        return Err(format!(
            "fixtures absent at {} (needed for its seeds)",
            cfg.fixtures.display()
        ));
    };
    if seeds.is_empty() {
        return Err("no seeds".into());
    }
    Ok(seeds)
}

impl ReaderStats {
    /// Count one execution that took `dt` (`outcome`: `None` when it panicked); the kind
    /// of a bad input ("crash" or "hang", a hang winning), `None` for a good one.
    fn record(
        &mut self,
        outcome: Option<Outcome>,
        dt: Duration,
        hang: Duration,
    ) -> Option<&'static str> {
        self.execs += 1;
        self.slowest_exec_ms = self.slowest_exec_ms.max(dt.as_secs_f64() * 1e3);
        let mut bad = None;
        match outcome {
            Some(Outcome::Accepted) => self.accepted += 1,
            Some(Outcome::Rejected) => self.rejected += 1,
            None => {
                self.crashes += 1;
                let msg = LAST_PANIC
                    .with(|p| p.borrow_mut().take())
                    .unwrap_or_else(|| "panic".into());
                if self.first_crash.is_none() {
                    self.first_crash = Some(msg);
                }
                bad = Some("crash");
            }
        }
        if dt > hang {
            self.hangs += 1;
            bad = Some("hang");
        }
        bad
    }

    /// Save a bad input under `dir` as `<reader>-<kind>-<fnv>.bin` (at most 100 per reader).
    fn save_input(&mut self, dir: &Path, kind: &str, input: &[u8]) {
        if self.saved.len() < 100 {
            let _ = std::fs::create_dir_all(dir);
            let p = dir.join(format!("{}-{kind}-{:016x}.bin", self.reader, fnv(input)));
            if std::fs::write(&p, input).is_ok() {
                self.saved.push(p.display().to_string());
            }
        }
    }

    /// The progress line on stderr: executions, their rate since `t0`, crashes, hangs.
    fn print_progress(&self, t0: Instant) {
        let s = t0.elapsed().as_secs_f64();
        eprintln!(
            "{}: {} execs ({:.0}/s), {} crashes, {} hangs",
            self.reader,
            self.execs,
            self.execs as f64 / s,
            self.crashes,
            self.hangs
        );
        let _ = std::io::stderr().flush();
    }
}

fn fnv(b: &[u8]) -> u64 {
    depthsense_base::hash::fnv1a64(b)
}

/// Fuzz every reader of `cfg`; the JSON report.
pub fn run(cfg: &Config) -> (Vec<ReaderStats>, serde_json::Value) {
    quiet_panics();
    // Every reader runs on one rayon worker thread: the loaders' parallel paths (the chunked
    // table parser splits rows with rayon) then execute inline — the same code, without a
    // cross-thread hand-off per execution, which made table-json 170 exec/s on 2 busy cores —
    // and a panic's message is recorded on the thread that caught it.
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .thread_name(|_| "fuzz".into())
        .stack_size(8 << 20)
        .build();
    let stats: Vec<ReaderStats> = cfg
        .readers
        .iter()
        .map(|&r| match &one_thread {
            Ok(pool) => pool.install(|| fuzz_reader(r, cfg)),
            Err(_) => fuzz_reader(r, cfg),
        })
        .collect();
    let report = serde_json::json!({
        "seed": cfg.seed,
        "hang_ms": cfg.hang.as_millis() as u64,
        "execs_per_reader_limit": cfg.execs,
        "seconds_per_reader_limit": cfg.seconds,
        "machine": format!("{} logical cores", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)),
        "total_crashes": stats.iter().map(|s| s.crashes).sum::<u64>(),
        "total_hangs": stats.iter().map(|s| s.hangs).sum::<u64>(),
        "readers": stats.iter().map(ReaderStats::to_json).collect::<Vec<_>>(),
    });
    (stats, report)
}

/// Default location of the shared fixtures (`../shared/fixtures` from the workspace).
pub fn default_fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/fixtures")
}
