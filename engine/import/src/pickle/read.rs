//! The pickle stack machine. Objects live in an arena, plain data as the public [`Value`]
//! and the rest (containers, numpy's pieces) as the reader's own `Obj`; the stack, the
//! memo and the containers hold arena indices, so a memoised object mutated later (a dict
//! filled by SETITEMS, an array set by BUILD) is seen mutated through every reference.

use std::collections::HashMap;
use std::path::Path;

use super::numpy::{Callable, Dt, global};
use super::opcodes::opcode_name;
use super::{PickleError, Value};

mod reconstruct;
/// Deepest nesting converted (also stops self-referencing containers).
const MAX_DEPTH: usize = 200;

/// An object on the arena: plain data as the public [`Value`] holds it, or what exists
/// only while reading.
#[derive(Clone, Debug)]
enum Obj {
    /// None, a number, a string, bytes or a built array, final as read (never a
    /// container: those are the reader's own, below).
    Plain(Value),
    /// A Python 2 `str`: bytes, read as Latin-1 text where text is expected.
    Py2Str(Vec<u8>),
    /// Containers hold arena indices, not values, until STOP: an item memoised and then
    /// filled (SETITEMS, BUILD) is seen filled through every reference, and shared items
    /// are expanded only once, under a budget.
    Tuple(Vec<usize>),
    List(Vec<usize>),
    Dict(Vec<(usize, usize)>),
    Global(Callable),
    Dtype(Dt),
    /// Made by `_reconstruct`, waiting for its BUILD.
    PendingArray,
}

impl Obj {
    fn kind(&self) -> &'static str {
        match self {
            Obj::Plain(v) => v.kind(),
            Obj::Py2Str(_) => "str (Python 2)",
            Obj::Tuple(_) => "tuple",
            Obj::List(_) => "list",
            Obj::Dict(_) => "dict",
            Obj::Global(_) => "global",
            Obj::Dtype(_) => "dtype",
            Obj::PendingArray => "ndarray (not built)",
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

    fn push_value(&mut self, v: Value) {
        self.push(Obj::Plain(v));
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
            Obj::Plain(Value::Str(s)) => Ok(s.clone()),
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
        match &self.objs[id] {
            Obj::Plain(Value::Int(i)) => Ok(*i),
            Obj::Plain(Value::Bool(b)) => Ok(i64::from(*b)),
            o => Err(format!("expected an int, found {}", o.kind())),
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
            (Obj::Plain(Value::Str(x)), Obj::Plain(Value::Str(y))) => x == y,
            (Obj::Py2Str(x), Obj::Py2Str(y))
            | (Obj::Plain(Value::Bytes(x)), Obj::Plain(Value::Bytes(y))) => x == y,
            (Obj::Plain(Value::Int(x)), Obj::Plain(Value::Int(y))) => x == y,
            (Obj::Plain(Value::None), Obj::Plain(Value::None)) => true,
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
            0x80 | 0x95 => self.step_framing(op),
            b'}' | b']' | b')' | b'N' | 0x88 | 0x89 | b'K' | b'M' | b'J' | 0x8a | b'G' => {
                self.step_scalar(op)
            }
            b'X' | 0x8c | 0x8d | b'V' | b'C' | b'B' | 0x8e | 0x96 | b'U' | b'T' => {
                self.step_text(op)
            }
            b'(' | b't' | 0x85..=0x87 | b'l' | b'a' | b'e' | b'd' | b's' | b'u' => {
                self.step_container(op)
            }
            0x94 | b'q' | b'r' | b'h' | b'j' | b'c' | 0x93 | b'R' | b'b' => self.step_object(op),
            _ => Err(
                "not supported: only plain data (dicts, lists, tuples, strings, numbers) \
                 and numpy arrays are read"
                    .into(),
            ),
        }
    }

    /// The protocol header and frames.
    fn step_framing(&mut self, op: u8) -> Step {
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
            _ => return Err(format!("opcode {op:#04x} sent to the wrong group")),
        }
        Ok(())
    }

    /// None, booleans, integers, floats and empty containers.
    fn step_scalar(&mut self, op: u8) -> Step {
        match op {
            b'}' => self.push(Obj::Dict(Vec::new())),
            b']' => self.push(Obj::List(Vec::new())),
            b')' => self.push(Obj::Tuple(Vec::new())),
            b'N' => self.push_value(Value::None),
            0x88 => self.push_value(Value::Bool(true)),
            0x89 => self.push_value(Value::Bool(false)),
            b'K' => {
                let v = self.u8()?;
                self.push_value(Value::Int(i64::from(v)));
            }
            b'M' => {
                let v = u16::from_le_bytes(self.le()?);
                self.push_value(Value::Int(i64::from(v)));
            }
            b'J' => {
                let v = i32::from_le_bytes(self.le()?);
                self.push_value(Value::Int(i64::from(v)));
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
                self.push_value(Value::Int(i64::from_le_bytes(a)));
            }
            b'G' => {
                let v = f64::from_be_bytes(self.le()?);
                self.push_value(Value::Float(v));
            }
            _ => return Err(format!("opcode {op:#04x} sent to the wrong group")),
        }
        Ok(())
    }

    /// Strings and bytes.
    fn step_text(&mut self, op: u8) -> Step {
        match op {
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
                self.push_value(Value::Str(s));
            }
            b'C' => {
                let n = self.u8()?;
                let b = self.take(u64::from(n))?.to_vec();
                self.push_value(Value::Bytes(b));
            }
            b'B' => {
                let n = u32::from_le_bytes(self.le()?);
                let b = self.take(u64::from(n))?.to_vec();
                self.push_value(Value::Bytes(b));
            }
            0x8e | 0x96 => {
                let n = u64::from_le_bytes(self.le()?);
                let b = self.take(n)?.to_vec();
                self.push_value(Value::Bytes(b));
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
            _ => return Err(format!("opcode {op:#04x} sent to the wrong group")),
        }
        Ok(())
    }

    /// Marks, tuples, lists and dicts.
    fn step_container(&mut self, op: u8) -> Step {
        match op {
            b'(' => self.marks.push(self.stack.len()),
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
            _ => return Err(format!("opcode {op:#04x} sent to the wrong group")),
        }
        Ok(())
    }

    /// The memo, globals, REDUCE and BUILD.
    fn step_object(&mut self, op: u8) -> Step {
        match op {
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
            _ => return Err(format!("opcode {op:#04x} sent to the wrong group")),
        }
        Ok(())
    }

    fn unicode(&mut self, n: u64) -> Step {
        let b = self.take(n)?;
        let s = std::str::from_utf8(b)
            .map_err(|_| "the string is not UTF-8")?
            .to_string();
        self.push_value(Value::Str(s));
        Ok(())
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
            Obj::Plain(v) => v.clone(),
            Obj::Py2Str(_) => Value::Str(self.text(id)?),
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
            o => return Err(format!("a {} is not plain data", o.kind())),
        })
    }
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
