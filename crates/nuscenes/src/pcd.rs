//! Point-cloud files (SPEC §2): LIDAR_TOP `.pcd.bin` (float32 × 5 records) and radar `.pcd`
//! (PCD v0.7 with `DATA binary`, `ascii` or `binary_compressed`).
//!
//! The nuScenes radar layout has 18 packed fields, 43 bytes per point, and real files are
//! zero-padded after the points: the header's point count is authoritative, never the body
//! length.

use std::path::Path;

use crate::error::{NuError, Result};

/// One radar return with all 18 fields of the nuScenes radar PCD layout.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RadarPoint {
    pub x: f32,
    pub y: f32,
    pub z: f32,
    pub dyn_prop: i8,
    pub id: i16,
    pub rcs: f32,
    pub vx: f32,
    pub vy: f32,
    pub vx_comp: f32,
    pub vy_comp: f32,
    pub is_quality_valid: i8,
    pub ambig_state: i8,
    pub x_rms: i8,
    pub y_rms: i8,
    pub invalid_state: i8,
    pub pdh0: i8,
    pub vx_rms: i8,
    pub vy_rms: i8,
}

/// Field names of the nuScenes radar layout, in file order.
pub const RADAR_FIELD_NAMES: [&str; 18] = [
    "x",
    "y",
    "z",
    "dyn_prop",
    "id",
    "rcs",
    "vx",
    "vy",
    "vx_comp",
    "vy_comp",
    "is_quality_valid",
    "ambig_state",
    "x_rms",
    "y_rms",
    "invalid_state",
    "pdh0",
    "vx_rms",
    "vy_rms",
];
/// Byte sizes of the radar fields.
pub const RADAR_FIELD_SIZES: [usize; 18] = [4, 4, 4, 1, 2, 4, 4, 4, 4, 4, 1, 1, 1, 1, 1, 1, 1, 1];
/// PCD TYPE letters of the radar fields.
pub const RADAR_FIELD_TYPES: [char; 18] = [
    'F', 'F', 'F', 'I', 'I', 'F', 'F', 'F', 'F', 'F', 'I', 'I', 'I', 'I', 'I', 'I', 'I', 'I',
];
/// Bytes per radar point in the nuScenes layout.
pub const RADAR_POINT_BYTES: usize = 43;

impl RadarPoint {
    /// Value of field `i` (in [`RADAR_FIELD_NAMES`] order) as f64.
    pub fn field(&self, i: usize) -> f64 {
        match i {
            0 => self.x as f64,
            1 => self.y as f64,
            2 => self.z as f64,
            3 => self.dyn_prop as f64,
            4 => self.id as f64,
            5 => self.rcs as f64,
            6 => self.vx as f64,
            7 => self.vy as f64,
            8 => self.vx_comp as f64,
            9 => self.vy_comp as f64,
            10 => self.is_quality_valid as f64,
            11 => self.ambig_state as f64,
            12 => self.x_rms as f64,
            13 => self.y_rms as f64,
            14 => self.invalid_state as f64,
            15 => self.pdh0 as f64,
            16 => self.vx_rms as f64,
            _ => self.vy_rms as f64,
        }
    }

    fn from_fields(v: &[f64; 18]) -> RadarPoint {
        RadarPoint {
            x: v[0] as f32,
            y: v[1] as f32,
            z: v[2] as f32,
            dyn_prop: v[3] as i8,
            id: v[4] as i16,
            rcs: v[5] as f32,
            vx: v[6] as f32,
            vy: v[7] as f32,
            vx_comp: v[8] as f32,
            vy_comp: v[9] as f32,
            is_quality_valid: v[10] as i8,
            ambig_state: v[11] as i8,
            x_rms: v[12] as i8,
            y_rms: v[13] as i8,
            invalid_state: v[14] as i8,
            pdh0: v[15] as i8,
            vx_rms: v[16] as i8,
            vy_rms: v[17] as i8,
        }
    }

    /// The devkit's default radar filters (SPEC §2): `invalid_state == 0`,
    /// `dyn_prop` in 0..=6, `ambig_state == 3`.
    pub fn passes_default_filters(&self) -> bool {
        self.invalid_state == 0 && (0..=6).contains(&self.dyn_prop) && self.ambig_state == 3
    }
}

/// Encode radar points as a nuScenes-style PCD v0.7 `binary` file: the exact header of the
/// real files, 43 packed little-endian bytes per point, then zero padding so that the file is
/// 4096 + 43·N bytes long like the originals.
pub fn encode_radar_pcd_binary(points: &[RadarPoint]) -> Vec<u8> {
    let n = points.len();
    let header = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {}\nSIZE 4 4 4 1 2 4 4 4 4 4 1 1 1 1 1 1 1 1\nTYPE F F F I I F F F F F I I I I I I I I\nCOUNT 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n",
        RADAR_FIELD_NAMES.join(" ")
    );
    let mut out = Vec::with_capacity(4096 + RADAR_POINT_BYTES * n);
    out.extend_from_slice(header.as_bytes());
    for p in points {
        out.extend_from_slice(&p.x.to_le_bytes());
        out.extend_from_slice(&p.y.to_le_bytes());
        out.extend_from_slice(&p.z.to_le_bytes());
        out.extend_from_slice(&p.dyn_prop.to_le_bytes());
        out.extend_from_slice(&p.id.to_le_bytes());
        out.extend_from_slice(&p.rcs.to_le_bytes());
        out.extend_from_slice(&p.vx.to_le_bytes());
        out.extend_from_slice(&p.vy.to_le_bytes());
        out.extend_from_slice(&p.vx_comp.to_le_bytes());
        out.extend_from_slice(&p.vy_comp.to_le_bytes());
        for b in [
            p.is_quality_valid,
            p.ambig_state,
            p.x_rms,
            p.y_rms,
            p.invalid_state,
            p.pdh0,
            p.vx_rms,
            p.vy_rms,
        ] {
            out.extend_from_slice(&b.to_le_bytes());
        }
    }
    let want = 4096 + RADAR_POINT_BYTES * n;
    if out.len() < want {
        out.resize(want, 0);
    }
    out
}

/// Encode lidar points as a nuScenes `.pcd.bin` (x, y, z, intensity, ring as f32 LE).
pub fn encode_lidar_pcd_bin(points: &[[f32; 5]]) -> Vec<u8> {
    bytemuck::cast_slice::<[f32; 5], u8>(points).to_vec()
}

/// Lidar points read from a `.pcd.bin`, with non-finite points dropped and counted.
#[derive(Debug, Clone, Default)]
pub struct LidarScan {
    /// (x, y, z, intensity, ring) per point, sensor frame.
    pub points: Vec<[f32; 5]>,
    /// Points dropped because a coordinate was NaN or infinite.
    pub nan_dropped: usize,
}

/// Parse a LIDAR_TOP `.pcd.bin` (SPEC §2). `name` is used in errors.
pub fn parse_lidar_pcd_bin(bytes: &[u8], name: &str) -> Result<LidarScan> {
    if !bytes.len().is_multiple_of(20) {
        return Err(NuError::Pcd {
            path: name.into(),
            reason: format!(
                "length {} is not a multiple of 20 bytes (5 float32 per point): truncated file?",
                bytes.len()
            ),
        });
    }
    let n = bytes.len() / 20;
    let mut points = Vec::with_capacity(n);
    let mut nan_dropped = 0;
    for rec in bytes.chunks_exact(20) {
        let mut p = [0f32; 5];
        for (k, v) in p.iter_mut().enumerate() {
            let o = 4 * k;
            *v = f32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
        }
        if p[0].is_finite() && p[1].is_finite() && p[2].is_finite() {
            points.push(p);
        } else {
            nan_dropped += 1;
        }
    }
    Ok(LidarScan {
        points,
        nan_dropped,
    })
}

/// Read a LIDAR_TOP `.pcd.bin` file.
pub fn read_lidar_pcd_bin(path: &Path) -> Result<LidarScan> {
    let bytes = std::fs::read(path).map_err(|e| NuError::io(path, e))?;
    parse_lidar_pcd_bin(&bytes, &path.display().to_string())
}

/// PCD data encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PcdData {
    Ascii,
    Binary,
    BinaryCompressed,
}

/// One field of a PCD header.
#[derive(Debug, Clone, PartialEq)]
pub struct PcdField {
    pub name: String,
    pub size: usize,
    /// 'F', 'I' or 'U'.
    pub ty: char,
    pub count: usize,
}

/// A parsed PCD header.
#[derive(Debug, Clone, PartialEq)]
pub struct PcdHeader {
    pub fields: Vec<PcdField>,
    pub width: usize,
    pub height: usize,
    pub points: usize,
    pub data: PcdData,
    /// Byte offset of the data section.
    pub data_offset: usize,
}

impl PcdHeader {
    /// Bytes per point (sum of size × count). [`parse_pcd_header`] guarantees that this
    /// neither overflows nor exceeds [`MAX_PCD_POINT_BYTES`]; on a hand-built header the sum
    /// saturates.
    pub fn point_bytes(&self) -> usize {
        self.fields.iter().fold(0usize, |acc, f| {
            acc.saturating_add(f.size.saturating_mul(f.count))
        })
    }

    /// Number of value columns (sum of COUNT).
    pub fn columns(&self) -> usize {
        self.fields
            .iter()
            .fold(0usize, |acc, f| acc.saturating_add(f.count))
    }
}

/// Largest point record a PCD header may declare (bytes per point, and value columns).
/// Real files have a few dozen bytes; the bound keeps a hostile `COUNT` from driving
/// allocations or loops before any data is checked.
pub const MAX_PCD_POINT_BYTES: usize = 1 << 16;

/// A generic point cloud: one f64 column per (field, count element).
#[derive(Debug, Clone)]
pub struct PcdCloud {
    pub header: PcdHeader,
    /// Column names (`name`, or `name_i` for COUNT > 1).
    pub names: Vec<String>,
    /// Column-major values, `columns[c][point]`.
    pub columns: Vec<Vec<f64>>,
}

fn pcd_err(name: &str, reason: impl Into<String>) -> NuError {
    NuError::Pcd {
        path: name.into(),
        reason: reason.into(),
    }
}

/// Parse the PCD header (up to and including the `DATA` line).
pub fn parse_pcd_header(bytes: &[u8], name: &str) -> Result<PcdHeader> {
    let (raw, data_offset) = RawPcdHeader::read(bytes, name)?;
    let fields = raw.checked_fields(name)?;
    check_point_bytes(&fields, name)?;
    let (width, height, points) = raw.checked_dimensions(name)?;
    Ok(PcdHeader {
        fields,
        width,
        height,
        points,
        data: raw.data.unwrap_or(PcdData::Binary),
        data_offset,
    })
}

/// The header's values as written, before they are checked against each other.
#[derive(Default)]
struct RawPcdHeader {
    fields: Vec<String>,
    sizes: Vec<usize>,
    types: Vec<char>,
    counts: Vec<usize>,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
    data: Option<PcdData>,
}

/// A header value that must be an unsigned integer.
#[inline]
fn parse_header_usize(s: &str, what: &str, name: &str) -> Result<usize> {
    s.parse::<usize>()
        .map_err(|_| pcd_err(name, format!("bad {what} value {s:?} in header")))
}

impl RawPcdHeader {
    /// Read header lines up to and including `DATA`; also returns the data section's offset.
    fn read(bytes: &[u8], name: &str) -> Result<(RawPcdHeader, usize)> {
        let mut raw = RawPcdHeader::default();
        let mut pos = 0usize;
        while raw.data.is_none() {
            if pos >= bytes.len() {
                return Err(pcd_err(name, "header ends before a DATA line"));
            }
            let end = bytes[pos..]
                .iter()
                .position(|&b| b == b'\n')
                .map(|i| pos + i)
                .unwrap_or(bytes.len());
            let line = std::str::from_utf8(&bytes[pos..end])
                .map_err(|_| pcd_err(name, "header is not text: not a PCD file?"))?
                .trim();
            pos = (end + 1).min(bytes.len());
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            raw.apply_line(line, name)?;
        }
        Ok((raw, pos))
    }

    /// Record one non-comment header line (`KEY values...`).
    fn apply_line(&mut self, line: &str, name: &str) -> Result<()> {
        let mut it = line.split_whitespace();
        let key = it.next().unwrap_or("");
        let rest: Vec<&str> = it.collect();
        let first = || rest.first().copied().unwrap_or("");
        match key {
            "VERSION" | "VIEWPOINT" => {}
            "FIELDS" => self.fields = rest.iter().map(|s| s.to_string()).collect(),
            "SIZE" => {
                self.sizes = rest
                    .iter()
                    .map(|s| parse_header_usize(s, "SIZE", name))
                    .collect::<Result<_>>()?
            }
            "TYPE" => {
                self.types = rest
                    .iter()
                    .map(|s| parse_pcd_type(s, name))
                    .collect::<Result<_>>()?
            }
            "COUNT" => {
                self.counts = rest
                    .iter()
                    .map(|s| parse_header_usize(s, "COUNT", name))
                    .collect::<Result<_>>()?
            }
            "WIDTH" => self.width = Some(parse_header_usize(first(), "WIDTH", name)?),
            "HEIGHT" => self.height = Some(parse_header_usize(first(), "HEIGHT", name)?),
            "POINTS" => self.points = Some(parse_header_usize(first(), "POINTS", name)?),
            "DATA" => {
                self.data = Some(match rest.first().copied() {
                    Some("ascii") => PcdData::Ascii,
                    Some("binary") => PcdData::Binary,
                    Some("binary_compressed") => PcdData::BinaryCompressed,
                    other => return Err(pcd_err(name, format!("unknown PCD DATA kind {other:?}"))),
                })
            }
            other => {
                return Err(pcd_err(
                    name,
                    format!("unknown PCD header line {other:?}: not a PCD v0.7 file?"),
                ))
            }
        }
        Ok(())
    }

    /// FIELDS, SIZE, TYPE and COUNT zipped into fields, each a supported type and size.
    fn checked_fields(&self, name: &str) -> Result<Vec<PcdField>> {
        let fields = &self.fields;
        if fields.is_empty() {
            return Err(pcd_err(name, "header has no FIELDS"));
        }
        let ones;
        let counts = if self.counts.is_empty() {
            ones = vec![1; fields.len()];
            &ones
        } else {
            &self.counts
        };
        let (sizes, types) = (&self.sizes, &self.types);
        if sizes.len() != fields.len()
            || types.len() != fields.len()
            || counts.len() != fields.len()
        {
            return Err(pcd_err(
                name,
                format!(
                    "unknown PCD field layout: {} FIELDS but {} SIZE, {} TYPE, {} COUNT entries",
                    fields.len(),
                    sizes.len(),
                    types.len(),
                    counts.len()
                ),
            ));
        }
        let mut out_fields = Vec::with_capacity(fields.len());
        for i in 0..fields.len() {
            let ok = match types[i] {
                'F' => matches!(sizes[i], 4 | 8),
                _ => matches!(sizes[i], 1 | 2 | 4 | 8),
            };
            if !ok || counts[i] == 0 {
                return Err(pcd_err(
                    name,
                    format!(
                        "unknown PCD field layout: field {:?} has TYPE {} SIZE {} COUNT {}",
                        fields[i], types[i], sizes[i], counts[i]
                    ),
                ));
            }
            out_fields.push(PcdField {
                name: fields[i].clone(),
                size: sizes[i],
                ty: types[i],
                count: counts[i],
            });
        }
        Ok(out_fields)
    }

    /// WIDTH, HEIGHT (default 1) and POINTS (default WIDTH×HEIGHT), which must agree.
    fn checked_dimensions(&self, name: &str) -> Result<(usize, usize, usize)> {
        let width = self
            .width
            .ok_or_else(|| pcd_err(name, "header has no WIDTH"))?;
        let height = self.height.unwrap_or(1);
        let wh = width.checked_mul(height).ok_or_else(|| {
            pcd_err(
                name,
                format!("header WIDTH×HEIGHT {width}×{height} overflows"),
            )
        })?;
        let points = self.points.unwrap_or(wh);
        if points != wh {
            return Err(pcd_err(
                name,
                format!("header POINTS {points} disagrees with WIDTH×HEIGHT {width}×{height}"),
            ));
        }
        Ok((width, height, points))
    }
}

/// One TYPE entry: a single letter F, I or U.
#[inline]
fn parse_pcd_type(s: &str, name: &str) -> Result<char> {
    let c = s.chars().next().unwrap_or('?');
    if s.len() == 1 && matches!(c, 'F' | 'I' | 'U') {
        Ok(c)
    } else {
        Err(pcd_err(name, format!("unknown PCD TYPE {s:?}")))
    }
}

/// Bytes per point must neither overflow nor exceed [`MAX_PCD_POINT_BYTES`].
fn check_point_bytes(fields: &[PcdField], name: &str) -> Result<()> {
    let mut point_bytes = 0usize;
    for f in fields {
        point_bytes = f
            .size
            .checked_mul(f.count)
            .and_then(|b| point_bytes.checked_add(b))
            .filter(|&b| b <= MAX_PCD_POINT_BYTES)
            .ok_or_else(|| {
                pcd_err(
                    name,
                    format!(
                        "unknown PCD field layout: points of more than {MAX_PCD_POINT_BYTES} bytes (field {:?} SIZE {} COUNT {})",
                        f.name, f.size, f.count
                    ),
                )
            })?;
    }
    Ok(())
}

fn read_scalar(b: &[u8], ty: char, size: usize) -> f64 {
    match (ty, size) {
        ('F', 4) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        ('F', _) => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        ('I', 1) => b[0] as i8 as f64,
        ('I', 2) => i16::from_le_bytes([b[0], b[1]]) as f64,
        ('I', 4) => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        ('I', _) => i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f64,
        (_, 1) => b[0] as f64,
        (_, 2) => u16::from_le_bytes([b[0], b[1]]) as f64,
        (_, 4) => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f64,
    }
}

/// Largest output/input ratio of LZF (a 3-byte back-reference of 264 bytes).
const LZF_MAX_EXPANSION: usize = 88;

/// LZF decompression (the codec of PCD `binary_compressed`). Corrupt input is an error,
/// never a panic; memory is bounded by the input length, whatever `out_len` claims.
pub fn lzf_decompress(input: &[u8], out_len: usize) -> std::result::Result<Vec<u8>, String> {
    lzf_check_expansion(input.len(), out_len)?;
    let mut out = Vec::with_capacity(out_len);
    let mut i = 0;
    while i < input.len() {
        let ctrl = input[i] as usize;
        i += 1;
        if ctrl < 32 {
            let len = ctrl + 1;
            if i + len > input.len() {
                return Err("LZF literal run past the end of the input".into());
            }
            if out.len() + len > out_len {
                return Err(lzf_overrun(out_len));
            }
            out.extend_from_slice(&input[i..i + len]);
            i += len;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                if i >= input.len() {
                    return Err("LZF back-reference truncated".into());
                }
                len += input[i] as usize;
                i += 1;
            }
            len += 2;
            if i >= input.len() {
                return Err("LZF back-reference truncated".into());
            }
            let back = ((ctrl & 0x1f) << 8) + input[i] as usize + 1;
            i += 1;
            if back > out.len() {
                return Err("LZF back-reference before the start of the output".into());
            }
            if out.len() + len > out_len {
                return Err(lzf_overrun(out_len));
            }
            let start = out.len() - back;
            for k in 0..len {
                let b = out[start + k];
                out.push(b);
            }
        }
        if out.len() > out_len {
            return Err(lzf_overrun(out_len));
        }
    }
    if out.len() != out_len {
        return Err(format!(
            "LZF output has {} bytes, header promises {out_len}",
            out.len()
        ));
    }
    Ok(out)
}

/// One 3-byte back-reference yields at most 264 bytes: anything claiming more than that
/// expansion is corrupt, and is refused before allocating `out_len` bytes.
fn lzf_check_expansion(input_len: usize, out_len: usize) -> std::result::Result<(), String> {
    let max_out = input_len.saturating_mul(LZF_MAX_EXPANSION);
    if out_len > max_out {
        return Err(format!(
            "LZF header promises {out_len} bytes from {input_len} compressed bytes (at most {max_out} possible)"
        ));
    }
    Ok(())
}

/// The error of an LZF stream that outgrows its promised size.
#[cold]
fn lzf_overrun(out_len: usize) -> String {
    format!("LZF output longer than the {out_len} bytes the header promises")
}

/// Parse any PCD v0.7 file (ascii, binary, binary_compressed) into f64 columns.
pub fn parse_pcd(bytes: &[u8], name: &str) -> Result<PcdCloud> {
    let header = parse_pcd_header(bytes, name)?;
    let n = header.points;
    let (names, col_spec) = column_layout(&header);
    let body = bytes.get(header.data_offset..).unwrap_or(&[]);
    check_plausible_points(&header, body, names.len(), name)?;
    let mut columns: Vec<Vec<f64>> = (0..names.len()).map(|_| Vec::with_capacity(n)).collect();
    match header.data {
        PcdData::Binary => read_binary_columns(&header, body, &col_spec, &mut columns, name)?,
        PcdData::BinaryCompressed => read_compressed_columns(&header, body, &mut columns, name)?,
        PcdData::Ascii => read_ascii_columns(n, body, &mut columns, name)?,
    }
    Ok(PcdCloud {
        header,
        names,
        columns,
    })
}

/// Where one value column lives in a binary point record.
#[derive(Clone, Copy)]
struct ColumnSpec {
    ty: char,
    size: usize,
    /// Byte offset within the point.
    offset: usize,
}

/// Column names (`name`, or `name_i` for COUNT > 1) and their places in a binary record.
fn column_layout(header: &PcdHeader) -> (Vec<String>, Vec<ColumnSpec>) {
    let mut names = Vec::new();
    let mut col_spec = Vec::new();
    let mut off = 0;
    for f in &header.fields {
        for c in 0..f.count {
            names.push(if f.count == 1 {
                f.name.clone()
            } else {
                format!("{}_{c}", f.name)
            });
            col_spec.push(ColumnSpec {
                ty: f.ty,
                size: f.size,
                offset: off,
            });
            off += f.size;
        }
    }
    (names, col_spec)
}

/// The header's point count is checked against the data before any allocation depends on
/// it (issue 10): at most one point per byte of data (per value in ascii).
fn check_plausible_points(
    header: &PcdHeader,
    body: &[u8],
    n_columns: usize,
    name: &str,
) -> Result<()> {
    let n = header.points;
    let pb = header.point_bytes();
    let plausible = match header.data {
        PcdData::Ascii => body.len() / (2 * n_columns.max(1)) + 1,
        PcdData::Binary => body.len() / pb.max(1),
        PcdData::BinaryCompressed => body.len().saturating_mul(LZF_MAX_EXPANSION) / pb.max(1),
    };
    if n > plausible {
        return Err(pcd_err(
            name,
            format!(
                "truncated: header promises {n} points of {pb} bytes, the {} bytes of {:?} data cannot hold more than {plausible}",
                body.len(),
                header.data
            ),
        ));
    }
    Ok(())
}

/// `DATA binary`: packed point records, one after the other.
fn read_binary_columns(
    header: &PcdHeader,
    body: &[u8],
    col_spec: &[ColumnSpec],
    columns: &mut [Vec<f64>],
    name: &str,
) -> Result<()> {
    let n = header.points;
    let pb = header.point_bytes();
    let need = n.saturating_mul(pb);
    if body.len() < need {
        return Err(pcd_err(
            name,
            format!(
                "truncated: header promises {n} points × {pb} bytes of data, file has {} bytes",
                body.len()
            ),
        ));
    }
    for p in 0..n {
        let rec = &body[p * pb..(p + 1) * pb];
        for (c, s) in col_spec.iter().enumerate() {
            let o = s.offset;
            columns[c].push(read_scalar(&rec[o..o + s.size], s.ty, s.size));
        }
    }
    Ok(())
}

/// `DATA binary_compressed`: two u32 sizes, then LZF of the fields in structure-of-arrays.
fn read_compressed_columns(
    header: &PcdHeader,
    body: &[u8],
    columns: &mut [Vec<f64>],
    name: &str,
) -> Result<()> {
    let n = header.points;
    let pb = header.point_bytes();
    if body.len() < 8 {
        return Err(pcd_err(name, "truncated: binary_compressed sizes missing"));
    }
    let csize = u32::from_le_bytes([body[0], body[1], body[2], body[3]]) as usize;
    let usize_ = u32::from_le_bytes([body[4], body[5], body[6], body[7]]) as usize;
    if Some(usize_) != n.checked_mul(pb) {
        return Err(pcd_err(
            name,
            format!("binary_compressed: uncompressed size {usize_} ≠ {n} points × {pb} bytes"),
        ));
    }
    if body.len() - 8 < csize {
        return Err(pcd_err(
            name,
            format!(
                "truncated: compressed data of {csize} bytes promised, {} present",
                body.len() - 8
            ),
        ));
    }
    let raw = lzf_decompress(&body[8..8 + csize], usize_)
        .map_err(|e| pcd_err(name, format!("binary_compressed: {e}")))?;
    // Structure-of-arrays: every field's values for all points, field after field.
    let mut field_base = 0;
    let mut c = 0;
    for f in &header.fields {
        for k in 0..f.count {
            for p in 0..n {
                let o = field_base + (p * f.count + k) * f.size;
                columns[c].push(read_scalar(&raw[o..o + f.size], f.ty, f.size));
            }
            c += 1;
        }
        field_base += n * f.size * f.count;
    }
    Ok(())
}

/// `DATA ascii`: one line of whitespace-separated values per point (blank lines skipped).
fn read_ascii_columns(n: usize, body: &[u8], columns: &mut [Vec<f64>], name: &str) -> Result<()> {
    let text =
        std::str::from_utf8(body).map_err(|_| pcd_err(name, "ascii data is not valid text"))?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    for p in 0..n {
        let line = lines.next().ok_or_else(|| {
            pcd_err(
                name,
                format!("truncated: header promises {n} points, ascii data has {p}"),
            )
        })?;
        let vals: Vec<&str> = line.split_whitespace().collect();
        if vals.len() != columns.len() {
            return Err(pcd_err(
                name,
                format!(
                    "ascii point {p} has {} values, header needs {}",
                    vals.len(),
                    columns.len()
                ),
            ));
        }
        for (c, v) in vals.iter().enumerate() {
            let x: f64 = match v.to_ascii_lowercase().as_str() {
                "nan" => f64::NAN,
                s => s
                    .parse()
                    .map_err(|_| pcd_err(name, format!("ascii point {p}: bad number {v:?}")))?,
            };
            columns[c].push(x);
        }
    }
    Ok(())
}

/// Radar points read from a `.pcd`, with non-finite points dropped and counted.
#[derive(Debug, Clone, Default)]
pub struct RadarScan {
    /// All points with finite coordinates (filters not applied).
    pub points: Vec<RadarPoint>,
    /// Points dropped because x, y or z was NaN or infinite.
    pub nan_dropped: usize,
}

impl RadarScan {
    /// Points passing the devkit's default filters (SPEC §2), or all points when `filters`
    /// is false; the second value is how many were filtered out.
    pub fn filtered(&self, filters: bool) -> (Vec<RadarPoint>, usize) {
        if !filters {
            return (self.points.clone(), 0);
        }
        let kept: Vec<RadarPoint> = self
            .points
            .iter()
            .copied()
            .filter(|p| p.passes_default_filters())
            .collect();
        let out = self.points.len() - kept.len();
        (kept, out)
    }
}

/// Parse a radar `.pcd` into [`RadarPoint`]s. The file must carry the 18 nuScenes radar
/// fields (any order, any supported DATA kind); anything else is an "unknown PCD field
/// layout" error naming the file.
pub fn parse_radar_pcd(bytes: &[u8], name: &str) -> Result<RadarScan> {
    let header = parse_pcd_header(bytes, name)?;
    // Fast path: the exact nuScenes binary layout.
    if is_nuscenes_radar_layout(&header) {
        return parse_radar_binary(bytes, &header, name);
    }
    radar_from_cloud(&parse_pcd(bytes, name)?, name)
}

/// Whether the header is exactly the nuScenes radar layout with `DATA binary`.
fn is_nuscenes_radar_layout(header: &PcdHeader) -> bool {
    header.data == PcdData::Binary
        && header.fields.len() == 18
        && header.fields.iter().enumerate().all(|(i, f)| {
            f.name == RADAR_FIELD_NAMES[i]
                && f.size == RADAR_FIELD_SIZES[i]
                && f.ty == RADAR_FIELD_TYPES[i]
                && f.count == 1
        })
}

/// The fast path: 43-byte nuScenes records read straight into [`RadarPoint`]s.
fn parse_radar_binary(bytes: &[u8], header: &PcdHeader, name: &str) -> Result<RadarScan> {
    let mut scan = RadarScan::default();
    let n = header.points;
    let body = bytes.get(header.data_offset..).unwrap_or(&[]);
    let need = n.saturating_mul(RADAR_POINT_BYTES);
    if body.len() < need {
        return Err(pcd_err(
            name,
            format!(
                "truncated: header promises {n} points × 43 bytes of data, file has {} bytes",
                body.len()
            ),
        ));
    }
    scan.points.reserve(n);
    for rec in body[..need].chunks_exact(RADAR_POINT_BYTES) {
        let p = radar_point_from_record(rec);
        if p.x.is_finite() && p.y.is_finite() && p.z.is_finite() {
            scan.points.push(p);
        } else {
            scan.nan_dropped += 1;
        }
    }
    Ok(scan)
}

/// Decode one packed little-endian record of the nuScenes radar layout (43 bytes).
#[inline]
fn radar_point_from_record(rec: &[u8]) -> RadarPoint {
    let f = |o: usize| f32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
    RadarPoint {
        x: f(0),
        y: f(4),
        z: f(8),
        dyn_prop: rec[12] as i8,
        id: i16::from_le_bytes([rec[13], rec[14]]),
        rcs: f(15),
        vx: f(19),
        vy: f(23),
        vx_comp: f(27),
        vy_comp: f(31),
        is_quality_valid: rec[35] as i8,
        ambig_state: rec[36] as i8,
        x_rms: rec[37] as i8,
        y_rms: rec[38] as i8,
        invalid_state: rec[39] as i8,
        pdh0: rec[40] as i8,
        vx_rms: rec[41] as i8,
        vy_rms: rec[42] as i8,
    }
}

/// The general path: the 18 radar fields looked up by name in a generic cloud.
fn radar_from_cloud(cloud: &PcdCloud, name: &str) -> Result<RadarScan> {
    let mut scan = RadarScan::default();
    let mut idx = [0usize; 18];
    for (k, want) in RADAR_FIELD_NAMES.iter().enumerate() {
        idx[k] = cloud.names.iter().position(|n| n == want).ok_or_else(|| {
            pcd_err(
                name,
                format!(
                    "unknown PCD field layout: radar field {want:?} missing (fields: {})",
                    cloud.names.join(" ")
                ),
            )
        })?;
    }
    for p in 0..cloud.header.points {
        let mut v = [0f64; 18];
        for k in 0..18 {
            v[k] = cloud.columns[idx[k]][p];
        }
        if v[0].is_finite() && v[1].is_finite() && v[2].is_finite() {
            scan.points.push(RadarPoint::from_fields(&v));
        } else {
            scan.nan_dropped += 1;
        }
    }
    Ok(scan)
}

/// Read a radar `.pcd` file.
pub fn read_radar_pcd(path: &Path) -> Result<RadarScan> {
    let bytes = std::fs::read(path).map_err(|e| NuError::io(path, e))?;
    parse_radar_pcd(&bytes, &path.display().to_string())
}

/// Encode a generic cloud as PCD `ascii` (used by tests and tools).
pub fn encode_pcd_ascii(fields: &[PcdField], rows: &[Vec<f64>]) -> Vec<u8> {
    let mut s = String::from("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n");
    let join = |f: &dyn Fn(&PcdField) -> String| fields.iter().map(f).collect::<Vec<_>>().join(" ");
    s += &format!("FIELDS {}\n", join(&|f| f.name.clone()));
    s += &format!("SIZE {}\n", join(&|f| f.size.to_string()));
    s += &format!("TYPE {}\n", join(&|f| f.ty.to_string()));
    s += &format!("COUNT {}\n", join(&|f| f.count.to_string()));
    s += &format!(
        "WIDTH {}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {}\nDATA ascii\n",
        rows.len(),
        rows.len()
    );
    for r in rows {
        s += &r
            .iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(" ");
        s.push('\n');
    }
    s.into_bytes()
}

/// The 18 RADAR_FRONT fields (SPEC §2) as PCD field descriptions.
pub fn radar_pcd_fields() -> Vec<PcdField> {
    (0..18)
        .map(|k| PcdField {
            name: RADAR_FIELD_NAMES[k].into(),
            size: RADAR_FIELD_SIZES[k],
            ty: RADAR_FIELD_TYPES[k],
            count: 1,
        })
        .collect()
}

/// Encode radar points as PCD `ascii` with the 18 radar fields (tests and tools).
pub fn encode_radar_pcd_ascii(points: &[RadarPoint]) -> Vec<u8> {
    let rows: Vec<Vec<f64>> = points
        .iter()
        .map(|p| (0..18).map(|k| p.field(k)).collect())
        .collect();
    encode_pcd_ascii(&radar_pcd_fields(), &rows)
}

/// Encode radar points as PCD `binary_compressed` with LZF literal runs only (valid LZF,
/// no compression); used to test the reader against the structure-of-arrays layout.
pub fn encode_radar_pcd_binary_compressed(points: &[RadarPoint]) -> Vec<u8> {
    let n = points.len();
    let mut header = String::from_utf8_lossy(&encode_radar_pcd_binary(&[])).into_owned();
    header = header
        .replace("WIDTH 0", &format!("WIDTH {n}"))
        .replace("POINTS 0", &format!("POINTS {n}"))
        .replace("DATA binary", "DATA binary_compressed");
    let header = header.trim_end_matches('\0').to_string();
    let mut soa = Vec::with_capacity(n * RADAR_POINT_BYTES);
    for (k, &size) in RADAR_FIELD_SIZES.iter().enumerate() {
        for p in points {
            let v = p.field(k);
            match (RADAR_FIELD_TYPES[k], size) {
                ('F', _) => soa.extend_from_slice(&(v as f32).to_le_bytes()),
                (_, 2) => soa.extend_from_slice(&(v as i16).to_le_bytes()),
                _ => soa.extend_from_slice(&(v as i8).to_le_bytes()),
            }
        }
    }
    let mut comp = Vec::with_capacity(soa.len() + soa.len() / 32 + 1);
    for chunk in soa.chunks(32) {
        comp.push((chunk.len() - 1) as u8);
        comp.extend_from_slice(chunk);
    }
    let mut out = header.into_bytes();
    out.extend_from_slice(&(comp.len() as u32).to_le_bytes());
    out.extend_from_slice(&(soa.len() as u32).to_le_bytes());
    out.extend_from_slice(&comp);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_points() -> Vec<RadarPoint> {
        (0..7)
            .map(|i| RadarPoint {
                x: 10.0 + i as f32,
                y: -1.5 * i as f32,
                z: 0.0,
                dyn_prop: (i % 8) as i8,
                id: 100 + i as i16,
                rcs: 3.5,
                vx: 0.25,
                vy: -0.5,
                vx_comp: 1.0,
                vy_comp: -2.0,
                is_quality_valid: 1,
                ambig_state: if i == 3 { 2 } else { 3 },
                x_rms: 19,
                y_rms: 3,
                invalid_state: if i == 5 { 1 } else { 0 },
                pdh0: 1,
                vx_rms: 17,
                vy_rms: 2,
            })
            .collect()
    }

    #[test]
    fn radar_binary_round_trip_and_padding() {
        let pts = sample_points();
        let bytes = encode_radar_pcd_binary(&pts);
        assert_eq!(bytes.len(), 4096 + 43 * pts.len());
        let scan = parse_radar_pcd(&bytes, "mem").unwrap();
        assert_eq!(scan.points, pts);
        // Filters: i=3 ambig 2, i=5 invalid, i=7.. dyn_prop 7 (none here, 0..7 → 0..=6).
        let (kept, out) = scan.filtered(true);
        assert_eq!(out, 2);
        assert_eq!(kept.len(), 5);
        assert_eq!(scan.filtered(false).0.len(), 7);
    }

    #[test]
    fn generic_reader_agrees_with_fast_path() {
        let pts = sample_points();
        let bytes = encode_radar_pcd_binary(&pts);
        let cloud = parse_pcd(&bytes, "mem").unwrap();
        for (k, col) in cloud.columns.iter().enumerate() {
            for (p, v) in col.iter().enumerate() {
                assert_eq!(*v, pts[p].field(k), "field {k} point {p}");
            }
        }
    }

    #[test]
    fn ascii_and_compressed_round_trip() {
        let pts = sample_points();
        let ascii = encode_radar_pcd_ascii(&pts);
        assert_eq!(parse_radar_pcd(&ascii, "a").unwrap().points, pts);
        let comp = encode_radar_pcd_binary_compressed(&pts);
        assert_eq!(parse_radar_pcd(&comp, "c").unwrap().points, pts);
    }

    #[test]
    fn lzf_back_reference() {
        // literal "ab" then back-reference len 4 offset 2 → "ababab"
        let input = [1u8, b'a', b'b', (2 << 5), 1];
        assert_eq!(lzf_decompress(&input, 6).unwrap(), b"ababab");
        assert!(lzf_decompress(&[0x20, 5], 3).is_err());
    }

    #[test]
    fn truncated_pcd_is_an_error_naming_the_file() {
        let bytes = encode_radar_pcd_binary(&sample_points());
        let header_len = parse_pcd_header(&bytes, "x").unwrap().data_offset;
        let cut = &bytes[..header_len + 43 * 3 + 10];
        let err = parse_radar_pcd(cut, "cut.pcd").unwrap_err().to_string();
        assert!(
            err.contains("cut.pcd") && err.contains("truncated"),
            "{err}"
        );
    }

    #[test]
    fn unknown_layout_is_an_error() {
        let bytes = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA binary\n\0\0\0\0\0\0\0\0\0\0\0\0";
        let err = parse_radar_pcd(bytes, "xyz.pcd").unwrap_err().to_string();
        assert!(err.contains("unknown PCD field layout"), "{err}");
        let bad = b"VERSION 0.7\nFIELDS x y\nSIZE 4 3\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nPOINTS 1\nDATA binary\n";
        let err = parse_pcd(bad, "bad.pcd").unwrap_err().to_string();
        assert!(err.contains("unknown PCD field layout") && err.contains("bad.pcd"));
        let err = parse_pcd(b"hello world\n", "h").unwrap_err().to_string();
        assert!(err.contains("unknown PCD header line"), "{err}");
    }

    #[test]
    fn nan_points_are_dropped_and_counted() {
        let mut pts = sample_points();
        pts[2].x = f32::NAN;
        pts[4].z = f32::INFINITY;
        let scan = parse_radar_pcd(&encode_radar_pcd_binary(&pts), "m").unwrap();
        assert_eq!(scan.points.len(), 5);
        assert_eq!(scan.nan_dropped, 2);
        let lidar = vec![[1.0, 2.0, 3.0, 4.0, 5.0], [f32::NAN, 0.0, 0.0, 0.0, 0.0]];
        let s = parse_lidar_pcd_bin(&encode_lidar_pcd_bin(&lidar), "l").unwrap();
        assert_eq!(s.points, vec![[1.0, 2.0, 3.0, 4.0, 5.0]]);
        assert_eq!(s.nan_dropped, 1);
        assert!(parse_lidar_pcd_bin(&[0u8; 21], "short.bin").is_err());
    }

    fn radar_header(n: &str, width: &str, height: &str, data: &str) -> String {
        format!(
            "# .PCD v0.7\nVERSION 0.7\nFIELDS {}\nSIZE 4 4 4 1 2 4 4 4 4 4 1 1 1 1 1 1 1 1\nTYPE F F F I I F F F F F I I I I I I I I\nCOUNT 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1 1\nWIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n",
            RADAR_FIELD_NAMES.join(" ")
        )
    }

    fn assert_err(bytes: &[u8], name: &str, want: &str) {
        for r in [
            parse_radar_pcd(bytes, name).map(|_| ()),
            parse_pcd(bytes, name).map(|_| ()),
        ] {
            let err = r.expect_err("hostile input must be an error").to_string();
            assert!(err.contains(name) && err.contains(want), "{err}");
        }
    }

    #[test]
    fn header_claiming_a_trillion_points_is_an_error_not_an_abort() {
        // issue 10 defect 4: no allocation may follow a header value unchecked.
        let n = "1000000000000";
        for data in ["binary", "ascii"] {
            let mut b = radar_header(n, n, "1", data).into_bytes();
            b.extend_from_slice(&[0u8; 43 * 3]);
            assert_err(&b, "huge.pcd", "truncated");
        }
        // binary_compressed: sizes that agree with n × 43 only modulo 2^64 or 2^32.
        let mut b = radar_header(n, n, "1", "binary_compressed").into_bytes();
        b.extend_from_slice(&8u32.to_le_bytes());
        b.extend_from_slice(&(43u32 * 1000).to_le_bytes());
        b.extend_from_slice(&[7, 1, 2, 3, 4, 5, 6, 7, 8]);
        assert_err(&b, "huge-c.pcd", "huge-c.pcd");
        // usize::MAX points: n × 43 overflows.
        let max = usize::MAX.to_string();
        let b = radar_header(&max, &max, "1", "binary").into_bytes();
        assert_err(&b, "max.pcd", "truncated");
    }

    #[test]
    fn width_times_height_overflow_is_an_error() {
        let w = (1usize << 40).to_string();
        let h = (1usize << 30).to_string();
        let b = radar_header("0", &w, &h, "binary").into_bytes();
        assert_err(&b, "wh.pcd", "overflows");
        let b = radar_header("12", "3", "4", "binary").into_bytes();
        assert_err(&b, "wh2.pcd", "truncated");
    }

    #[test]
    fn huge_count_is_refused_before_any_loop_or_allocation() {
        let b = b"VERSION 0.7\nFIELDS x\nSIZE 4\nTYPE F\nCOUNT 1000000000000\nWIDTH 0\nPOINTS 0\nDATA binary\n";
        let err = parse_pcd(b, "count.pcd").unwrap_err().to_string();
        assert!(err.contains("count.pcd") && err.contains("bytes"), "{err}");
        let max = format!(
            "VERSION 0.7\nFIELDS x y\nSIZE 8 8\nTYPE F F\nCOUNT {} 2\nWIDTH 0\nPOINTS 0\nDATA ascii\n",
            usize::MAX / 8
        );
        assert!(parse_pcd(max.as_bytes(), "m.pcd").is_err());
    }

    #[test]
    fn truncated_data_of_every_kind_is_an_error() {
        let pts = sample_points();
        for full in [
            encode_radar_pcd_binary(&pts),
            encode_radar_pcd_ascii(&pts),
            encode_radar_pcd_binary_compressed(&pts),
        ] {
            let h = parse_pcd_header(&full, "x").unwrap().data_offset;
            let ascii = parse_pcd_header(&full, "x").unwrap().data == PcdData::Ascii;
            // Every cut inside the data (ascii: at a line boundary loses whole points).
            for cut in h..full.len() {
                let b = &full[..cut];
                if ascii && cut > h && full[cut - 1] != b'\n' {
                    continue;
                }
                if parse_pcd(b, "t.pcd").is_ok() && cut < h + 43 * pts.len() {
                    panic!("cut at {cut} of {} parsed", full.len());
                }
            }
        }
    }

    #[test]
    fn bad_lzf_is_an_error() {
        // back-reference before the start, literal past the end, truncated back-reference
        assert!(lzf_decompress(&[0x20, 0], 3).is_err());
        assert!(lzf_decompress(&[5, 1, 2], 6).is_err());
        assert!(lzf_decompress(&[0, 1, 0xe0], 10).is_err());
        assert!(lzf_decompress(&[0, 1, 0xe0, 0], 10).is_err());
        // output longer or shorter than promised
        assert!(lzf_decompress(&[1, b'a', b'b', 2 << 5, 1], 5).is_err());
        assert!(lzf_decompress(&[1, b'a', b'b'], 3).is_err());
        // a size no input of this length can produce: refused before allocating
        let err = lzf_decompress(&[0, 1], usize::MAX).unwrap_err();
        assert!(err.contains("promises"), "{err}");
        let err = lzf_decompress(&[], 1 << 40).unwrap_err();
        assert!(err.contains("promises"), "{err}");
        // in a file: corrupt stream, compressed size past the end, uncompressed size wrong
        let pts = sample_points();
        let good = encode_radar_pcd_binary_compressed(&pts);
        let h = parse_pcd_header(&good, "x").unwrap().data_offset;
        let mut b = good.clone();
        b[h + 8] = 0xff; // a back-reference as the first op
        assert_err(&b, "lzf.pcd", "LZF");
        let mut b = good.clone();
        b[h..h + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_err(&b, "csize.pcd", "truncated");
        let mut b = good.clone();
        b[h + 4..h + 8].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_err(&b, "usize.pcd", "uncompressed size");
        assert_err(&good[..h + 5], "short.pcd", "truncated");
    }

    #[test]
    fn all_radar_front_mini_files_parse() {
        let Some(dir) = depthsense_testkit::fixture("radar-front-mini") else {
            return;
        };
        let rd = std::fs::read_dir(&dir).unwrap();
        let mut n = 0;
        for e in rd {
            let p = e.unwrap().path();
            let bytes = std::fs::read(&p).unwrap();
            let scan = parse_radar_pcd(&bytes, &p.display().to_string()).unwrap();
            let h = parse_pcd_header(&bytes, "x").unwrap();
            assert_eq!(scan.points.len() + scan.nan_dropped, h.points);
            assert!((52..=125).contains(&h.points), "{}", p.display());
            assert_eq!(bytes.len(), 4096 + 43 * h.points);
            // radar has no elevation (SPEC §2)
            assert!(scan.points.iter().all(|q| q.z == 0.0));
            n += 1;
        }
        assert_eq!(n, 404);
    }

    #[test]
    fn encoder_matches_real_file_bytes() {
        let Some(p) = depthsense_testkit::fixture(
            "nuscenes-kf0/samples/RADAR_FRONT/n015-2018-07-24-11-22-45+0800__RADAR_FRONT__1532402927664178.pcd",
        ) else {
            return;
        };
        let bytes = std::fs::read(&p).unwrap();
        let scan = parse_radar_pcd(&bytes, "kf0").unwrap();
        assert_eq!(scan.points.len(), 125);
        let enc = encode_radar_pcd_binary(&scan.points);
        assert_eq!(enc.len(), bytes.len());
        assert_eq!(
            enc, bytes,
            "re-encoded radar file differs from the original"
        );
    }
}
