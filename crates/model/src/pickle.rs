//! Reading and writing PyTorch `torch.save` files (the zip format of torch ≥ 1.6: an archive
//! holding `<name>/data.pkl`, a pickle whose tensors point by persistent id to raw
//! little-endian storages `<name>/data/<key>`), without Python.
//!
//! The reader implements the pickle opcodes `torch.save` emits (protocols 2–4) and rebuilds
//! `torch._utils._rebuild_tensor_v2` / `_rebuild_parameter` tensors; `collections.OrderedDict`
//! becomes a dict; any other class becomes an opaque object that keeps its constructor
//! arguments and `BUILD` state, so pickled `nn.Module`s can still be walked for tensors.

use std::collections::HashMap;
use std::io::{Read, Write};
use std::path::Path;

use tch::{Device, Kind, Tensor};

use crate::ModelError;

/// A pickled value.
#[derive(Debug, Clone)]
pub enum Value {
    /// `None`.
    None,
    /// `bool`.
    Bool(bool),
    /// `int`.
    Int(i64),
    /// `float`.
    Float(f64),
    /// `str`.
    Str(String),
    /// `bytes`.
    Bytes(Vec<u8>),
    /// `tuple`.
    Tuple(Vec<Value>),
    /// `list` (and sets).
    List(Vec<Value>),
    /// `dict` / `OrderedDict`, insertion order kept.
    Dict(Vec<(Value, Value)>),
    /// A global reference `module.name`.
    Global(String, String),
    /// A storage referenced by persistent id.
    Storage {
        /// Storage class name (`FloatStorage`, …).
        dtype: String,
        /// Key of the storage record (`data/<key>`).
        key: String,
    },
    /// A tensor view into a storage.
    Tensor(TensorRef),
    /// Any other object: its class/callable, arguments and `BUILD` state.
    Object {
        /// The callable that built it.
        class: Box<Value>,
        /// Its arguments.
        args: Vec<Value>,
        /// State given by `BUILD` (`None` when absent).
        state: Box<Value>,
    },
    /// The pickle MARK (internal).
    Mark,
}

/// Where a tensor's data lives.
#[derive(Debug, Clone, PartialEq)]
pub struct TensorRef {
    /// Storage record key.
    pub storage_key: String,
    /// Storage class name (`FloatStorage`).
    pub storage_type: String,
    /// Offset in elements.
    pub offset: i64,
    /// Shape.
    pub size: Vec<i64>,
    /// Strides in elements.
    pub stride: Vec<i64>,
}

fn storage_kind(name: &str) -> Option<(Kind, usize)> {
    Some(match name {
        "FloatStorage" => (Kind::Float, 4),
        "DoubleStorage" => (Kind::Double, 8),
        "HalfStorage" => (Kind::Half, 2),
        "BFloat16Storage" => (Kind::BFloat16, 2),
        "LongStorage" => (Kind::Int64, 8),
        "IntStorage" => (Kind::Int, 4),
        "ShortStorage" => (Kind::Int16, 2),
        "CharStorage" => (Kind::Int8, 1),
        "ByteStorage" | "UntypedStorage" => (Kind::Uint8, 1),
        "BoolStorage" => (Kind::Bool, 1),
        _ => return None,
    })
}

fn storage_name(kind: Kind) -> Option<&'static str> {
    Some(match kind {
        Kind::Float => "FloatStorage",
        Kind::Double => "DoubleStorage",
        Kind::Half => "HalfStorage",
        Kind::BFloat16 => "BFloat16Storage",
        Kind::Int64 => "LongStorage",
        Kind::Int => "IntStorage",
        Kind::Int16 => "ShortStorage",
        Kind::Int8 => "CharStorage",
        Kind::Uint8 => "ByteStorage",
        Kind::Bool => "BoolStorage",
        _ => return None,
    })
}

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        // `n` comes from the file: compare against what is left, never `pos + n`.
        if n > self.b.len() - self.pos {
            return Err(format!(
                "pickle truncated at byte {} (wanted {n} more)",
                self.pos
            ));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().map_err(|_| "short read")?,
        ))
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().map_err(|_| "short read")?,
        ))
    }
    /// The string or bytes value of opcode `op`: BINUNICODE (`X`), SHORT_BINUNICODE,
    /// BINUNICODE8, SHORT_BINSTRING (`U`), BINSTRING (`T`), BINBYTES (`B`), SHORT_BINBYTES (`C`).
    fn string_op(&mut self, op: u8) -> Result<Value, String> {
        if let b'X' | 0x8c | 0x8d = op {
            let n = match op {
                b'X' => self.u32()? as usize,
                0x8c => self.u8()? as usize,
                _ => usize::try_from(self.u64()?).unwrap_or(usize::MAX),
            };
            return Ok(Value::Str(
                String::from_utf8_lossy(self.take(n)?).into_owned(),
            ));
        }
        let n = if op == b'U' || op == b'C' {
            self.u8()? as usize
        } else {
            self.u32()? as usize
        };
        let data = self.take(n)?.to_vec();
        Ok(if op == b'U' || op == b'T' {
            Value::Str(String::from_utf8_lossy(&data).into_owned())
        } else {
            Value::Bytes(data)
        })
    }
    /// LONG1: a little-endian two's-complement integer of up to 8 bytes; wider ones (only the
    /// legacy format's magic number is this wide) as bytes.
    fn long1(&mut self) -> Result<Value, String> {
        let n = self.u8()? as usize;
        let b = self.take(n)?;
        if n > 8 {
            // only the legacy format's magic number is this wide
            return Ok(Value::Bytes(b.to_vec()));
        }
        let mut v: i64 = 0;
        for (i, x) in b.iter().enumerate() {
            v |= (*x as i64) << (8 * i);
        }
        if n > 0 && n < 8 && b[n - 1] & 0x80 != 0 {
            v -= 1i64 << (8 * n);
        }
        Ok(Value::Int(v))
    }
    fn line(&mut self) -> Result<String, String> {
        let start = self.pos;
        while self.pos < self.b.len() && self.b[self.pos] != b'\n' {
            self.pos += 1;
        }
        if self.pos >= self.b.len() {
            return Err("pickle truncated inside GLOBAL".into());
        }
        let s = String::from_utf8_lossy(&self.b[start..self.pos]).into_owned();
        self.pos += 1;
        Ok(s)
    }
}

fn as_ints(v: &Value) -> Option<Vec<i64>> {
    match v {
        Value::Tuple(xs) | Value::List(xs) => xs
            .iter()
            .map(|x| {
                if let Value::Int(i) = x {
                    Some(*i)
                } else {
                    None
                }
            })
            .collect(),
        _ => None,
    }
}

fn reduce(callable: Value, args: Value) -> Result<Value, String> {
    let args = match args {
        Value::Tuple(a) => a,
        other => vec![other],
    };
    if let Value::Global(m, n) = &callable {
        match (m.as_str(), n.as_str()) {
            ("collections", "OrderedDict") | ("builtins", "dict") => {
                return Ok(Value::Dict(Vec::new()))
            }
            ("torch._utils", "_rebuild_tensor_v2") | ("torch._utils", "_rebuild_tensor") => {
                let (storage_type, storage_key) = match args.first() {
                    Some(Value::Storage { dtype, key }) => (dtype.clone(), key.clone()),
                    _ => return Err("_rebuild_tensor without a storage".into()),
                };
                let offset = match args.get(1) {
                    Some(Value::Int(o)) => *o,
                    _ => return Err("_rebuild_tensor: bad storage offset".into()),
                };
                let size = args
                    .get(2)
                    .and_then(as_ints)
                    .ok_or("_rebuild_tensor: bad size")?;
                let stride = args
                    .get(3)
                    .and_then(as_ints)
                    .ok_or("_rebuild_tensor: bad stride")?;
                return Ok(Value::Tensor(TensorRef {
                    storage_key,
                    storage_type,
                    offset,
                    size,
                    stride,
                }));
            }
            ("torch._utils", "_rebuild_parameter")
            | ("torch._utils", "_rebuild_parameter_with_state") => {
                return args
                    .into_iter()
                    .next()
                    .ok_or_else(|| "_rebuild_parameter without data".into());
            }
            _ => {}
        }
    }
    Ok(Value::Object {
        class: Box::new(callable),
        args,
        state: Box::new(Value::None),
    })
}

/// Parses a pickle stream (the persistent ids of `torch.save` become [`Value::Storage`]).
pub fn parse_pickle(bytes: &[u8]) -> Result<Value, String> {
    parse_pickle_at(bytes, 0).map(|(v, _)| v)
}

/// Deepest nesting of containers a pickle may build. Real `torch.save` files nest a few
/// dozen levels; the bound keeps recursion (walking, dropping) far from the stack limit.
pub const MAX_PICKLE_DEPTH: u32 = 256;

/// Size accounting of one value: nesting depth and a weight (nodes + bytes/8) that bounds
/// what copying it costs.
#[derive(Clone, Copy, Default)]
struct Meta {
    depth: u32,
    weight: u64,
}

impl Meta {
    fn leaf(v: &Value) -> Meta {
        let bytes = match v {
            Value::Str(s) => s.len(),
            Value::Bytes(b) => b.len(),
            Value::Global(m, n) => m.len() + n.len(),
            Value::Storage { dtype, key } => dtype.len() + key.len(),
            _ => 0,
        };
        Meta {
            depth: 0,
            weight: 1 + bytes as u64 / 8,
        }
    }
    /// A container holding values of these metas.
    fn around<'m>(children: impl IntoIterator<Item = &'m Meta>) -> Meta {
        let mut m = Meta {
            depth: 1,
            weight: 1,
        };
        for c in children {
            m.depth = m.depth.max(c.depth + 1);
            m.weight = m.weight.saturating_add(c.weight);
        }
        m
    }
    /// `self` after `child` was put inside it.
    fn absorb(&mut self, child: Meta) {
        self.depth = self.depth.max(child.depth + 1);
        self.weight = self.weight.saturating_add(child.weight);
    }
}

/// The pickle machine's stack with per-value [`Meta`], the MARK positions, and the budget of
/// copies (memo and DUP) left: a hostile pickle can neither nest without bound nor grow
/// exponentially through the memo ("billion laughs").
struct Machine {
    items: Vec<(Value, Meta)>,
    marks: Vec<usize>,
    copy_budget: u64,
}

impl Machine {
    fn push(&mut self, v: Value, m: Meta) -> Result<(), String> {
        if m.depth > MAX_PICKLE_DEPTH {
            return Err(format!(
                "pickle nests deeper than {MAX_PICKLE_DEPTH} levels"
            ));
        }
        if matches!(v, Value::Mark) {
            self.marks.push(self.items.len());
        }
        self.items.push((v, m));
        Ok(())
    }
    fn leaf(&mut self, v: Value) -> Result<(), String> {
        let m = Meta::leaf(&v);
        self.push(v, m)
    }
    fn pop(&mut self) -> Result<(Value, Meta), String> {
        let (v, m) = self
            .items
            .pop()
            .ok_or_else(|| "pickle stack underflow".to_string())?;
        if matches!(v, Value::Mark) {
            self.marks.pop();
        }
        Ok((v, m))
    }
    /// The top `n` values (TUPLE1..3).
    fn pop_n(&mut self, n: usize) -> Result<(Vec<Value>, Meta), String> {
        if self.items.len() < n {
            return Err("pickle stack underflow in TUPLEn".into());
        }
        let at = self.items.len() - n;
        while self.marks.last().is_some_and(|&i| i >= at) {
            self.marks.pop();
        }
        let popped = self.items.split_off(at);
        let meta = Meta::around(popped.iter().map(|(_, m)| m));
        Ok((popped.into_iter().map(|(v, _)| v).collect(), meta))
    }
    /// Everything above the topmost MARK (which is removed).
    fn pop_mark(&mut self) -> Result<(Vec<Value>, Meta), String> {
        let i = self.marks.pop().ok_or("pickle: MARK not found")?;
        let popped = self.items.split_off(i + 1);
        self.items.pop();
        let meta = Meta::around(popped.iter().map(|(_, m)| m));
        Ok((popped.into_iter().map(|(v, _)| v).collect(), meta))
    }
    fn last_mut(&mut self) -> Option<(&mut Value, &mut Meta)> {
        self.items.last_mut().map(|(v, m)| (v, m))
    }
    /// A copy of the top value, charged to the copy budget.
    fn copy_top(&mut self, op: &str) -> Result<(Value, Meta), String> {
        let m = self
            .items
            .last()
            .map(|(_, m)| *m)
            .ok_or_else(|| format!("{op} on empty stack"))?;
        self.charge(m)?;
        let v = self
            .items
            .last()
            .map(|(v, _)| v.clone())
            .unwrap_or(Value::None);
        Ok((v, m))
    }
    fn charge(&mut self, m: Meta) -> Result<(), String> {
        self.copy_budget = self.copy_budget.checked_sub(m.weight).ok_or_else(|| {
            "pickle copies more data through its memo than any real file (memo bomb?)".to_string()
        })?;
        Ok(())
    }
    /// Checks the depth of the top value after something was put inside it.
    fn check_top(&self) -> Result<(), String> {
        match self.items.last() {
            Some((_, m)) if m.depth > MAX_PICKLE_DEPTH => Err(format!(
                "pickle nests deeper than {MAX_PICKLE_DEPTH} levels"
            )),
            _ => Ok(()),
        }
    }
    /// STACK_GLOBAL: module and name strings → a global.
    fn stack_global(&mut self) -> Result<(), String> {
        let (n, _) = self.pop()?;
        let (m, _) = self.pop()?;
        match (m, n) {
            (Value::Str(m), Value::Str(n)) => self.leaf(Value::Global(m, n)),
            _ => Err("STACK_GLOBAL with non-string operands".into()),
        }
    }
    /// BINPERSID: a `('storage', type, key, …)` tuple → a storage.
    fn persistent_id(&mut self) -> Result<(), String> {
        let (pid, _) = self.pop()?;
        let items = match pid {
            Value::Tuple(t) => t,
            _ => return Err("persistent id is not a tuple".into()),
        };
        match (items.first(), items.get(1), items.get(2)) {
            (Some(Value::Str(tag)), Some(sv), Some(Value::Str(key))) if tag == "storage" => {
                let dtype = match sv {
                    Value::Global(_, n) => n.clone(),
                    Value::Str(s) => s.clone(),
                    _ => "UntypedStorage".into(),
                };
                self.leaf(Value::Storage {
                    dtype,
                    key: key.clone(),
                })
            }
            _ => Err("persistent id is not a ('storage', type, key, …) tuple".into()),
        }
    }
    /// DICT: the key/value pairs above the topmost MARK → a dict.
    fn dict(&mut self) -> Result<(), String> {
        let (items, m) = self.pop_mark()?;
        let mut d = Vec::new();
        let mut it = items.into_iter();
        while let (Some(k), Some(v)) = (it.next(), it.next()) {
            d.push((k, v));
        }
        self.push(Value::Dict(d), m)
    }
    /// BUILD: the popped state into the object below it.
    fn build(&mut self) -> Result<(), String> {
        let (state_v, ms) = self.pop()?;
        match self.last_mut() {
            Some((Value::Object { state, .. }, m)) => {
                **state = state_v;
                m.absorb(ms);
            }
            Some(_) => {} // OrderedDict attributes (`_metadata`) etc.: ignored
            None => return Err("BUILD on empty stack".into()),
        }
        self.check_top()
    }
    /// SETITEM: one popped key/value pair into the dict below it.
    fn set_item(&mut self) -> Result<(), String> {
        let (v, mv) = self.pop()?;
        let (k, mk) = self.pop()?;
        match self.last_mut() {
            Some((Value::Dict(d), m)) => {
                d.push((k, v));
                m.absorb(mv);
                m.absorb(mk);
            }
            _ => return Err("SETITEM on a non-dict".into()),
        }
        self.check_top()
    }
    /// SETITEMS: the key/value pairs above the topmost MARK into the dict below it.
    fn set_items(&mut self) -> Result<(), String> {
        let (items, mi) = self.pop_mark()?;
        match self.last_mut() {
            Some((Value::Dict(d), m)) => {
                let mut it = items.into_iter();
                while let (Some(k), Some(v)) = (it.next(), it.next()) {
                    d.push((k, v));
                }
                m.absorb(Meta {
                    depth: mi.depth.saturating_sub(1),
                    weight: mi.weight,
                });
            }
            _ => return Err("SETITEMS on a non-dict".into()),
        }
        self.check_top()
    }
    /// APPEND: one popped value onto the list below it.
    fn append(&mut self) -> Result<(), String> {
        let (v, mv) = self.pop()?;
        match self.last_mut() {
            Some((Value::List(l), m)) => {
                l.push(v);
                m.absorb(mv);
            }
            _ => return Err("APPEND on a non-list".into()),
        }
        self.check_top()
    }
    /// APPENDS (and ADDITEMS): the values above the topmost MARK onto the list below it.
    fn appends(&mut self) -> Result<(), String> {
        let (items, mi) = self.pop_mark()?;
        match self.last_mut() {
            Some((Value::List(l), m)) => {
                l.extend(items);
                m.absorb(Meta {
                    depth: mi.depth.saturating_sub(1),
                    weight: mi.weight,
                });
            }
            _ => return Err("APPENDS on a non-list".into()),
        }
        self.check_top()
    }
}

/// Parses one pickle starting at byte `start`; returns the value and the position after STOP.
///
/// Hostile input is an error, never a panic, a hang or an allocation beyond a small multiple
/// of the input (issue 10): lengths are checked against the bytes left, nesting is bounded by
/// [`MAX_PICKLE_DEPTH`], and memo/DUP copies by a budget proportional to the input length.
pub fn parse_pickle_at(bytes: &[u8], start: usize) -> Result<(Value, usize), String> {
    if start > bytes.len() {
        return Err(format!(
            "pickle starts at byte {start}, past the end ({} bytes)",
            bytes.len()
        ));
    }
    let mut r = Reader {
        b: bytes,
        pos: start,
    };
    let mut st = Machine {
        items: Vec::new(),
        marks: Vec::new(),
        copy_budget: (bytes.len() as u64).saturating_mul(16) + (1 << 20),
    };
    let mut memo: HashMap<u32, (Value, Meta)> = HashMap::new();
    loop {
        let op = r.u8()?;
        match op {
            0x80 => {
                r.u8()?;
            } // PROTO
            0x95 => {
                r.u64()?;
            } // FRAME
            b'.' => return st.pop().map(|(v, _)| (v, r.pos)),
            b'}' => st.leaf(Value::Dict(Vec::new()))?,
            b']' | 0x8f => st.leaf(Value::List(Vec::new()))?,
            b')' => st.leaf(Value::Tuple(Vec::new()))?,
            b'(' => st.leaf(Value::Mark)?,
            b'N' => st.leaf(Value::None)?,
            0x88 => st.leaf(Value::Bool(true))?,
            0x89 => st.leaf(Value::Bool(false))?,
            b'q' | b'r' | 0x94 => {
                let i = match op {
                    b'q' => r.u8()? as u32,
                    b'r' => r.u32()?,
                    _ => memo.len() as u32,
                };
                let name = match op {
                    b'q' => "BINPUT",
                    b'r' => "LONG_BINPUT",
                    _ => "MEMOIZE",
                };
                let v = st.copy_top(name)?;
                memo.insert(i, v);
            }
            b'h' | b'j' => {
                let i = if op == b'h' { r.u8()? as u32 } else { r.u32()? };
                let (v, m) = memo.get(&i).ok_or(format!("BINGET {i}: not in memo"))?;
                let m = *m;
                st.charge(m)?;
                st.push(v.clone(), m)?;
            }
            b'X' | 0x8c | 0x8d | b'U' | b'T' | b'B' | b'C' => st.leaf(r.string_op(op)?)?,
            b'c' => {
                let m = r.line()?;
                let n = r.line()?;
                st.leaf(Value::Global(m, n))?;
            }
            0x93 => st.stack_global()?,
            b'Q' => st.persistent_id()?,
            b'J' => st.leaf(Value::Int(r.u32()? as i32 as i64))?,
            b'K' => st.leaf(Value::Int(r.u8()? as i64))?,
            b'M' => {
                let b = r.take(2)?;
                st.leaf(Value::Int(u16::from_le_bytes([b[0], b[1]]) as i64))?;
            }
            0x8a => st.leaf(r.long1()?)?,
            b'G' => {
                let b = r.take(8)?;
                st.leaf(Value::Float(f64::from_be_bytes(
                    b.try_into().map_err(|_| "short read")?,
                )))?;
            }
            0x85..=0x87 => {
                let (items, m) = st.pop_n((op - 0x84) as usize)?;
                st.push(Value::Tuple(items), m)?;
            }
            b't' => {
                let (items, m) = st.pop_mark()?;
                st.push(Value::Tuple(items), m)?;
            }
            b'l' | 0x91 => {
                let (items, m) = st.pop_mark()?;
                st.push(Value::List(items), m)?;
            }
            b'd' => st.dict()?,
            b'R' | 0x81 => {
                let (args, ma) = st.pop()?;
                let (callable, mc) = st.pop()?;
                let m = Meta::around([&ma, &mc]);
                st.push(reduce(callable, args)?, m)?;
            }
            b'b' => st.build()?,
            b's' => st.set_item()?,
            b'u' => st.set_items()?,
            b'a' => st.append()?,
            b'e' | 0x90 => st.appends()?,
            b'0' => {
                st.pop()?;
            }
            b'2' => {
                let (v, m) = st.copy_top("DUP")?;
                st.push(v, m)?;
            }
            other => {
                return Err(format!(
                    "unsupported pickle opcode 0x{other:02x} at byte {}",
                    r.pos - 1
                ))
            }
        }
    }
}

/// Walks a parsed `torch.save` object and returns every tensor with a dotted name: a state
/// dict `{name: tensor}` as is; nested dicts (`{"state_dict": {...}}`, `{"model": {...}}`)
/// with their keys joined by `.`; pickled `nn.Module`s through `_parameters`, `_buffers` and
/// `_modules`.
pub fn collect_tensors(v: &Value) -> Vec<(String, TensorRef)> {
    fn walk(v: &Value, prefix: &str, out: &mut Vec<(String, TensorRef)>) {
        let join = |k: &str| {
            if prefix.is_empty() {
                k.to_string()
            } else {
                format!("{prefix}.{k}")
            }
        };
        match v {
            Value::Tensor(t) => out.push((prefix.to_string(), t.clone())),
            Value::Dict(d) => {
                for (k, v) in d {
                    let key = match k {
                        Value::Str(s) => s.clone(),
                        Value::Int(i) => i.to_string(),
                        _ => continue,
                    };
                    // nn.Module state: flatten `_parameters`, `_buffers`, `_modules` away.
                    if matches!(key.as_str(), "_parameters" | "_buffers" | "_modules") {
                        walk(v, prefix, out);
                    } else if key.starts_with('_')
                        && prefix.is_empty()
                        && !matches!(v, Value::Tensor(_))
                    {
                        continue;
                    } else {
                        walk(v, &join(&key), out);
                    }
                }
            }
            Value::Object { state, .. } => walk(state, prefix, out),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(v, "", &mut out);
    out
}

/// The magic number opening legacy (pre-1.6) `torch.save` files, little-endian.
const LEGACY_MAGIC: [u8; 10] = [0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19];

/// Reads every tensor of a `torch.save` file onto the CPU (dotted names, file order): the zip
/// format of torch ≥ 1.6 and the legacy format (magic number, protocol, sys-info and object
/// pickles, the storage-key list, then each storage as an 8-byte element count + raw data).
pub fn read_torch_file(path: &Path) -> Result<Vec<(String, Tensor)>, ModelError> {
    let bytes = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
    read_torch_bytes(path, &bytes)
}

/// [`read_torch_file`] on bytes already in memory; `path` only names the file in errors.
/// Every size in the file is checked against the bytes present before anything is
/// allocated from it (issue 10).
pub fn read_torch_bytes(path: &Path, bytes: &[u8]) -> Result<Vec<(String, Tensor)>, ModelError> {
    if bytes.starts_with(b"PK") {
        read_zip(path, bytes)
    } else if bytes.first() == Some(&0x80) {
        read_legacy(path, bytes)
    } else {
        Err(ModelError::format(
            path,
            "not a torch.save file (neither a zip archive nor a legacy pickle)",
        ))
    }
}

/// Record `name` of a `torch.save` zip archive (`archive_len` bytes in all), read in full.
fn read_record(
    path: &Path,
    zip: &mut zip::ZipArchive<std::io::Cursor<&[u8]>>,
    archive_len: usize,
    name: &str,
) -> Result<Vec<u8>, ModelError> {
    let mut e = zip
        .by_name(name)
        .map_err(|e| ModelError::format(path, format!("missing record {name}: {e}")))?;
    // The declared size is only a hint: never allocate more than deflate can produce
    // from the archive, and never read past the declared size.
    let declared = e.size();
    let possible = (archive_len as u64).saturating_mul(1100);
    if declared > possible {
        return Err(ModelError::format(
            path,
            format!("record {name} claims {declared} bytes, more than a {archive_len} byte archive can hold"),
        ));
    }
    let mut buf = Vec::with_capacity(declared.min(archive_len as u64) as usize);
    (&mut e)
        .take(declared.saturating_add(1))
        .read_to_end(&mut buf)
        .map_err(|e| {
            ModelError::format(path, format!("record {name} unreadable (truncated?): {e}"))
        })?;
    if buf.len() as u64 != declared {
        return Err(ModelError::format(
            path,
            format!(
                "record {name} holds {} bytes, its header says {declared}",
                buf.len()
            ),
        ));
    }
    Ok(buf)
}

fn read_zip(path: &Path, bytes: &[u8]) -> Result<Vec<(String, Tensor)>, ModelError> {
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(|e| {
        ModelError::format(
            path,
            format!("not a readable zip archive (truncated?): {e}"),
        )
    })?;
    let pkl_name = zip
        .file_names()
        .find(|n| *n == "data.pkl" || n.ends_with("/data.pkl"))
        .map(str::to_string)
        .ok_or_else(|| {
            ModelError::format(path, "zip archive without data.pkl: not a torch.save file")
        })?;
    let prefix = pkl_name.trim_end_matches("data.pkl").to_string();
    let mut read_entry = |name: &str| read_record(path, &mut zip, bytes.len(), name);
    if let Ok(order) = read_entry(&format!("{prefix}byteorder")) {
        if order.trim_ascii() != b"little" {
            return Err(ModelError::format(
                path,
                "big-endian torch.save files are not supported",
            ));
        }
    }
    let pkl = read_entry(&pkl_name)?;
    let value =
        parse_pickle(&pkl).map_err(|e| ModelError::format(path, format!("{pkl_name}: {e}")))?;
    let refs = collect_tensors(&value);
    let mut storages: HashMap<String, Vec<u8>> = HashMap::new();
    for (_, t) in &refs {
        if !storages.contains_key(&t.storage_key) {
            let data = read_entry(&format!("{prefix}data/{}", t.storage_key))?;
            storages.insert(t.storage_key.clone(), data);
        }
    }
    materialize(path, refs, &storages)
}

fn read_legacy(path: &Path, bytes: &[u8]) -> Result<Vec<(String, Tensor)>, ModelError> {
    let bad = |m: String| ModelError::format(path, format!("legacy torch.save file: {m}"));
    let (magic, pos) = parse_pickle_at(bytes, 0).map_err(&bad)?;
    if !matches!(&magic, Value::Bytes(b) if b[..] == LEGACY_MAGIC) {
        return Err(bad("wrong magic number (not a torch.save file)".into()));
    }
    let (_protocol, pos) = parse_pickle_at(bytes, pos).map_err(&bad)?;
    let (_sys_info, pos) = parse_pickle_at(bytes, pos).map_err(&bad)?;
    let (value, pos) = parse_pickle_at(bytes, pos).map_err(&bad)?;
    let (keys, mut pos) = parse_pickle_at(bytes, pos).map_err(&bad)?;
    let keys = match keys {
        Value::List(k) => k,
        _ => return Err(bad("storage key list missing".into())),
    };
    let refs = collect_tensors(&value);
    let types: HashMap<&str, &str> = refs
        .iter()
        .map(|(_, t)| (t.storage_key.as_str(), t.storage_type.as_str()))
        .collect();
    let mut storages = HashMap::new();
    for k in keys {
        let Value::Str(key) = k else {
            return Err(bad("non-string storage key".into()));
        };
        let es = types
            .get(key.as_str())
            .and_then(|t| storage_kind(t))
            .map_or(1, |x| x.1);
        if pos + 8 > bytes.len() {
            return Err(bad(format!("truncated before storage {key}")));
        }
        let numel = u64::from_le_bytes(bytes[pos..pos + 8].try_into().unwrap_or([0; 8])) as usize;
        pos += 8;
        let len = numel.checked_mul(es).filter(|&l| l <= bytes.len() - pos);
        let Some(len) = len else {
            return Err(bad(format!(
                "truncated: storage {key} needs {numel}×{es} bytes"
            )));
        };
        storages.insert(key, bytes[pos..pos + len].to_vec());
        pos += len;
    }
    materialize(path, refs, &storages)
}

/// Checks the strided view `t` against a storage of `numel` elements, in checked
/// arithmetic: every number here comes from the file (issue 10). Returns whether the view is
/// empty, or why it is refused.
fn check_view(t: &TensorRef, numel: usize) -> Result<bool, &'static str> {
    if t.size.len() != t.stride.len() {
        return Err("has sizes and strides of different lengths");
    }
    if t.offset < 0 || t.size.iter().any(|&s| s < 0) || t.stride.iter().any(|&s| s < 0) {
        return Err("has a negative size, stride or offset");
    }
    let empty = t.size.contains(&0);
    let view_numel = t
        .size
        .iter()
        .try_fold(1i64, |a, &s| a.checked_mul(s))
        .ok_or("has more elements than fit in 64 bits")?;
    let last = t
        .size
        .iter()
        .zip(&t.stride)
        .try_fold(t.offset, |a, (&s, &st)| {
            (s - 1)
                .max(0)
                .checked_mul(st)
                .and_then(|x| a.checked_add(x))
        })
        .ok_or("overflows")?;
    if !empty && last as u64 >= numel as u64 {
        return Err("exceeds its storage (truncated?)");
    }
    // Stride-0 views would let a few bytes expand into any amount of memory.
    if view_numel as u64 > (numel as u64).max(1 << 16) {
        return Err("expands beyond its storage");
    }
    Ok(empty)
}

fn materialize(
    path: &Path,
    refs: Vec<(String, TensorRef)>,
    storages: &HashMap<String, Vec<u8>>,
) -> Result<Vec<(String, Tensor)>, ModelError> {
    if refs.is_empty() {
        return Err(ModelError::format(path, "the pickle holds no tensors"));
    }
    let mut out = Vec::with_capacity(refs.len());
    for (name, t) in refs {
        let (kind, es) = storage_kind(&t.storage_type).ok_or_else(|| {
            ModelError::format(
                path,
                format!("tensor {name}: unsupported storage {}", t.storage_type),
            )
        })?;
        let data = storages.get(&t.storage_key).ok_or_else(|| {
            ModelError::format(
                path,
                format!("tensor {name}: storage {} missing", t.storage_key),
            )
        })?;
        let numel = data.len() / es;
        let empty = check_view(&t, numel).map_err(|why| {
            ModelError::format(
                path,
                format!(
                    "tensor {name}: view {:?}/{:?}+{} {why} (storage of {numel} elements)",
                    t.size, t.stride, t.offset
                ),
            )
        })?;
        let tensor = if empty {
            Tensor::f_zeros(&t.size, (kind, Device::Cpu))?
        } else {
            let flat = Tensor::f_from_data_size(&data[..numel * es], &[numel as i64], kind)?;
            flat.f_as_strided(&t.size, &t.stride, t.offset)?
                .f_contiguous()?
        };
        out.push((name, tensor));
    }
    Ok(out)
}

struct PickleWriter {
    out: Vec<u8>,
}

impl PickleWriter {
    fn op(&mut self, b: u8) {
        self.out.push(b);
    }
    fn string(&mut self, s: &str) {
        self.op(b'X');
        self.out.extend_from_slice(&(s.len() as u32).to_le_bytes());
        self.out.extend_from_slice(s.as_bytes());
    }
    fn int(&mut self, i: i64) {
        if let Ok(v) = i32::try_from(i) {
            self.op(b'J');
            self.out.extend_from_slice(&v.to_le_bytes());
        } else {
            self.op(0x8a);
            self.op(8);
            self.out.extend_from_slice(&i.to_le_bytes());
        }
    }
    fn global(&mut self, m: &str, n: &str) {
        self.op(b'c');
        self.out.extend_from_slice(format!("{m}\n{n}\n").as_bytes());
    }
    fn int_tuple(&mut self, xs: &[i64]) {
        self.op(b'(');
        for &x in xs {
            self.int(x);
        }
        self.op(b't');
    }
    /// One state-dict entry: `name` → `_rebuild_tensor_v2` of storage `key` (class `st`,
    /// `numel` elements), a contiguous view of `size`.
    fn tensor_entry(&mut self, name: &str, key: &str, st: &str, numel: usize, size: &[i64]) {
        let mut stride = vec![1i64; size.len()];
        for d in (0..size.len().saturating_sub(1)).rev() {
            stride[d] = stride[d + 1] * size[d + 1].max(1);
        }
        self.string(name);
        self.global("torch._utils", "_rebuild_tensor_v2");
        self.op(b'(');
        self.op(b'(');
        self.string("storage");
        self.global("torch", st);
        self.string(key);
        self.string("cpu");
        self.int(numel as i64);
        self.op(b't');
        self.op(b'Q');
        self.int(0);
        self.int_tuple(size);
        self.int_tuple(&stride);
        self.op(0x89);
        self.global("collections", "OrderedDict");
        self.op(b')');
        self.op(b'R');
        self.op(b't');
        self.op(b'R');
    }
}

/// The raw little-endian bytes of tensor `name` and its storage class name.
fn storage_bytes(name: &str, t: &Tensor) -> Result<(Vec<u8>, &'static str), ModelError> {
    let st = storage_name(t.kind()).ok_or_else(|| {
        ModelError::InvalidConfig(format!("tensor {name}: dtype {:?} not writable", t.kind()))
    })?;
    let numel = t.numel();
    let es = t.kind().elt_size_in_bytes();
    let mut buf = vec![0u8; numel * es];
    t.f_copy_data_u8(&mut buf, numel)?;
    Ok((buf, st))
}

/// The zip archive of a `torch.save` file: `archive/data.pkl`, `byteorder`, the storages
/// `data/<i>` and `version`, stored uncompressed.
fn torch_zip(path: &Path, pkl: &[u8], blobs: &[Vec<u8>]) -> Result<Vec<u8>, ModelError> {
    let mut cursor = std::io::Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut cursor);
        let opts =
            zip::write::FileOptions::default().compression_method(zip::CompressionMethod::Stored);
        let mut put = |name: &str, data: &[u8]| -> Result<(), ModelError> {
            z.start_file(format!("archive/{name}"), opts)
                .map_err(|e| ModelError::format(path, format!("zip: {e}")))?;
            z.write_all(data).map_err(|e| ModelError::io(path, e))
        };
        put("data.pkl", pkl)?;
        put("byteorder", b"little")?;
        for (i, b) in blobs.iter().enumerate() {
            put(&format!("data/{i}"), b)?;
        }
        put("version", b"3\n")?;
        z.finish()
            .map_err(|e| ModelError::format(path, format!("zip: {e}")))?;
    }
    Ok(cursor.into_inner())
}

/// Writes named tensors as a `torch.save`-compatible zip file holding an `OrderedDict` state
/// dict (what `torch.save(model.state_dict(), path)` produces; `torch.load` reads it back,
/// also with `weights_only=True`). Written atomically.
pub fn write_torch_state_dict(path: &Path, tensors: &[(String, Tensor)]) -> Result<(), ModelError> {
    let mut w = PickleWriter { out: vec![0x80, 2] };
    w.global("collections", "OrderedDict");
    w.op(b')');
    w.op(b'R');
    w.op(b'(');
    let mut blobs = Vec::new();
    for (i, (name, t)) in tensors.iter().enumerate() {
        let t = t.detach().to_device(Device::Cpu).contiguous();
        let (buf, st) = storage_bytes(name, &t)?;
        w.tensor_entry(name, &i.to_string(), st, t.numel(), &t.size());
        blobs.push(buf);
    }
    w.op(b'u');
    w.op(b'.');
    let archive = torch_zip(path, &w.out, &blobs)?;
    crate::checkpoint::write_atomic(path, &archive)
}
