//! The pickle machine of PyTorch `torch.save` files (whose tensors point by persistent id to
//! raw little-endian storages), without Python; the files themselves are [`crate::torch_file`].
//!
//! The reader implements the pickle opcodes `torch.save` emits (protocols 2–4) and rebuilds
//! `torch._utils._rebuild_tensor_v2` / `_rebuild_parameter` tensors; `collections.OrderedDict`
//! becomes a dict; any other class becomes an opaque object that keeps its constructor
//! arguments and `BUILD` state, so pickled `nn.Module`s can still be walked for tensors.

use std::collections::HashMap;

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

/// Why a pickle stream was refused: truncated, hostile (too deep, a memo bomb) or using an
/// opcode `torch.save` does not emit. The text says where.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct PickleError(String);

/// Parses a pickle stream (the persistent ids of `torch.save` become [`Value::Storage`]).
pub fn parse_pickle(bytes: &[u8]) -> Result<Value, PickleError> {
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
    /// An empty machine for a pickle of `len` bytes: its copy budget is 16 bytes per input
    /// byte and 1 MiB.
    fn new(len: usize) -> Self {
        Self {
            items: Vec::new(),
            marks: Vec::new(),
            copy_budget: (len as u64).saturating_mul(16) + (1 << 20),
        }
    }
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
    /// REDUCE and NEWOBJ: a callable and its arguments → the value [`reduce`] makes of them.
    fn reduce_top(&mut self) -> Result<(), String> {
        let (args, ma) = self.pop()?;
        let (callable, mc) = self.pop()?;
        let m = Meta::around([&ma, &mc]);
        self.push(reduce(callable, args)?, m)
    }
    /// DUP: the top value again, charged to the copy budget.
    fn dup(&mut self) -> Result<(), String> {
        let (v, m) = self.copy_top("DUP")?;
        self.push(v, m)
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
pub fn parse_pickle_at(bytes: &[u8], start: usize) -> Result<(Value, usize), PickleError> {
    run_machine(bytes, start).map_err(PickleError)
}

fn run_machine(bytes: &[u8], start: usize) -> Result<(Value, usize), String> {
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
    let mut st = Machine::new(bytes.len());
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
            b'q' | b'r' | 0x94 | b'h' | b'j' => memo_op(op, &mut r, &mut st, &mut memo)?,
            b'X' | 0x8c | 0x8d | b'U' | b'T' | b'B' | b'C' => st.leaf(r.string_op(op)?)?,
            b'c' => st.leaf(global_op(&mut r)?)?,
            0x93 => st.stack_global()?,
            b'Q' => st.persistent_id()?,
            b'J' | b'K' | b'M' | 0x8a | b'G' => st.leaf(number_op(op, &mut r)?)?,
            0x85..=0x87 | b't' | b'l' | 0x91 => sequence_op(op, &mut st)?,
            b'd' => st.dict()?,
            b'R' | 0x81 => st.reduce_top()?,
            b'b' => st.build()?,
            b's' => st.set_item()?,
            b'u' => st.set_items()?,
            b'a' => st.append()?,
            b'e' | 0x90 => st.appends()?,
            b'0' => {
                st.pop()?;
            }
            b'2' => st.dup()?,
            other => {
                return Err(format!(
                    "unsupported pickle opcode 0x{other:02x} at byte {}",
                    r.pos - 1
                ))
            }
        }
    }
}

/// GLOBAL: module and name, each on a line of its own → a global.
fn global_op(r: &mut Reader<'_>) -> Result<Value, String> {
    let m = r.line()?;
    let n = r.line()?;
    Ok(Value::Global(m, n))
}

/// The memo opcodes: BINPUT, LONG_BINPUT and MEMOIZE store the top of the stack, BINGET and
/// LONG_BINGET push a stored value again.
fn memo_op(
    op: u8,
    r: &mut Reader<'_>,
    st: &mut Machine,
    memo: &mut HashMap<u32, (Value, Meta)>,
) -> Result<(), String> {
    if op == b'h' || op == b'j' {
        let i = if op == b'h' { r.u8()? as u32 } else { r.u32()? };
        let (v, m) = memo.get(&i).ok_or(format!("BINGET {i}: not in memo"))?;
        let m = *m;
        st.charge(m)?;
        return st.push(v.clone(), m);
    }
    let (i, name) = match op {
        b'q' => (r.u8()? as u32, "BINPUT"),
        b'r' => (r.u32()?, "LONG_BINPUT"),
        _ => (memo.len() as u32, "MEMOIZE"),
    };
    let v = st.copy_top(name)?;
    memo.insert(i, v);
    Ok(())
}

/// The number opcodes: BININT, BININT1, BININT2, LONG1 and BINFLOAT.
fn number_op(op: u8, r: &mut Reader<'_>) -> Result<Value, String> {
    Ok(match op {
        b'J' => Value::Int(r.u32()? as i32 as i64),
        b'K' => Value::Int(r.u8()? as i64),
        b'M' => {
            let b = r.take(2)?;
            Value::Int(u16::from_le_bytes([b[0], b[1]]) as i64)
        }
        0x8a => r.long1()?,
        _ => {
            let b = r.take(8)?;
            Value::Float(f64::from_be_bytes(b.try_into().map_err(|_| "short read")?))
        }
    })
}

/// The opcodes that build a tuple or a list from the stack: TUPLE1–3, TUPLE and LIST (to the
/// mark).
fn sequence_op(op: u8, st: &mut Machine) -> Result<(), String> {
    let (items, m) = match op {
        0x85..=0x87 => st.pop_n((op - 0x84) as usize)?,
        _ => st.pop_mark()?,
    };
    let v = match op {
        b'l' | 0x91 => Value::List(items),
        _ => Value::Tuple(items),
    };
    st.push(v, m)
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
