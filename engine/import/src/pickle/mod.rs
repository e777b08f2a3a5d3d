//! Python pickles of plain data and numpy arrays, read without Python and without running
//! any code: what HumanNeRF's `pickle.dump` of dicts (of dicts) of arrays writes
//! (`cameras.pkl`, `mesh_infos.pkl`, `canonical_joints.pkl`), in protocols 2 to 5, from
//! numpy 1.x (`numpy.core`) or 2.x (`numpy._core`), and Python 2's protocol 2.
//!
//! The reader ([`parse_pickle`], [`read_pickle`]) is a small stack machine over the
//! opcodes such files use. Globals are resolved against an allow-list (numpy's
//! `_reconstruct`, `ndarray`, `dtype`, `scalar`, `_frombuffer` and `_codecs.encode`) and
//! `REDUCE`/`BUILD` are interpreted for exactly those: an array is rebuilt from its state
//! tuple (version, shape, dtype, Fortran flag, raw bytes), never by calling anything. Any
//! other opcode or global is an error naming it and its byte offset. The memo holds shared
//! references: an array memoised before its `BUILD` and fetched again later (the same
//! camera matrix in every frame) is the built array everywhere.
//!
//! [`write_protocol4`] writes the opcode sequence that CPython's pickler with numpy 1.x
//! writes for the same data (protocol 4), for test fixtures in HumanNeRF's layout.
//!
//! ```
//! use talkin_data::array::NdArray;
//! use talkin_import::pickle::{Value, parse_pickle, write_protocol4};
//!
//! let k = NdArray::f32(&[3, 3], vec![500., 0., 64., 0., 500., 64., 0., 0., 1.]).unwrap();
//! let cameras = Value::dict([("frame_000000", Value::dict([("intrinsics", Value::array(k))]))]);
//! let bytes = write_protocol4(&cameras);
//! let back = parse_pickle(&bytes, "cameras.pkl".as_ref()).unwrap();
//! let k = back.get("frame_000000").and_then(|f| f.get("intrinsics")).unwrap();
//! assert_eq!(k.as_array().unwrap().shape(), &[3, 3]);
//! ```

mod numpy;
mod opcodes;
mod read;
mod write;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use talkin_data::array::NdArray;

pub use read::parse_pickle;
pub use write::write_protocol4;

/// A value read from a pickle.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    None,
    Bool(bool),
    Int(i64),
    /// A Python float or a numpy floating-point scalar.
    Float(f64),
    /// A Python 3 `str`, or a Python 2 `str` decoded as Latin-1 (as
    /// `pickle.load(f, encoding="latin1")` does).
    Str(String),
    Bytes(Vec<u8>),
    Tuple(Vec<Value>),
    List(Vec<Value>),
    /// Items in insertion order.
    Dict(Vec<(Value, Value)>),
    /// A numpy array; one shared `Arc` where the pickle shares the object.
    Array(Arc<NdArray>),
}

impl Value {
    /// A dict with string keys.
    pub fn dict<K: Into<String>>(items: impl IntoIterator<Item = (K, Value)>) -> Value {
        Value::Dict(
            items
                .into_iter()
                .map(|(k, v)| (Value::Str(k.into()), v))
                .collect(),
        )
    }

    pub fn array(a: NdArray) -> Value {
        Value::Array(Arc::new(a))
    }

    /// The value under string key `key` of a dict.
    pub fn get(&self, key: &str) -> Option<&Value> {
        match self {
            Value::Dict(items) => items
                .iter()
                .find(|(k, _)| matches!(k, Value::Str(s) if s == key))
                .map(|(_, v)| v),
            _ => None,
        }
    }

    /// The items of a dict.
    pub fn as_dict(&self) -> Option<&[(Value, Value)]> {
        match self {
            Value::Dict(items) => Some(items),
            _ => None,
        }
    }

    pub fn as_array(&self) -> Option<&NdArray> {
        match self {
            Value::Array(a) => Some(a),
            _ => None,
        }
    }

    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }

    /// A number: a float, an int, a bool or a one-element numeric array.
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Value::Float(x) => Some(*x),
            Value::Int(i) => Some(*i as f64),
            Value::Bool(b) => Some(f64::from(u8::from(*b))),
            Value::Array(a) => a.scalar_f64(),
            _ => None,
        }
    }

    /// A short name of the kind of value, for messages.
    pub fn kind(&self) -> &'static str {
        match self {
            Value::None => "None",
            Value::Bool(_) => "bool",
            Value::Int(_) => "int",
            Value::Float(_) => "float",
            Value::Str(_) => "str",
            Value::Bytes(_) => "bytes",
            Value::Tuple(_) => "tuple",
            Value::List(_) => "list",
            Value::Dict(_) => "dict",
            Value::Array(_) => "ndarray",
        }
    }
}

/// Why a pickle could not be read.
#[derive(Debug, thiserror::Error)]
pub enum PickleError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: pickle byte {offset}: {problem}", file.display())]
    Malformed {
        file: PathBuf,
        /// Offset of the opcode at fault (or of the end, for truncation).
        offset: usize,
        problem: String,
    },
}

/// Reads and parses the pickle file `path`.
pub fn read_pickle(path: impl AsRef<Path>) -> Result<Value, PickleError> {
    let file = path.as_ref();
    let bytes = std::fs::read(file).map_err(|source| PickleError::Io {
        file: file.into(),
        source,
    })?;
    parse_pickle(&bytes, file)
}

#[cfg(test)]
mod tests;
