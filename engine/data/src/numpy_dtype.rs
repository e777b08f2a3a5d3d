//! How numpy lays out an [`NdArray`] that we write: its dtype as numpy spells it (`<f8`,
//! `|u1`, `<U5`: byte order, kind and size) and its data bytes (little-endian, C order;
//! text as fixed-width UTF-32LE, `<U{width}` with the width of the longest string in
//! characters). The `.npy` writer ([`crate::npz::npy_bytes`]) and the pickle writer
//! (`talkin_import::pickle::write_protocol4`) both take the layout from here.

use crate::array::{ArrayData, DType, NdArray};

/// An array's element type as numpy names it, with the width of a text element.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct NumpyDtype {
    pub dtype: DType,
    /// Characters per text element (`U{width}`); 0 for numbers.
    pub width: usize,
}

impl NumpyDtype {
    /// The dtype numpy gives `array`'s values; text is as wide as its longest string, and
    /// at least 1 (numpy makes `np.array([''])` a `<U1`).
    pub fn of(array: &NdArray) -> NumpyDtype {
        let width = match array.data() {
            ArrayData::Str(v) => v.iter().map(|s| s.chars().count()).max().unwrap_or(0),
            _ => 0,
        };
        let dtype = array.dtype();
        NumpyDtype {
            dtype,
            width: if dtype == DType::Str { width.max(1) } else { 0 },
        }
    }

    /// numpy's byte-order character for the data [`le_bytes`] writes: `|` (none) for
    /// one-byte types, `<` otherwise (text included: its units are 4-byte code points).
    pub fn byte_order(self) -> &'static str {
        match self.dtype {
            DType::Bool | DType::I8 | DType::U8 => "|",
            _ => "<",
        }
    }

    /// The type code without byte order: `f8`, `b1`, `U5`.
    pub fn code(self) -> String {
        match self.dtype {
            DType::Str => format!("U{}", self.width),
            dtype => dtype.name().to_string(),
        }
    }

    /// The `descr` of a `.npy` header: byte order and type code, `<f8`, `|b1`, `<U5`.
    pub fn descr(self) -> String {
        format!("{}{}", self.byte_order(), self.code())
    }
}

/// `array`'s data as numpy stores it with the dtype [`NumpyDtype::of`] gives: C order,
/// little-endian, booleans as one byte 0 or 1, each string as UTF-32LE code points padded
/// with NULs to the width.
pub fn le_bytes(array: &NdArray) -> Vec<u8> {
    macro_rules! le {
        ($v:expr) => {
            $v.iter().flat_map(|x| x.to_le_bytes()).collect()
        };
    }
    match array.data() {
        ArrayData::Bool(v) => v.iter().map(|&b| u8::from(b)).collect(),
        ArrayData::I8(v) => le!(v),
        ArrayData::I16(v) => le!(v),
        ArrayData::I32(v) => le!(v),
        ArrayData::I64(v) => le!(v),
        ArrayData::U8(v) => v.clone(),
        ArrayData::U16(v) => le!(v),
        ArrayData::U32(v) => le!(v),
        ArrayData::U64(v) => le!(v),
        ArrayData::F32(v) => le!(v),
        ArrayData::F64(v) => le!(v),
        ArrayData::Str(v) => {
            let width = NumpyDtype::of(array).width;
            let mut raw = Vec::with_capacity(v.len() * width * 4);
            for s in v {
                let n = s.chars().count();
                for c in s.chars() {
                    raw.extend(u32::from(c).to_le_bytes());
                }
                raw.extend(std::iter::repeat_n(0u8, 4 * (width - n)));
            }
            raw
        }
    }
}
