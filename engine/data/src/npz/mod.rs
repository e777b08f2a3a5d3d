//! `.npy` and `.npz` files as numpy writes them (`np.save`, `np.savez`,
//! `np.savez_compressed`): numeric, boolean and text arrays by name, C or Fortran order,
//! any byte order, 0-d scalars included.
//!
//! The `.npy` format is parsed by the `npyz` crate; the zip archive around the members by
//! `zip` (which reads numpy's zip64 headers and deflate). Object arrays (`descr` `|O`,
//! whose payload is a pickle, such as the SMPL-X model's `part2num`) are never decoded:
//! [`Npz::read`] refuses them with [`NpzError::Pickled`] and [`Npz::read_all`] lists them
//! as skipped. Every error names the file and the array; a truncated or corrupt file is
//! an error, never a panic.
//!
//! ```no_run
//! use talkin_data::array::Dim;
//! use talkin_data::npz::Npz;
//!
//! let mut npz = Npz::open("motion.npz")?;
//! let poses = npz.read_checked("poses", &[Dim::Any("N"), Dim::Is(165)])?;
//! let rate = npz.get("mocap_frame_rate")?.and_then(|a| a.scalar_f64());
//! # Ok::<(), talkin_data::npz::NpzError>(())
//! ```
//!
//! For fixtures, [`NpzWriter`] writes archives the way `np.savez` does (members stored,
//! `<name>.npy`), numeric and text members through npyz's writer.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use npyz::{Order, TypeChar, WriterBuilder};

use crate::array::{ArrayData, DType, Dim, NdArray, each_numeric, shape_text};
use crate::numpy_dtype::NumpyDtype;

/// Why an `.npy`/`.npz` file or one of its arrays was rejected. Every variant names the
/// file; all but `Io` and `Archive` name the array.
#[derive(Debug, thiserror::Error)]
pub enum NpzError {
    #[error("{}: {source}", file.display())]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: not a readable .npz (zip) archive: {problem}", file.display())]
    Archive { file: PathBuf, problem: String },
    #[error("{}: array `{array}` is missing (expected shape {expected})", file.display())]
    Missing {
        file: PathBuf,
        array: String,
        expected: String,
    },
    #[error("{}: array `{array}`: {problem}", file.display())]
    Corrupt {
        file: PathBuf,
        array: String,
        problem: String,
    },
    #[error(
        "{}: array `{array}` holds pickled Python objects (descr '|O'), which are not read",
        file.display()
    )]
    Pickled { file: PathBuf, array: String },
    #[error("{}: array `{array}`: expected shape {expected}, found {found:?}", file.display())]
    Shape {
        file: PathBuf,
        array: String,
        expected: String,
        found: Vec<usize>,
    },
    #[error("{}: array `{array}`: expected {expected} values, found dtype {found}", file.display())]
    DType {
        file: PathBuf,
        array: String,
        expected: &'static str,
        found: String,
    },
    #[error("{}: array `{array}`: non-finite value {value} at {index:?}", file.display())]
    NonFinite {
        file: PathBuf,
        array: String,
        index: Vec<usize>,
        value: f64,
    },
}

/// What an archive holds: its readable arrays and the names of the members it skipped
/// (object arrays).
#[derive(Clone, Debug, Default)]
pub struct NpzContents {
    pub arrays: BTreeMap<String, NdArray>,
    pub skipped: Vec<String>,
}

/// An open `.npz` archive; arrays are read on demand.
pub struct Npz {
    file: PathBuf,
    zip: zip::ZipArchive<BufReader<File>>,
    names: Vec<String>,
}

impl std::fmt::Debug for Npz {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Npz")
            .field("file", &self.file)
            .field("names", &self.names)
            .finish()
    }
}

impl Npz {
    /// Opens `path` and lists its arrays (members named `<array>.npy`).
    pub fn open(path: impl AsRef<Path>) -> Result<Npz, NpzError> {
        let file = path.as_ref().to_path_buf();
        let f = File::open(&file).map_err(|source| NpzError::Io {
            file: file.clone(),
            source,
        })?;
        let zip = zip::ZipArchive::new(BufReader::new(f)).map_err(|e| NpzError::Archive {
            file: file.clone(),
            problem: e.to_string(),
        })?;
        let names = zip
            .file_names()
            .filter_map(|n| n.strip_suffix(".npy"))
            .map(str::to_string)
            .collect();
        Ok(Npz { file, zip, names })
    }

    /// The archive's path, as errors name it.
    pub fn file(&self) -> &Path {
        &self.file
    }

    /// Names of the arrays, in archive order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    pub fn contains(&self, name: &str) -> bool {
        self.names.iter().any(|n| n == name)
    }

    /// The raw bytes of member `<name>.npy`, or `None` if absent. A member that says or
    /// turns out to be larger than [`MAX_MEMBER_BYTES`] is refused before it is read (a
    /// few bytes of deflate can claim gigabytes).
    fn member(&mut self, name: &str) -> Result<Option<Vec<u8>>, NpzError> {
        let mut bytes = Vec::new();
        let too_large = |size: u64| {
            format!("member of {size} bytes is larger than the {MAX_MEMBER_BYTES} bytes read")
        };
        let read = match self.zip.by_name(&format!("{name}.npy")) {
            Ok(entry) if entry.size() > MAX_MEMBER_BYTES => Err(too_large(entry.size())),
            Ok(entry) => match entry.take(MAX_MEMBER_BYTES + 1).read_to_end(&mut bytes) {
                Ok(n) if n as u64 > MAX_MEMBER_BYTES => Err(too_large(n as u64)),
                Ok(_) => Ok(()),
                Err(e) => Err(format!("truncated or corrupt member: {e}")),
            },
            Err(zip::result::ZipError::FileNotFound) => return Ok(None),
            Err(e) => Err(format!("cannot open the member: {e}")),
        };
        read.map_err(|problem| self.corrupt(name, problem))?;
        Ok(Some(bytes))
    }

    fn corrupt(&self, array: &str, problem: String) -> NpzError {
        NpzError::Corrupt {
            file: self.file.clone(),
            array: array.into(),
            problem,
        }
    }

    /// Array `name`, or `None` if the archive has no such member.
    pub fn get(&mut self, name: &str) -> Result<Option<NdArray>, NpzError> {
        match self.member(name)? {
            None => Ok(None),
            Some(bytes) => parse_npy(&bytes, &self.file, name).map(Some),
        }
    }

    /// Array `name`; a missing one is an error.
    pub fn read(&mut self, name: &str) -> Result<NdArray, NpzError> {
        self.get(name)?.ok_or_else(|| NpzError::Missing {
            file: self.file.clone(),
            array: name.into(),
            expected: "any".into(),
        })
    }

    /// Array `name`, which must exist, hold numbers (integers or floats), have shape `dims`
    /// and, if floating point, hold no NaN or infinity.
    pub fn read_checked(&mut self, name: &str, dims: &[Dim]) -> Result<NdArray, NpzError> {
        let a = self.get(name)?.ok_or_else(|| NpzError::Missing {
            file: self.file.clone(),
            array: name.into(),
            expected: shape_text(dims),
        })?;
        check_array(&a, &self.file, name, dims)?;
        Ok(a)
    }

    /// Like [`Npz::read_checked`], but `None` when the array is absent.
    pub fn get_checked(&mut self, name: &str, dims: &[Dim]) -> Result<Option<NdArray>, NpzError> {
        match self.get(name)? {
            None => Ok(None),
            Some(a) => {
                check_array(&a, &self.file, name, dims)?;
                Ok(Some(a))
            }
        }
    }

    /// Every array; object arrays are listed in `skipped`, never decoded.
    pub fn read_all(&mut self) -> Result<NpzContents, NpzError> {
        let mut out = NpzContents::default();
        for name in self.names.clone() {
            match self.get(&name) {
                Ok(Some(a)) => {
                    out.arrays.insert(name, a);
                }
                Ok(None) => {}
                Err(NpzError::Pickled { .. }) => out.skipped.push(name),
                Err(e) => return Err(e),
            }
        }
        Ok(out)
    }
}

/// Checks that `a` (array `name` of `file`) holds numbers of shape `dims`, all finite.
pub fn check_array(a: &NdArray, file: &Path, name: &str, dims: &[Dim]) -> Result<(), NpzError> {
    if !(a.dtype().is_float() || a.dtype().is_integer() || a.dtype() == DType::Bool) {
        return Err(NpzError::DType {
            file: file.into(),
            array: name.into(),
            expected: "numeric",
            found: a.dtype().to_string(),
        });
    }
    if !a.has_shape(dims) {
        return Err(NpzError::Shape {
            file: file.into(),
            array: name.into(),
            expected: shape_text(dims),
            found: a.shape().to_vec(),
        });
    }
    if let Some(k) = a.first_non_finite() {
        return Err(NpzError::NonFinite {
            file: file.into(),
            array: name.into(),
            index: a.unravel(k),
            value: a.to_f64().map_or(f64::NAN, |v| v[k]),
        });
    }
    Ok(())
}

/// Reads a single `.npy` file; errors name the file and, as the array, its stem.
pub fn read_npy(path: impl AsRef<Path>) -> Result<NdArray, NpzError> {
    let file = path.as_ref();
    let bytes = std::fs::read(file).map_err(|source| NpzError::Io {
        file: file.into(),
        source,
    })?;
    let name = file
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    parse_npy(&bytes, file, &name)
}

/// The largest `.npy` member of an archive that is read: 1 GiB, ten times the largest real
/// one (SMPL-X's `shapedirs`, 10 475 x 3 x 400 float64, ~100 MB).
pub const MAX_MEMBER_BYTES: u64 = 1 << 30;
/// The most elements an array may claim: 2^28, checked before any is decoded (a text
/// array of zero-width elements needs no bytes of data for any count).
pub const MAX_ELEMENTS: usize = 1 << 28;

/// The header of a `.npy` is at most this long (numpy itself refuses 10 000 by default).
const MAX_HEADER: usize = 1 << 16;
/// Nesting of brackets allowed in a header: a real one nests two deep.
const MAX_HEADER_NESTING: usize = 16;

/// Checks what npyz trusts: the header length, its bracket nesting (its parser recurses)
/// and that the shape's products fit (it multiplies unchecked).
fn precheck_header(bytes: &[u8]) -> Result<(), String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy array (bad magic)".into());
    }
    let (len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        v => return Err(format!(".npy version {v} is not supported (1, 2 or 3)")),
    };
    if len > MAX_HEADER {
        return Err(format!("header of {len} bytes is too long"));
    }
    let header = bytes
        .get(start..start + len)
        .ok_or("truncated .npy header")?;
    let mut depth = 0usize;
    for &c in header {
        match c {
            b'(' | b'[' | b'{' => {
                depth += 1;
                if depth > MAX_HEADER_NESTING {
                    return Err("malformed header (nested too deep)".into());
                }
            }
            b')' | b']' | b'}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    let text = String::from_utf8_lossy(header);
    if let Some(at) = text.find("'shape'") {
        let rest = &text[at..];
        if let (Some(open), Some(close)) = (rest.find('('), rest.find(')'))
            && open < close
        {
            // npyz multiplies the dims in both orders for its strides, so every partial
            // product must fit, not only the whole one: a zero dim does not save
            // (0, 2^31, 2^40), whose strides overflow.
            let mut count: u64 = 1;
            for dim in rest[open + 1..close].split(',').map(str::trim) {
                if let Ok(d) = dim.parse::<u64>().map(|d| d.max(1)) {
                    count = count.checked_mul(d).ok_or_else(|| {
                        format!("shape ({}) is too large", &rest[open + 1..close])
                    })?;
                }
            }
        }
    }
    Ok(())
}

/// Parses the bytes of a `.npy` (array `name` of `file`, as errors name it).
pub fn parse_npy(bytes: &[u8], file: &Path, name: &str) -> Result<NdArray, NpzError> {
    let corrupt = |problem: String| NpzError::Corrupt {
        file: file.into(),
        array: name.into(),
        problem,
    };
    precheck_header(bytes).map_err(corrupt)?;
    let npy = npyz::NpyFile::new(bytes).map_err(|e| corrupt(format!("bad .npy header: {e}")))?;
    if npy.uses_pickled_array() {
        return Err(NpzError::Pickled {
            file: file.into(),
            array: name.into(),
        });
    }
    let descr = npy.dtype().descr();
    let unsupported = || NpzError::DType {
        file: file.into(),
        array: name.into(),
        expected: "boolean, integer, float or text",
        found: descr.clone(),
    };
    let npyz::DType::Plain(ty) = npy.dtype() else {
        return Err(unsupported());
    };
    let shape = npy
        .shape()
        .iter()
        .map(|&d| usize::try_from(d))
        .collect::<Result<Vec<usize>, _>>()
        .map_err(|_| corrupt("shape does not fit in memory".into()))?;
    let count = crate::array::element_count(&shape)
        .filter(|&n| n <= MAX_ELEMENTS)
        .ok_or_else(|| {
            corrupt(format!(
                "shape {shape:?} is too large (at most {MAX_ELEMENTS} elements are read)"
            ))
        })?;
    let item = ty
        .num_bytes()
        .ok_or_else(|| corrupt(format!("dtype {descr} is too large")))?;
    let header_len = bytes.len() - data_len(bytes);
    let needed = count
        .checked_mul(item)
        .ok_or_else(|| corrupt(format!("shape {shape:?} is too large")))?;
    let found = bytes.len() - header_len;
    if found != needed {
        return Err(corrupt(format!(
            "shape {shape:?} of {descr} needs {needed} bytes of data, found {found} (truncated or corrupt)"
        )));
    }
    let order = npy.order();
    let size = ty.size_field() as usize;
    let decode_err = |e: std::io::Error| corrupt(format!("cannot decode {descr} data: {e}"));
    let data = match (ty.type_char(), size) {
        (TypeChar::Bool, 1) => ArrayData::Bool(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Int, 1) => ArrayData::I8(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Int, 2) => ArrayData::I16(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Int, 4) => ArrayData::I32(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Int, 8) => ArrayData::I64(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Uint, 1) => ArrayData::U8(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Uint, 2) => ArrayData::U16(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Uint, 4) => ArrayData::U32(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Uint, 8) => ArrayData::U64(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Float, 4) => ArrayData::F32(npy.into_vec().map_err(decode_err)?),
        (TypeChar::Float, 8) => ArrayData::F64(npy.into_vec().map_err(decode_err)?),
        (TypeChar::UnicodeStr | TypeChar::ByteStr, _) => {
            ArrayData::Str(npy.into_vec().map_err(decode_err)?)
        }
        _ => return Err(unsupported()),
    };
    let array = match order {
        Order::C => NdArray::new(shape, data),
        Order::Fortran => NdArray::from_fortran(shape, data),
    };
    array.map_err(|e| corrupt(e.to_string()))
}

/// Bytes after the header of a `.npy` whose header passed [`precheck_header`].
fn data_len(bytes: &[u8]) -> usize {
    let (len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
    };
    bytes.len() - start - len
}

/// The `.npy` bytes of `array` (little-endian, C order, the dtype numpy would give it),
/// written by npyz.
pub fn npy_bytes(array: &NdArray) -> std::io::Result<Vec<u8>> {
    let descr = NumpyDtype::of(array).descr();
    let dtype = npyz::DType::Plain(descr.parse().map_err(std::io::Error::other)?);
    let shape: Vec<u64> = array.shape().iter().map(|&d| d as u64).collect();
    let mut out = Vec::new();
    each_numeric!(
        array.data(),
        v => write_npy(&mut out, &dtype, &shape, v),
        s => write_npy(&mut out, &dtype, &shape, s)
    )?;
    Ok(out)
}

/// Appends a `.npy` of `values` (C order, of `shape`) to `out`.
fn write_npy<T: npyz::Serialize>(
    out: &mut Vec<u8>,
    dtype: &npyz::DType,
    shape: &[u64],
    values: &[T],
) -> std::io::Result<()> {
    let mut w = npyz::WriteOptions::new()
        .dtype(dtype.clone())
        .shape(shape)
        .writer(out)
        .begin_nd()?;
    for x in values {
        w.push(x)?;
    }
    w.finish()
}

/// The `.npy` bytes numpy writes for a 0-d object array holding `pickle` (e.g. the SMPL-X
/// model's `joint2num`): for fixtures of files with members that must be skipped.
pub fn object_npy_bytes(pickle: &[u8]) -> Vec<u8> {
    raw_npy_bytes(
        "{'descr': '|O', 'fortran_order': False, 'shape': (), }",
        pickle,
    )
}

/// A version 1.0 `.npy` file: magic, the header dict `dict` padded with spaces and a
/// newline to a multiple of 64 bytes, then `data` as is (whatever the dict claims: how
/// tests build files with hostile headers).
pub fn raw_npy_bytes(dict: &str, data: &[u8]) -> Vec<u8> {
    let mut header = dict.to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((header.len() as u16).to_le_bytes());
    out.extend(header.as_bytes());
    out.extend(data);
    out
}

/// Writes `.npz` archives as `np.savez` does (uncompressed members `<name>.npy`), for
/// fixtures.
pub struct NpzWriter {
    zip: zip::ZipWriter<BufWriter<File>>,
}

impl NpzWriter {
    pub fn create(path: impl AsRef<Path>) -> std::io::Result<NpzWriter> {
        Ok(NpzWriter {
            zip: zip::ZipWriter::new(BufWriter::new(File::create(path)?)),
        })
    }

    /// Adds `array` as member `<name>.npy`.
    pub fn array(&mut self, name: &str, array: &NdArray) -> std::io::Result<&mut Self> {
        let bytes = npy_bytes(array)?;
        self.raw(name, &bytes)
    }

    /// Adds member `<name>.npy` holding `npy` verbatim.
    pub fn raw(&mut self, name: &str, npy: &[u8]) -> std::io::Result<&mut Self> {
        let options = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Stored);
        self.zip
            .start_file(format!("{name}.npy"), options)
            .map_err(std::io::Error::other)?;
        self.zip.write_all(npy)?;
        Ok(self)
    }

    pub fn finish(self) -> std::io::Result<()> {
        let mut w = self.zip.finish().map_err(std::io::Error::other)?;
        w.flush()
    }
}

#[cfg(test)]
mod tests;
