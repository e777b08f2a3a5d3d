//! The pickle stack machine. Objects live in an arena and the stack, the memo and the
//! containers hold arena indices, so a memoised object mutated later (a dict filled by
//! SETITEMS, an array set by BUILD) is seen mutated through every reference.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use super::{PickleError, Value};
use crate::array::{ArrayData, DType, NdArray, element_count};

/// Deepest nesting converted (also stops self-referencing containers).
const MAX_DEPTH: usize = 200;

/// A callable the reader knows how to interpret (never calls).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Callable {
    /// `numpy.core.multiarray._reconstruct(ndarray, (0,), b'b')`: an empty array for BUILD.
    Reconstruct,
    /// The `numpy.ndarray` class (an argument of `_reconstruct`).
    NdarrayClass,
    /// `numpy.dtype(type_string, align, copy)`.
    DtypeClass,
    /// `numpy.core.multiarray.scalar(dtype, raw_bytes)`: a numpy scalar.
    Scalar,
    /// `_codecs.encode(text, 'latin1')`: how protocol 2 writes bytes.
    CodecsEncode,
    /// `numpy.core.numeric._frombuffer(buffer, dtype, shape, order)`: protocol 5 arrays.
    FromBuffer,
}

/// numpy's element type as a dtype object carries it.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Dt {
    /// `None` for object arrays (`O8`): recognised, never decoded.
    dtype: Option<DType>,
    /// Bytes per element.
    size: usize,
    /// For text: `U` (UTF-32) or `S` (bytes).
    text_kind: u8,
    big_endian: bool,
}

#[derive(Clone, Debug)]
enum Obj {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Bytes(Vec<u8>),
    /// A Python 2 `str`: bytes, read as Latin-1 text where text is expected.
    Py2Str(Vec<u8>),
    Tuple(Vec<usize>),
    List(Vec<usize>),
    Dict(Vec<(usize, usize)>),
    Global(Callable),
    Dtype(Dt),
    /// Made by `_reconstruct`, waiting for its BUILD.
    PendingArray,
    Array(Arc<NdArray>),
}

impl Obj {
    fn kind(&self) -> &'static str {
        match self {
            Obj::None => "None",
            Obj::Bool(_) => "bool",
            Obj::Int(_) => "int",
            Obj::Float(_) => "float",
            Obj::Str(_) => "str",
            Obj::Bytes(_) => "bytes",
            Obj::Py2Str(_) => "str (Python 2)",
            Obj::Tuple(_) => "tuple",
            Obj::List(_) => "list",
            Obj::Dict(_) => "dict",
            Obj::Global(_) => "global",
            Obj::Dtype(_) => "dtype",
            Obj::PendingArray => "ndarray (not built)",
            Obj::Array(_) => "ndarray",
        }
    }
}

type Step = Result<(), String>;

struct Machine<'b> {
    bytes: &'b [u8],
    pos: usize,
    objs: Vec<Obj>,
    stack: Vec<usize>,
    marks: Vec<usize>,
    memo: HashMap<u64, usize>,
}

/// Parses a pickle (`file` is only named in errors).
pub fn parse_pickle(bytes: &[u8], file: &Path) -> Result<Value, PickleError> {
    let mut m = Machine {
        bytes,
        pos: 0,
        objs: Vec::new(),
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
    };
    let malformed = |offset, problem| PickleError::Malformed {
        file: file.into(),
        offset,
        problem,
    };
    loop {
        let at = m.pos;
        let Some(&op) = bytes.get(at) else {
            return Err(malformed(
                at,
                "truncated: the pickle ends before STOP".into(),
            ));
        };
        m.pos += 1;
        if op == b'.' {
            let root = m.pop().map_err(|p| malformed(at, format!("STOP: {p}")))?;
            let mut budget = 16 * bytes.len() + 1024;
            return m
                .convert(root, 0, &mut budget)
                .map_err(|p| malformed(at, p));
        }
        m.step(op)
            .map_err(|p| malformed(at, format!("{} ({}): {p}", opcode_name(op), hex(op))))?;
    }
}

fn hex(op: u8) -> String {
    format!("0x{op:02x}")
}

/// pickletools' name of an opcode.
fn opcode_name(op: u8) -> &'static str {
    match op {
        b'(' => "MARK",
        b'.' => "STOP",
        b'0' => "POP",
        b'1' => "POP_MARK",
        b'2' => "DUP",
        b'F' => "FLOAT",
        b'I' => "INT",
        b'J' => "BININT",
        b'K' => "BININT1",
        b'L' => "LONG",
        b'M' => "BININT2",
        b'N' => "NONE",
        b'P' => "PERSID",
        b'Q' => "BINPERSID",
        b'R' => "REDUCE",
        b'S' => "STRING",
        b'T' => "BINSTRING",
        b'U' => "SHORT_BINSTRING",
        b'V' => "UNICODE",
        b'X' => "BINUNICODE",
        b'a' => "APPEND",
        b'b' => "BUILD",
        b'c' => "GLOBAL",
        b'd' => "DICT",
        b'}' => "EMPTY_DICT",
        b'e' => "APPENDS",
        b'g' => "GET",
        b'h' => "BINGET",
        b'i' => "INST",
        b'j' => "LONG_BINGET",
        b'l' => "LIST",
        b']' => "EMPTY_LIST",
        b'o' => "OBJ",
        b'p' => "PUT",
        b'q' => "BINPUT",
        b'r' => "LONG_BINPUT",
        b's' => "SETITEM",
        b't' => "TUPLE",
        b')' => "EMPTY_TUPLE",
        b'u' => "SETITEMS",
        b'G' => "BINFLOAT",
        0x80 => "PROTO",
        0x81 => "NEWOBJ",
        0x82 => "EXT1",
        0x83 => "EXT2",
        0x84 => "EXT4",
        0x85 => "TUPLE1",
        0x86 => "TUPLE2",
        0x87 => "TUPLE3",
        0x88 => "NEWTRUE",
        0x89 => "NEWFALSE",
        0x8a => "LONG1",
        0x8b => "LONG4",
        b'B' => "BINBYTES",
        b'C' => "SHORT_BINBYTES",
        0x8c => "SHORT_BINUNICODE",
        0x8d => "BINUNICODE8",
        0x8e => "BINBYTES8",
        0x8f => "EMPTY_SET",
        0x90 => "ADDITEMS",
        0x91 => "FROZENSET",
        0x92 => "NEWOBJ_EX",
        0x93 => "STACK_GLOBAL",
        0x94 => "MEMOIZE",
        0x95 => "FRAME",
        0x96 => "BYTEARRAY8",
        0x97 => "NEXT_BUFFER",
        0x98 => "READONLY_BUFFER",
        _ => "unknown opcode",
    }
}

impl Machine<'_> {
    fn take(&mut self, n: u64) -> Result<&[u8], String> {
        let left = self.bytes.len() - self.pos;
        let n = usize::try_from(n)
            .ok()
            .filter(|&n| n <= left)
            .ok_or_else(|| format!("truncated: needs {n} bytes, {left} left"))?;
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }

    fn le<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N as u64)?);
        Ok(a)
    }

    fn line(&mut self) -> Result<String, String> {
        let rest = &self.bytes[self.pos..];
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or("truncated: no end of line")?;
        let text = String::from_utf8(rest[..end].to_vec()).map_err(|_| "the line is not UTF-8")?;
        self.pos += end + 1;
        Ok(text)
    }

    fn push(&mut self, o: Obj) {
        self.objs.push(o);
        self.stack.push(self.objs.len() - 1);
    }

    fn pop(&mut self) -> Result<usize, String> {
        if self.stack.len() <= self.marks.last().copied().unwrap_or(0) {
            return Err("the stack is empty".into());
        }
        self.stack.pop().ok_or_else(|| "the stack is empty".into())
    }

    fn top(&self) -> Result<usize, String> {
        if self.stack.len() <= self.marks.last().copied().unwrap_or(0) {
            return Err("the stack is empty".into());
        }
        self.stack
            .last()
            .copied()
            .ok_or_else(|| "the stack is empty".into())
    }

    /// Everything pushed since the last MARK, which is removed.
    fn pop_mark(&mut self) -> Result<Vec<usize>, String> {
        let m = self.marks.pop().ok_or("no MARK to pop to")?;
        Ok(self.stack.split_off(m))
    }

    fn text(&self, id: usize) -> Result<String, String> {
        match &self.objs[id] {
            Obj::Str(s) => Ok(s.clone()),
            Obj::Py2Str(b) => Ok(b.iter().map(|&c| char::from(c)).collect()),
            o => Err(format!("expected a string, found {}", o.kind())),
        }
    }

    fn tuple(&self, id: usize) -> Result<Vec<usize>, String> {
        match &self.objs[id] {
            Obj::Tuple(v) => Ok(v.clone()),
            o => Err(format!("expected a tuple, found {}", o.kind())),
        }
    }

    fn int(&self, id: usize) -> Result<i64, String> {
        match self.objs[id] {
            Obj::Int(i) => Ok(i),
            Obj::Bool(b) => Ok(i64::from(b)),
            ref o => Err(format!("expected an int, found {}", o.kind())),
        }
    }

    fn truth(&self, id: usize) -> Result<bool, String> {
        Ok(self.int(id)? != 0)
    }

    fn memo_put(&mut self, key: u64) -> Step {
        let top = self.top()?;
        self.memo.insert(key, top);
        Ok(())
    }

    fn memo_get(&mut self, key: u64) -> Step {
        let id = *self
            .memo
            .get(&key)
            .ok_or_else(|| format!("memo entry {key} was never stored"))?;
        self.stack.push(id);
        Ok(())
    }

    fn dict_insert(&mut self, dict: usize, pairs: &[usize]) -> Step {
        if !pairs.len().is_multiple_of(2) {
            return Err("an odd number of keys and values".into());
        }
        for kv in pairs.chunks_exact(2) {
            let existing = match &self.objs[dict] {
                Obj::Dict(items) => items.iter().position(|&(k, _)| self.key_eq(k, kv[0])),
                o => return Err(format!("expected a dict, found {}", o.kind())),
            };
            if let Obj::Dict(items) = &mut self.objs[dict] {
                match existing {
                    Some(i) => items[i].1 = kv[1],
                    None => items.push((kv[0], kv[1])),
                }
            }
        }
        Ok(())
    }

    /// Equality of dict keys (strings, numbers, None); other keys never collide.
    fn key_eq(&self, a: usize, b: usize) -> bool {
        match (&self.objs[a], &self.objs[b]) {
            (Obj::Str(x), Obj::Str(y)) => x == y,
            (Obj::Py2Str(x), Obj::Py2Str(y)) | (Obj::Bytes(x), Obj::Bytes(y)) => x == y,
            (Obj::Int(x), Obj::Int(y)) => x == y,
            (Obj::None, Obj::None) => true,
            _ => a == b,
        }
    }

    fn list_extend(&mut self, list: usize, items: &[usize]) -> Step {
        match &mut self.objs[list] {
            Obj::List(v) => {
                v.extend_from_slice(items);
                Ok(())
            }
            o => Err(format!("expected a list, found {}", o.kind())),
        }
    }

    fn step(&mut self, op: u8) -> Step {
        match op {
            0x80 => {
                let p = self.u8()?;
                if p > 5 {
                    return Err(format!("protocol {p} is newer than 5"));
                }
            }
            0x95 => {
                self.take(8)?;
            }
            b'(' => self.marks.push(self.stack.len()),
            b'}' => self.push(Obj::Dict(Vec::new())),
            b']' => self.push(Obj::List(Vec::new())),
            b')' => self.push(Obj::Tuple(Vec::new())),
            b'N' => self.push(Obj::None),
            0x88 => self.push(Obj::Bool(true)),
            0x89 => self.push(Obj::Bool(false)),
            b'K' => {
                let v = self.u8()?;
                self.push(Obj::Int(i64::from(v)));
            }
            b'M' => {
                let v = u16::from_le_bytes(self.le()?);
                self.push(Obj::Int(i64::from(v)));
            }
            b'J' => {
                let v = i32::from_le_bytes(self.le()?);
                self.push(Obj::Int(i64::from(v)));
            }
            0x8a => {
                let n = self.u8()?;
                let b = self.take(u64::from(n))?;
                if b.len() > 8 {
                    return Err(format!("an integer of {} bytes is too large", b.len()));
                }
                let fill = if b.last().is_some_and(|&x| x & 0x80 != 0) {
                    0xff
                } else {
                    0
                };
                let mut a = [fill; 8];
                a[..b.len()].copy_from_slice(b);
                self.push(Obj::Int(i64::from_le_bytes(a)));
            }
            b'G' => {
                let v = f64::from_be_bytes(self.le()?);
                self.push(Obj::Float(v));
            }
            b'X' => {
                let n = u32::from_le_bytes(self.le()?);
                self.unicode(u64::from(n))?;
            }
            0x8c => {
                let n = self.u8()?;
                self.unicode(u64::from(n))?;
            }
            0x8d => {
                let n = u64::from_le_bytes(self.le()?);
                self.unicode(n)?;
            }
            b'V' => {
                let raw = self.line()?;
                let s = raw_unicode_escape(&raw)?;
                self.push(Obj::Str(s));
            }
            b'C' => {
                let n = self.u8()?;
                let b = self.take(u64::from(n))?.to_vec();
                self.push(Obj::Bytes(b));
            }
            b'B' => {
                let n = u32::from_le_bytes(self.le()?);
                let b = self.take(u64::from(n))?.to_vec();
                self.push(Obj::Bytes(b));
            }
            0x8e | 0x96 => {
                let n = u64::from_le_bytes(self.le()?);
                let b = self.take(n)?.to_vec();
                self.push(Obj::Bytes(b));
            }
            b'U' => {
                let n = self.u8()?;
                let b = self.take(u64::from(n))?.to_vec();
                self.push(Obj::Py2Str(b));
            }
            b'T' => {
                let n = i32::from_le_bytes(self.le()?);
                let n = u64::try_from(n).map_err(|_| format!("negative length {n}"))?;
                let b = self.take(n)?.to_vec();
                self.push(Obj::Py2Str(b));
            }
            b't' => {
                let items = self.pop_mark()?;
                self.push(Obj::Tuple(items));
            }
            0x85..=0x87 => {
                let n = usize::from(op - 0x84);
                let mut items = Vec::with_capacity(n);
                for _ in 0..n {
                    items.push(self.pop()?);
                }
                items.reverse();
                self.push(Obj::Tuple(items));
            }
            b'l' => {
                let items = self.pop_mark()?;
                self.push(Obj::List(items));
            }
            b'a' => {
                let v = self.pop()?;
                let list = self.top()?;
                self.list_extend(list, &[v])?;
            }
            b'e' => {
                let items = self.pop_mark()?;
                let list = self.top()?;
                self.list_extend(list, &items)?;
            }
            b'd' => {
                let items = self.pop_mark()?;
                self.push(Obj::Dict(Vec::new()));
                let dict = self.top()?;
                self.dict_insert(dict, &items)?;
            }
            b's' => {
                let v = self.pop()?;
                let k = self.pop()?;
                let dict = self.top()?;
                self.dict_insert(dict, &[k, v])?;
            }
            b'u' => {
                let items = self.pop_mark()?;
                let dict = self.top()?;
                self.dict_insert(dict, &items)?;
            }
            0x94 => {
                let key = self.memo.len() as u64;
                self.memo_put(key)?;
            }
            b'q' => {
                let key = self.u8()?;
                self.memo_put(u64::from(key))?;
            }
            b'r' => {
                let key = u32::from_le_bytes(self.le()?);
                self.memo_put(u64::from(key))?;
            }
            b'h' => {
                let key = self.u8()?;
                self.memo_get(u64::from(key))?;
            }
            b'j' => {
                let key = u32::from_le_bytes(self.le()?);
                self.memo_get(u64::from(key))?;
            }
            b'c' => {
                let module = self.line()?;
                let name = self.line()?;
                let g = global(&module, &name)?;
                self.push(Obj::Global(g));
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let g = global(&self.text(module)?, &self.text(name)?)?;
                self.push(Obj::Global(g));
            }
            b'R' => {
                let args = self.pop()?;
                let callable = self.pop()?;
                let args = self.tuple(args)?;
                let obj = match self.objs[callable] {
                    Obj::Global(g) => self.reduce(g, &args)?,
                    ref o => return Err(format!("cannot call a {}", o.kind())),
                };
                self.push(obj);
            }
            b'b' => {
                let state = self.pop()?;
                let target = self.top()?;
                self.build(target, state)?;
            }
            _ => {
                return Err(
                    "not supported: only plain data (dicts, lists, tuples, strings, numbers) \
                     and numpy arrays are read"
                        .into(),
                );
            }
        }
        Ok(())
    }

    fn unicode(&mut self, n: u64) -> Step {
        let b = self.take(n)?;
        let s = std::str::from_utf8(b)
            .map_err(|_| "the string is not UTF-8")?
            .to_string();
        self.push(Obj::Str(s));
        Ok(())
    }

    /// The object a REDUCE of `g` on `args` makes, interpreted, never called.
    fn reduce(&self, g: Callable, args: &[usize]) -> Result<Obj, String> {
        let want = |n: usize| {
            if args.len() == n {
                Ok(())
            } else {
                Err(format!("{g:?} takes {n} arguments, found {}", args.len()))
            }
        };
        match g {
            Callable::Reconstruct => {
                want(3)?;
                match self.objs[args[0]] {
                    Obj::Global(Callable::NdarrayClass) => Ok(Obj::PendingArray),
                    ref o => Err(format!(
                        "_reconstruct of a {} (only numpy.ndarray is read)",
                        o.kind()
                    )),
                }
            }
            Callable::DtypeClass => {
                if args.is_empty() {
                    return Err("dtype() without a type".into());
                }
                Ok(Obj::Dtype(parse_dtype(&self.text(args[0])?)?))
            }
            Callable::Scalar => {
                want(2)?;
                let Obj::Dtype(dt) = self.objs[args[0]] else {
                    return Err("scalar() without a dtype".into());
                };
                let raw = self.raw_bytes(args[1])?;
                let a = decode(&dt, &raw, vec![], false)?;
                Ok(match a.data() {
                    ArrayData::F32(_) | ArrayData::F64(_) => {
                        Obj::Float(a.scalar_f64().ok_or("empty scalar")?)
                    }
                    ArrayData::Bool(v) => Obj::Bool(v[0]),
                    ArrayData::Str(v) => Obj::Str(v[0].clone()),
                    _ => Obj::Int(
                        a.to_i64()
                            .and_then(|v| v.first().copied())
                            .ok_or("an unsigned 64-bit scalar beyond the range of a signed one")?,
                    ),
                })
            }
            Callable::CodecsEncode => {
                if args.is_empty() || args.len() > 2 {
                    return Err("_codecs.encode takes a string and an encoding".into());
                }
                let text = self.text(args[0])?;
                if let Some(&enc) = args.get(1) {
                    let enc = self.text(enc)?.to_ascii_lowercase().replace(['-', '_'], "");
                    if !matches!(enc.as_str(), "latin1" | "iso88591" | "l1") {
                        return Err(format!("_codecs.encode to {enc} (only latin1 is read)"));
                    }
                }
                text.chars()
                    .map(|c| u8::try_from(u32::from(c)).map_err(|_| "a character beyond Latin-1"))
                    .collect::<Result<Vec<u8>, _>>()
                    .map(Obj::Bytes)
                    .map_err(String::from)
            }
            Callable::FromBuffer => {
                want(4)?;
                let raw = self.raw_bytes(args[0])?;
                let Obj::Dtype(dt) = self.objs[args[1]] else {
                    return Err("_frombuffer without a dtype".into());
                };
                let shape = self.shape(args[2])?;
                let fortran = match self.text(args[3])?.as_str() {
                    "C" => false,
                    "F" => true,
                    o => return Err(format!("unknown array order {o:?}")),
                };
                Ok(Obj::Array(Arc::new(decode(&dt, &raw, shape, fortran)?)))
            }
            Callable::NdarrayClass => Err("calling numpy.ndarray directly is not supported".into()),
        }
    }

    fn raw_bytes(&self, id: usize) -> Result<Vec<u8>, String> {
        match &self.objs[id] {
            Obj::Bytes(b) | Obj::Py2Str(b) => Ok(b.clone()),
            Obj::Str(s) => Ok(s.chars().map(|c| c as u32 as u8).collect()),
            o => Err(format!(
                "expected raw array bytes, found {} (object arrays are not read)",
                o.kind()
            )),
        }
    }

    fn shape(&self, id: usize) -> Result<Vec<usize>, String> {
        self.tuple(id)?
            .iter()
            .map(|&d| usize::try_from(self.int(d)?).map_err(|_| "a negative dimension".to_string()))
            .collect()
    }

    /// BUILD: sets a dtype's byte order or an array's contents from their state.
    fn build(&mut self, target: usize, state: usize) -> Step {
        let fields = self.tuple(state)?;
        match self.objs[target].clone() {
            Obj::Dtype(mut dt) => {
                // (version, byteorder, subarray, names, fields, elsize, alignment, flags)
                if let Some(&order) = fields.get(1) {
                    dt.big_endian = self.text(order)? == ">";
                }
                if fields.len() > 3 && !matches!(self.objs[fields[3]], Obj::None) {
                    return Err("structured dtypes are not read".into());
                }
                self.objs[target] = Obj::Dtype(dt);
                Ok(())
            }
            Obj::PendingArray => {
                // (version, shape, dtype, is_fortran, data), or without the version.
                let f = match fields.len() {
                    5 => &fields[1..],
                    4 => &fields[..],
                    n => return Err(format!("an array state of {n} items (expected 5)")),
                };
                let shape = self.shape(f[0])?;
                let Obj::Dtype(dt) = self.objs[f[1]] else {
                    return Err(format!("the array's dtype is a {}", self.objs[f[1]].kind()));
                };
                let fortran = self.truth(f[2])?;
                if dt.dtype.is_none() {
                    return Err("object arrays (dtype O) are not read".into());
                }
                let raw = self.raw_bytes(f[3])?;
                self.objs[target] = Obj::Array(Arc::new(decode(&dt, &raw, shape, fortran)?));
                Ok(())
            }
            o => Err(format!("BUILD of a {} is not supported", o.kind())),
        }
    }

    /// The value tree under arena object `id`. `budget` bounds the nodes made, so shared
    /// references cannot multiply into an exponential tree.
    fn convert(&self, id: usize, depth: usize, budget: &mut usize) -> Result<Value, String> {
        if depth > MAX_DEPTH {
            return Err(format!(
                "nested deeper than {MAX_DEPTH} levels (or a container holding itself)"
            ));
        }
        *budget = budget
            .checked_sub(1)
            .ok_or("too many shared references to expand")?;
        let seq = |v: &[usize], budget: &mut usize| {
            v.iter()
                .map(|&c| self.convert(c, depth + 1, budget))
                .collect::<Result<Vec<_>, _>>()
        };
        Ok(match &self.objs[id] {
            Obj::None => Value::None,
            Obj::Bool(b) => Value::Bool(*b),
            Obj::Int(i) => Value::Int(*i),
            Obj::Float(x) => Value::Float(*x),
            Obj::Str(s) => Value::Str(s.clone()),
            Obj::Py2Str(_) => Value::Str(self.text(id)?),
            Obj::Bytes(b) => Value::Bytes(b.clone()),
            Obj::Tuple(v) => Value::Tuple(seq(v, budget)?),
            Obj::List(v) => Value::List(seq(v, budget)?),
            Obj::Dict(items) => Value::Dict(
                items
                    .iter()
                    .map(|&(k, v)| {
                        Ok((
                            self.convert(k, depth + 1, budget)?,
                            self.convert(v, depth + 1, budget)?,
                        ))
                    })
                    .collect::<Result<_, String>>()?,
            ),
            Obj::Array(a) => Value::Array(Arc::clone(a)),
            o => return Err(format!("a {} is not plain data", o.kind())),
        })
    }
}

/// The allow-list of globals.
fn global(module: &str, name: &str) -> Result<Callable, String> {
    let numpy_core = matches!(
        module,
        "numpy.core.multiarray"
            | "numpy._core.multiarray"
            | "numpy.core._multiarray_umath"
            | "numpy._core._multiarray_umath"
    );
    Ok(match (module, name) {
        (_, "_reconstruct") if numpy_core => Callable::Reconstruct,
        (_, "scalar") if numpy_core => Callable::Scalar,
        ("numpy.core.numeric" | "numpy._core.numeric", "_frombuffer") => Callable::FromBuffer,
        ("numpy", "ndarray") => Callable::NdarrayClass,
        ("numpy", "dtype") => Callable::DtypeClass,
        ("_codecs", "encode") => Callable::CodecsEncode,
        _ => {
            return Err(format!(
                "global `{module}.{name}` is not allowed (only numpy arrays, dtypes and \
                 scalars are read)"
            ));
        }
    })
}

/// A dtype from numpy's pickled type string (`f8`, `<i4`, `b1`, `u1`, `U28`, `O8`).
fn parse_dtype(s: &str) -> Result<Dt, String> {
    let (big_endian, body) = match s.as_bytes().first() {
        Some(b'>') => (true, &s[1..]),
        Some(b'<' | b'|' | b'=') => (false, &s[1..]),
        _ => (false, s),
    };
    let bad = || format!("dtype {s:?} is not read (numbers, booleans and text only)");
    if body == "?" {
        return Ok(Dt {
            dtype: Some(DType::Bool),
            size: 1,
            text_kind: 0,
            big_endian,
        });
    }
    let kind = body.chars().next().ok_or_else(bad)?;
    let size: usize = body[kind.len_utf8()..].parse().map_err(|_| bad())?;
    let (dtype, text_kind) = match kind {
        'O' => (None, 0),
        'U' | 'S' | 'a' if size > 0 => (Some(DType::Str), kind as u8),
        'U' | 'S' | 'a' => return Err(bad()),
        _ => (DType::numeric(kind, size), 0),
    };
    if dtype.is_none() && kind != 'O' {
        return Err(bad());
    }
    Ok(Dt {
        dtype,
        // `U7` counts characters of 4 bytes each.
        size: if kind == 'U' {
            size.checked_mul(4).ok_or_else(bad)?
        } else {
            size
        },
        text_kind: if text_kind == b'a' { b'S' } else { text_kind },
        big_endian,
    })
}

/// An array of `shape` from its raw bytes.
fn decode(dt: &Dt, raw: &[u8], shape: Vec<usize>, fortran: bool) -> Result<NdArray, String> {
    let dtype = dt.dtype.ok_or("object arrays (dtype O) are not read")?;
    let count = element_count(&shape).ok_or_else(|| format!("shape {shape:?} is too large"))?;
    let needed = count
        .checked_mul(dt.size)
        .ok_or_else(|| format!("shape {shape:?} is too large"))?;
    if raw.len() != needed {
        return Err(format!(
            "shape {shape:?} of {} needs {needed} bytes of data, found {}",
            dtype,
            raw.len()
        ));
    }
    macro_rules! nums {
        ($t:ty, $variant:ident) => {{
            const W: usize = std::mem::size_of::<$t>();
            ArrayData::$variant(
                raw.chunks_exact(W)
                    .map(|c| {
                        let mut a = [0u8; W];
                        a.copy_from_slice(c);
                        if dt.big_endian {
                            <$t>::from_be_bytes(a)
                        } else {
                            <$t>::from_le_bytes(a)
                        }
                    })
                    .collect(),
            )
        }};
    }
    let data = match dtype {
        DType::Bool => ArrayData::Bool(raw.iter().map(|&b| b != 0).collect()),
        DType::I8 => nums!(i8, I8),
        DType::I16 => nums!(i16, I16),
        DType::I32 => nums!(i32, I32),
        DType::I64 => nums!(i64, I64),
        DType::U8 => ArrayData::U8(raw.to_vec()),
        DType::U16 => nums!(u16, U16),
        DType::U32 => nums!(u32, U32),
        DType::U64 => nums!(u64, U64),
        DType::F32 => nums!(f32, F32),
        DType::F64 => nums!(f64, F64),
        DType::Str => ArrayData::Str(
            raw.chunks_exact(dt.size.max(1))
                .map(|c| text_element(c, dt))
                .collect::<Result<_, _>>()?,
        ),
    };
    let array = if fortran {
        NdArray::from_fortran(shape, data)
    } else {
        NdArray::new(shape, data)
    };
    array.map_err(|e| e.to_string())
}

/// One fixed-width text element, trailing NULs removed.
fn text_element(c: &[u8], dt: &Dt) -> Result<String, String> {
    let s: String = if dt.text_kind == b'U' {
        if !c.len().is_multiple_of(4) {
            return Err("a text element not a whole number of UTF-32 units".into());
        }
        c.chunks_exact(4)
            .map(|u| {
                let u = [u[0], u[1], u[2], u[3]];
                let code = if dt.big_endian {
                    u32::from_be_bytes(u)
                } else {
                    u32::from_le_bytes(u)
                };
                char::from_u32(code).ok_or_else(|| format!("invalid code point {code:#x}"))
            })
            .collect::<Result<_, _>>()?
    } else {
        c.iter().map(|&b| char::from(b)).collect()
    };
    Ok(s.trim_end_matches('\0').to_string())
}

/// Python's raw-unicode-escape: `\uXXXX` and `\UXXXXXXXX` escapes, other bytes Latin-1.
fn raw_unicode_escape(line: &str) -> Result<String, String> {
    let mut out = String::new();
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        let width = match (c, chars.peek()) {
            ('\\', Some('u')) => 4,
            ('\\', Some('U')) => 8,
            _ => {
                out.push(c);
                continue;
            }
        };
        chars.next();
        let digits: String = (0..width).filter_map(|_| chars.next()).collect();
        let code = u32::from_str_radix(&digits, 16)
            .ok()
            .filter(|_| digits.len() == width)
            .ok_or_else(|| format!("bad escape \\u{digits}"))?;
        out.push(char::from_u32(code).ok_or_else(|| format!("invalid code point {code:#x}"))?);
    }
    Ok(out)
}
