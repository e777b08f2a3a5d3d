//! A protocol-4 pickle writer for fixtures: the opcodes CPython's C pickler writes for
//! plain data and numpy 1.x arrays (`numpy.core.multiarray._reconstruct` + BUILD), with its
//! memo (strings and dtypes are shared as interned Python objects are; an array `Arc`
//! used twice is one object) and its framing (64 KiB frames; large bytes outside them).

use std::collections::HashMap;

use super::Value;
use talkin_data::array::{DType, NdArray};
use talkin_data::numpy_dtype::{NumpyDtype, le_bytes};

const FRAME_SIZE_TARGET: usize = 64 * 1024;
const FRAME_SIZE_MIN: usize = 4;
const BATCH: usize = 1000;

/// Writes `value` as `pickle.dumps(value, protocol=4)` does with numpy 1.x, for fixtures.
///
/// Python strings are memoised by value (as interned strings are), numpy dtypes once
/// per type (they are singletons), arrays once per `Arc` (Python object identity); a
/// `Value::Float` is a Python float. Arrays are written in C order.
pub fn write_protocol4(value: &Value) -> Vec<u8> {
    let mut w = Writer::default();
    w.out.extend([0x80, 4]);
    w.save(value);
    w.write(b".");
    w.commit_frame();
    w.out
}

#[derive(Default)]
struct Writer {
    /// Committed output.
    out: Vec<u8>,
    /// The frame being filled.
    frame: Vec<u8>,
    memo_len: u32,
    strings: HashMap<String, u32>,
    globals: HashMap<(&'static str, &'static str), u32>,
    dtypes: HashMap<NumpyDtype, u32>,
    arrays: HashMap<*const NdArray, u32>,
    small_b: Option<u32>,
}

impl Writer {
    fn write(&mut self, b: &[u8]) {
        self.frame.extend_from_slice(b);
    }

    fn commit_frame(&mut self) {
        if self.frame.len() >= FRAME_SIZE_MIN {
            self.out.push(0x95);
            self.out.extend((self.frame.len() as u64).to_le_bytes());
        }
        self.out.append(&mut self.frame);
    }

    /// A length-prefixed payload; one of 64 KiB or more goes outside any frame.
    fn write_sized(&mut self, header: &[u8], payload: &[u8]) {
        if payload.len() >= FRAME_SIZE_TARGET {
            self.commit_frame();
            self.out.extend_from_slice(header);
            self.out.extend_from_slice(payload);
        } else {
            self.write(header);
            self.write(payload);
        }
    }

    fn memoize(&mut self) -> u32 {
        self.write(&[0x94]);
        self.memo_len += 1;
        self.memo_len - 1
    }

    fn get(&mut self, index: u32) {
        match u8::try_from(index) {
            Ok(i) => self.write(&[b'h', i]),
            Err(_) => {
                self.write(b"j");
                self.write(&index.to_le_bytes());
            }
        }
    }

    /// CPython commits a frame of 64 KiB or more before saving the next object.
    fn boundary(&mut self) {
        if self.frame.len() >= FRAME_SIZE_TARGET {
            self.commit_frame();
        }
    }

    fn save(&mut self, v: &Value) {
        self.boundary();
        match v {
            Value::None => self.write(b"N"),
            Value::Bool(true) => self.write(&[0x88]),
            Value::Bool(false) => self.write(&[0x89]),
            Value::Int(i) => self.int(*i),
            Value::Float(x) => {
                self.write(b"G");
                self.write(&x.to_be_bytes());
            }
            Value::Str(s) => self.string(s),
            Value::Bytes(b) => {
                self.bytes(b);
                self.memoize();
            }
            Value::Tuple(items) => {
                self.tuple(items.len(), |w, i| w.save(&items[i]));
            }
            Value::List(items) => {
                self.write(b"]");
                self.memoize();
                self.batches(items.len(), b"a", b"e", |w, i| w.save(&items[i]));
            }
            Value::Dict(items) => {
                self.write(b"}");
                self.memoize();
                self.batches(items.len(), b"s", b"u", |w, i| {
                    w.save(&items[i].0);
                    w.save(&items[i].1);
                });
            }
            Value::Array(a) => self.array(a),
        }
    }

    /// Items of a list or dict: one alone with `single`, else batches of 1000 as
    /// MARK ... `batch` (an exact multiple of 1000 ends with an empty batch, as CPython's).
    fn batches(
        &mut self,
        n: usize,
        single: &[u8],
        batch: &[u8],
        mut item: impl FnMut(&mut Self, usize),
    ) {
        match n {
            0 => {}
            1 => {
                item(self, 0);
                self.write(single);
            }
            _ => {
                let mut i = 0;
                loop {
                    self.write(b"(");
                    let end = (i + BATCH).min(n);
                    for k in i..end {
                        item(self, k);
                    }
                    self.write(batch);
                    let done = end - i;
                    i = end;
                    if done != BATCH {
                        break;
                    }
                }
            }
        }
    }

    fn int(&mut self, i: i64) {
        self.boundary();
        if let Ok(b) = u8::try_from(i) {
            self.write(&[b'K', b]);
        } else if let Ok(b) = u16::try_from(i) {
            self.write(b"M");
            self.write(&b.to_le_bytes());
        } else if let Ok(b) = i32::try_from(i) {
            self.write(b"J");
            self.write(&b.to_le_bytes());
        } else {
            // LONG1: the shortest two's-complement little-endian bytes.
            let full = i.to_le_bytes();
            let mut n = 8;
            while n > 1 {
                let (last, prev) = (full[n - 1], full[n - 2]);
                let redundant =
                    (last == 0 && prev & 0x80 == 0) || (last == 0xff && prev & 0x80 != 0);
                if !redundant {
                    break;
                }
                n -= 1;
            }
            self.write(&[0x8a, n as u8]);
            self.write(&full[..n]);
        }
    }

    fn string(&mut self, s: &str) {
        self.boundary();
        if let Some(&i) = self.strings.get(s) {
            self.get(i);
            return;
        }
        let b = s.as_bytes();
        if let Ok(n) = u8::try_from(b.len()) {
            self.write_sized(&[0x8c, n], b);
        } else if let Ok(n) = u32::try_from(b.len()) {
            let mut h = vec![b'X'];
            h.extend(n.to_le_bytes());
            self.write_sized(&h, b);
        } else {
            let mut h = vec![0x8d];
            h.extend((b.len() as u64).to_le_bytes());
            self.write_sized(&h, b);
        }
        let i = self.memoize();
        self.strings.insert(s.to_string(), i);
    }

    /// The opcode and payload of a bytes object (no memo).
    fn bytes(&mut self, b: &[u8]) {
        self.boundary();
        if let Ok(n) = u8::try_from(b.len()) {
            self.write_sized(&[b'C', n], b);
        } else if let Ok(n) = u32::try_from(b.len()) {
            let mut h = vec![b'B'];
            h.extend(n.to_le_bytes());
            self.write_sized(&h, b);
        } else {
            let mut h = vec![0x8e];
            h.extend((b.len() as u64).to_le_bytes());
            self.write_sized(&h, b);
        }
    }

    /// A tuple of `n` items saved by `item`: TUPLE1-3 or MARK ... TUPLE, then memoised;
    /// the empty tuple is not memoised.
    fn tuple(&mut self, n: usize, mut item: impl FnMut(&mut Self, usize)) -> Option<u32> {
        self.boundary();
        match n {
            0 => {
                self.write(b")");
                None
            }
            1..=3 => {
                for i in 0..n {
                    item(self, i);
                }
                self.write(&[0x84 + n as u8]);
                Some(self.memoize())
            }
            _ => {
                self.write(b"(");
                for i in 0..n {
                    item(self, i);
                }
                self.write(b"t");
                Some(self.memoize())
            }
        }
    }

    fn global(&mut self, module: &'static str, name: &'static str) {
        self.boundary();
        if let Some(&i) = self.globals.get(&(module, name)) {
            self.get(i);
            return;
        }
        self.string(module);
        self.string(name);
        self.write(&[0x93]);
        let i = self.memoize();
        self.globals.insert((module, name), i);
    }

    /// `numpy.dtype(code, False, True)` with its state, once per type.
    fn dtype(&mut self, dtype: NumpyDtype) {
        self.boundary();
        if let Some(&i) = self.dtypes.get(&dtype) {
            self.get(i);
            return;
        }
        let code = dtype.code();
        // The state's elsize, alignment and flags as `dtype.__reduce__()` gives them: set
        // for flexible types (text: 4 bytes a character, flag 8 `NPY_NEEDS_INIT`), -1 -1 0
        // (implied by the code) for numbers.
        let (elsize, align, flags) = match dtype.dtype {
            DType::Str => (4 * dtype.width as i64, 4, 8),
            _ => (-1, -1, 0),
        };
        self.global("numpy", "dtype");
        self.tuple(3, |w, i| match i {
            0 => w.string(&code),
            1 => w.save(&Value::Bool(false)),
            _ => w.save(&Value::Bool(true)),
        });
        self.write(b"R");
        let index = self.memoize();
        let state = [
            Value::Int(3),
            Value::Str(dtype.byte_order().into()),
            Value::None,
            Value::None,
            Value::None,
            Value::Int(elsize),
            Value::Int(align),
            Value::Int(flags),
        ];
        self.tuple(state.len(), |w, i| w.save(&state[i]));
        self.write(b"b");
        self.dtypes.insert(dtype, index);
    }

    fn array(&mut self, a: &std::sync::Arc<NdArray>) {
        self.boundary();
        let key = std::sync::Arc::as_ptr(a);
        if let Some(&i) = self.arrays.get(&key) {
            self.get(i);
            return;
        }
        self.global("numpy.core.multiarray", "_reconstruct");
        self.tuple(3, |w, i| match i {
            0 => w.global("numpy", "ndarray"),
            1 => {
                w.tuple(1, |w, _| w.int(0));
            }
            _ => match w.small_b {
                Some(m) => {
                    w.boundary();
                    w.get(m)
                }
                None => {
                    w.bytes(b"b");
                    w.small_b = Some(w.memoize());
                }
            },
        });
        self.write(b"R");
        let index = self.memoize();
        let dtype = NumpyDtype::of(a);
        let raw = le_bytes(a);
        let shape = a.shape().to_vec();
        self.tuple(5, |w, i| match i {
            0 => w.int(1),
            1 => {
                w.tuple(shape.len(), |w, k| w.int(shape[k] as i64));
            }
            2 => w.dtype(dtype),
            3 => w.save(&Value::Bool(false)),
            _ => {
                w.bytes(&raw);
                w.memoize();
            }
        });
        self.write(b"b");
        self.arrays.insert(key, index);
    }
}
