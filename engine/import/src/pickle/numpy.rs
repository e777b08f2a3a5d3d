//! What the reader knows of numpy: the allow-listed globals, dtype strings, and how an
//! array's raw bytes decode (byte order, Fortran order, text kinds).

use talkin_data::array::{ArrayData, DType, NdArray, element_count};

/// A callable the reader knows how to interpret (never calls).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Callable {
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
pub(super) struct Dt {
    /// `None` for object arrays (`O8`): recognised, never decoded.
    pub(super) dtype: Option<DType>,
    /// Bytes per element.
    pub(super) size: usize,
    /// For text: `U` (UTF-32) or `S` (bytes).
    pub(super) text_kind: u8,
    pub(super) big_endian: bool,
}

/// The allow-list of globals.
pub(super) fn global(module: &str, name: &str) -> Result<Callable, String> {
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
pub(super) fn parse_dtype(s: &str) -> Result<Dt, String> {
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
pub(super) fn decode(
    dt: &Dt,
    raw: &[u8],
    shape: Vec<usize>,
    fortran: bool,
) -> Result<NdArray, String> {
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
