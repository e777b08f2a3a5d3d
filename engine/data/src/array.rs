//! [`NdArray`]: a numpy array as the readers hand it over (`.npy`/`.npz` members and
//! arrays inside pickles): element type, shape and values, always in C (row-major) order.

use std::fmt;

/// Element type of an array, as numpy names it (`descr` without the byte order).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DType {
    Bool,
    I8,
    I16,
    I32,
    I64,
    U8,
    U16,
    U32,
    U64,
    F32,
    F64,
    /// Fixed-width text (`U` or `S`).
    Str,
}

impl DType {
    /// numpy's type string without byte order: `f8`, `i4`, `u1`, `b1`, `U`.
    pub fn name(self) -> &'static str {
        match self {
            DType::Bool => "b1",
            DType::I8 => "i1",
            DType::I16 => "i2",
            DType::I32 => "i4",
            DType::I64 => "i8",
            DType::U8 => "u1",
            DType::U16 => "u2",
            DType::U32 => "u4",
            DType::U64 => "u8",
            DType::F32 => "f4",
            DType::F64 => "f8",
            DType::Str => "U",
        }
    }

    /// The numeric type of kind `kind` (`b`, `i`, `u`, `f`) and `bytes` wide.
    pub fn numeric(kind: char, bytes: usize) -> Option<DType> {
        Some(match (kind, bytes) {
            ('b', 1) => DType::Bool,
            ('i', 1) => DType::I8,
            ('i', 2) => DType::I16,
            ('i', 4) => DType::I32,
            ('i', 8) => DType::I64,
            ('u', 1) => DType::U8,
            ('u', 2) => DType::U16,
            ('u', 4) => DType::U32,
            ('u', 8) => DType::U64,
            ('f', 4) => DType::F32,
            ('f', 8) => DType::F64,
            _ => return None,
        })
    }

    /// Bytes per element of a numeric type (`None` for text).
    pub fn size(self) -> Option<usize> {
        Some(match self {
            DType::Bool | DType::I8 | DType::U8 => 1,
            DType::I16 | DType::U16 => 2,
            DType::I32 | DType::U32 | DType::F32 => 4,
            DType::I64 | DType::U64 | DType::F64 => 8,
            DType::Str => return None,
        })
    }

    pub fn is_float(self) -> bool {
        matches!(self, DType::F32 | DType::F64)
    }

    pub fn is_integer(self) -> bool {
        matches!(
            self,
            DType::I8
                | DType::I16
                | DType::I32
                | DType::I64
                | DType::U8
                | DType::U16
                | DType::U32
                | DType::U64
        )
    }
}

impl fmt::Display for DType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The values of an array, typed, in C order.
#[derive(Clone, Debug, PartialEq)]
pub enum ArrayData {
    Bool(Vec<bool>),
    I8(Vec<i8>),
    I16(Vec<i16>),
    I32(Vec<i32>),
    I64(Vec<i64>),
    U8(Vec<u8>),
    U16(Vec<u16>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    F32(Vec<f32>),
    F64(Vec<f64>),
    Str(Vec<String>),
}

/// `match`es an [`ArrayData`] with `$e` for every numeric (and boolean) vector `$v` and
/// `$s` for text: for code generic over the element type.
macro_rules! each_numeric {
    ($data:expr, $v:ident => $e:expr, $str:ident => $s:expr) => {
        match $data {
            $crate::array::ArrayData::Bool($v) => $e,
            $crate::array::ArrayData::I8($v) => $e,
            $crate::array::ArrayData::I16($v) => $e,
            $crate::array::ArrayData::I32($v) => $e,
            $crate::array::ArrayData::I64($v) => $e,
            $crate::array::ArrayData::U8($v) => $e,
            $crate::array::ArrayData::U16($v) => $e,
            $crate::array::ArrayData::U32($v) => $e,
            $crate::array::ArrayData::U64($v) => $e,
            $crate::array::ArrayData::F32($v) => $e,
            $crate::array::ArrayData::F64($v) => $e,
            $crate::array::ArrayData::Str($str) => $s,
        }
    };
}
pub(crate) use each_numeric;

impl ArrayData {
    pub fn dtype(&self) -> DType {
        match self {
            ArrayData::Bool(_) => DType::Bool,
            ArrayData::I8(_) => DType::I8,
            ArrayData::I16(_) => DType::I16,
            ArrayData::I32(_) => DType::I32,
            ArrayData::I64(_) => DType::I64,
            ArrayData::U8(_) => DType::U8,
            ArrayData::U16(_) => DType::U16,
            ArrayData::U32(_) => DType::U32,
            ArrayData::U64(_) => DType::U64,
            ArrayData::F32(_) => DType::F32,
            ArrayData::F64(_) => DType::F64,
            ArrayData::Str(_) => DType::Str,
        }
    }

    pub fn len(&self) -> usize {
        each_numeric!(self, v => v.len(), s => s.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Reorders Fortran-order values (first index fastest) of `shape` into C order.
    fn fortran_to_c(self, shape: &[usize]) -> ArrayData {
        fn reorder<T: Clone>(v: Vec<T>, shape: &[usize]) -> Vec<T> {
            if shape.len() < 2 {
                return v;
            }
            // Fortran strides of each axis; walk the C-order index and gather.
            let mut f_stride = vec![1usize; shape.len()];
            for a in 1..shape.len() {
                f_stride[a] = f_stride[a - 1] * shape[a - 1];
            }
            let mut index = vec![0usize; shape.len()];
            let mut out = Vec::with_capacity(v.len());
            for _ in 0..v.len() {
                let at: usize = index.iter().zip(&f_stride).map(|(i, s)| i * s).sum();
                out.push(v[at].clone());
                for a in (0..shape.len()).rev() {
                    index[a] += 1;
                    if index[a] < shape[a] {
                        break;
                    }
                    index[a] = 0;
                }
            }
            out
        }
        match self {
            ArrayData::Bool(v) => ArrayData::Bool(reorder(v, shape)),
            ArrayData::I8(v) => ArrayData::I8(reorder(v, shape)),
            ArrayData::I16(v) => ArrayData::I16(reorder(v, shape)),
            ArrayData::I32(v) => ArrayData::I32(reorder(v, shape)),
            ArrayData::I64(v) => ArrayData::I64(reorder(v, shape)),
            ArrayData::U8(v) => ArrayData::U8(reorder(v, shape)),
            ArrayData::U16(v) => ArrayData::U16(reorder(v, shape)),
            ArrayData::U32(v) => ArrayData::U32(reorder(v, shape)),
            ArrayData::U64(v) => ArrayData::U64(reorder(v, shape)),
            ArrayData::F32(v) => ArrayData::F32(reorder(v, shape)),
            ArrayData::F64(v) => ArrayData::F64(reorder(v, shape)),
            ArrayData::Str(v) => ArrayData::Str(reorder(v, shape)),
        }
    }
}

/// A numpy array: typed values in C order and the shape (`[]` for a 0-d scalar).
#[derive(Clone, Debug, PartialEq)]
pub struct NdArray {
    shape: Vec<usize>,
    data: ArrayData,
}

/// Why [`NdArray::new`] refused its parts.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("shape {shape:?} holds {expected} values, found {found}")]
pub struct LengthMismatch {
    pub shape: Vec<usize>,
    pub expected: usize,
    pub found: usize,
}

/// Product of `shape`, or `None` on overflow.
pub fn element_count(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |a, &b| a.checked_mul(b))
}

impl NdArray {
    /// An array of `shape` holding `data` in C order.
    pub fn new(shape: Vec<usize>, data: ArrayData) -> Result<NdArray, LengthMismatch> {
        let expected = element_count(&shape).unwrap_or(usize::MAX);
        if expected != data.len() {
            return Err(LengthMismatch {
                shape,
                expected,
                found: data.len(),
            });
        }
        Ok(NdArray { shape, data })
    }

    /// An array of `shape` holding `data` in Fortran order (first index fastest).
    pub fn from_fortran(shape: Vec<usize>, data: ArrayData) -> Result<NdArray, LengthMismatch> {
        let a = NdArray::new(shape, data)?;
        Ok(NdArray {
            data: a.data.fortran_to_c(&a.shape),
            shape: a.shape,
        })
    }

    /// A float64 array (the usual fixture).
    pub fn f64(shape: &[usize], values: Vec<f64>) -> Result<NdArray, LengthMismatch> {
        NdArray::new(shape.to_vec(), ArrayData::F64(values))
    }

    /// A float32 array.
    pub fn f32(shape: &[usize], values: Vec<f32>) -> Result<NdArray, LengthMismatch> {
        NdArray::new(shape.to_vec(), ArrayData::F32(values))
    }

    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    pub fn dtype(&self) -> DType {
        self.data.dtype()
    }

    /// The typed values, C order.
    pub fn data(&self) -> &ArrayData {
        &self.data
    }

    pub fn into_data(self) -> ArrayData {
        self.data
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Every value as f64 in C order (`None` for text). 64-bit integers beyond 2^53 lose
    /// precision; booleans are 0 and 1.
    pub fn to_f64(&self) -> Option<Vec<f64>> {
        Some(match &self.data {
            ArrayData::Bool(v) => v.iter().map(|&b| f64::from(u8::from(b))).collect(),
            ArrayData::I8(v) => v.iter().map(|&x| f64::from(x)).collect(),
            ArrayData::I16(v) => v.iter().map(|&x| f64::from(x)).collect(),
            ArrayData::I32(v) => v.iter().map(|&x| f64::from(x)).collect(),
            ArrayData::I64(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::U8(v) => v.iter().map(|&x| f64::from(x)).collect(),
            ArrayData::U16(v) => v.iter().map(|&x| f64::from(x)).collect(),
            ArrayData::U32(v) => v.iter().map(|&x| f64::from(x)).collect(),
            ArrayData::U64(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::F32(v) => v.iter().map(|&x| f64::from(x)).collect(),
            ArrayData::F64(v) => v.clone(),
            ArrayData::Str(_) => return None,
        })
    }

    /// Every value as i64 if the array holds integers or booleans (`None` otherwise, or if
    /// a u64 does not fit).
    pub fn to_i64(&self) -> Option<Vec<i64>> {
        Some(match &self.data {
            ArrayData::Bool(v) => v.iter().map(|&b| i64::from(b)).collect(),
            ArrayData::I8(v) => v.iter().map(|&x| i64::from(x)).collect(),
            ArrayData::I16(v) => v.iter().map(|&x| i64::from(x)).collect(),
            ArrayData::I32(v) => v.iter().map(|&x| i64::from(x)).collect(),
            ArrayData::I64(v) => v.clone(),
            ArrayData::U8(v) => v.iter().map(|&x| i64::from(x)).collect(),
            ArrayData::U16(v) => v.iter().map(|&x| i64::from(x)).collect(),
            ArrayData::U32(v) => v.iter().map(|&x| i64::from(x)).collect(),
            ArrayData::U64(v) => v
                .iter()
                .map(|&x| i64::try_from(x).ok())
                .collect::<Option<_>>()?,
            _ => return None,
        })
    }

    /// The only value of a 0-d (or one-element) numeric array, as f64.
    pub fn scalar_f64(&self) -> Option<f64> {
        (self.len() == 1)
            .then(|| self.to_f64())
            .flatten()?
            .first()
            .copied()
    }

    /// The text of a 0-d (or one-element) string array.
    pub fn scalar_str(&self) -> Option<&str> {
        match &self.data {
            ArrayData::Str(v) if v.len() == 1 => Some(&v[0]),
            _ => None,
        }
    }

    /// Index of the first NaN or infinity (C order), for float arrays.
    pub fn first_non_finite(&self) -> Option<usize> {
        match &self.data {
            ArrayData::F32(v) => v.iter().position(|x| !x.is_finite()),
            ArrayData::F64(v) => v.iter().position(|x| !x.is_finite()),
            _ => None,
        }
    }

    /// The multi-index of flat C-order position `k`.
    pub fn unravel(&self, mut k: usize) -> Vec<usize> {
        let mut index = vec![0; self.shape.len()];
        for a in (0..self.shape.len()).rev() {
            let d = self.shape[a].max(1);
            index[a] = k % d;
            k /= d;
        }
        index
    }

    /// True if the shape matches `dims`.
    pub fn has_shape(&self, dims: &[Dim]) -> bool {
        self.shape.len() == dims.len() && self.shape.iter().zip(dims).all(|(&n, d)| d.admits(n))
    }
}

/// One axis of an expected shape, for checks and error messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dim {
    /// Exactly this length.
    Is(usize),
    /// At least this long.
    AtLeast(usize),
    /// Any length; the label names it in messages (`N`, `V`).
    Any(&'static str),
}

impl Dim {
    pub fn admits(self, n: usize) -> bool {
        match self {
            Dim::Is(k) => n == k,
            Dim::AtLeast(k) => n >= k,
            Dim::Any(_) => true,
        }
    }
}

impl fmt::Display for Dim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Dim::Is(k) => write!(f, "{k}"),
            Dim::AtLeast(k) => write!(f, ">= {k}"),
            Dim::Any(label) => f.write_str(label),
        }
    }
}

/// `(N, 165)`-style text of an expected shape; `()` for a scalar, `(3,)` for one axis.
pub fn shape_text(dims: &[Dim]) -> String {
    let parts: Vec<String> = dims.iter().map(Dim::to_string).collect();
    match parts.len() {
        1 => format!("({},)", parts[0]),
        _ => format!("({})", parts.join(", ")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fortran_order_becomes_c_order() {
        // numpy: np.asfortranarray(np.arange(6).reshape(2, 3)) stores 0 3 1 4 2 5.
        let a = NdArray::from_fortran(vec![2, 3], ArrayData::I64(vec![0, 3, 1, 4, 2, 5])).unwrap();
        assert_eq!(a.to_i64().unwrap(), vec![0, 1, 2, 3, 4, 5]);
        // 3-d: element (i, j, k) of shape (2, 3, 4) sits at i + 2 j + 6 k in Fortran order.
        let f: Vec<i64> = (0..24).collect();
        let a = NdArray::from_fortran(vec![2, 3, 4], ArrayData::I64(f)).unwrap();
        let c = a.to_i64().unwrap();
        for i in 0..2 {
            for j in 0..3 {
                for k in 0..4 {
                    assert_eq!(c[i * 12 + j * 4 + k], (i + 2 * j + 6 * k) as i64);
                }
            }
        }
        assert_eq!(a.unravel(23), vec![1, 2, 3]);
    }

    #[test]
    fn lengths_shapes_and_scalars() {
        assert!(NdArray::f64(&[2, 3], vec![0.0; 5]).is_err());
        let s = NdArray::new(vec![], ArrayData::I32(vec![30])).unwrap();
        assert_eq!(s.scalar_f64(), Some(30.0));
        assert!(s.has_shape(&[]));
        let a = NdArray::f64(&[4, 165], vec![0.0; 660]).unwrap();
        assert!(a.has_shape(&[Dim::Any("N"), Dim::Is(165)]));
        assert!(!a.has_shape(&[Dim::Any("N"), Dim::AtLeast(200)]));
        assert_eq!(shape_text(&[Dim::Any("N"), Dim::Is(165)]), "(N, 165)");
        assert_eq!(shape_text(&[Dim::Is(45)]), "(45,)");
        assert_eq!(shape_text(&[]), "()");
        let mut v = vec![1.0; 6];
        v[4] = f64::NAN;
        assert_eq!(
            NdArray::f64(&[2, 3], v).unwrap().first_non_finite(),
            Some(4)
        );
    }
}
