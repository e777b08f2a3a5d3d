//! numpy's reconstruction, interpreted on the arena: REDUCE of the allow-listed globals
//! (`_reconstruct`, `dtype`, `scalar`, `_frombuffer`, `_codecs.encode`) and BUILD of an
//! array from its state tuple. Nothing is ever called.

use super::super::Value;
use super::super::numpy::{Callable, decode, parse_dtype};
use super::{Machine, Obj, Step};
use talkin_data::array::ArrayData;

impl Machine<'_> {
    /// The object a REDUCE of `g` on `args` makes, interpreted, never called.
    pub(super) fn reduce(&self, g: Callable, args: &[usize]) -> Result<Obj, String> {
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
                Ok(Obj::Plain(match a.data() {
                    ArrayData::F32(_) | ArrayData::F64(_) => {
                        Value::Float(a.scalar_f64().ok_or("empty scalar")?)
                    }
                    ArrayData::Bool(v) => Value::Bool(v[0]),
                    ArrayData::Str(v) => Value::Str(v[0].clone()),
                    _ => Value::Int(
                        a.to_i64()
                            .and_then(|v| v.first().copied())
                            .ok_or("an unsigned 64-bit scalar beyond the range of a signed one")?,
                    ),
                }))
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
                    .map(|b| Obj::Plain(Value::Bytes(b)))
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
                Ok(Obj::Plain(Value::array(decode(&dt, &raw, shape, fortran)?)))
            }
            Callable::NdarrayClass => Err("calling numpy.ndarray directly is not supported".into()),
        }
    }

    fn raw_bytes(&self, id: usize) -> Result<Vec<u8>, String> {
        match &self.objs[id] {
            Obj::Plain(Value::Bytes(b)) | Obj::Py2Str(b) => Ok(b.clone()),
            Obj::Plain(Value::Str(s)) => Ok(s.chars().map(|c| c as u32 as u8).collect()),
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
    pub(super) fn build(&mut self, target: usize, state: usize) -> Step {
        let fields = self.tuple(state)?;
        match self.objs[target].clone() {
            Obj::Dtype(mut dt) => {
                // (version, byteorder, subarray, names, fields, elsize, alignment, flags)
                if let Some(&order) = fields.get(1) {
                    dt.big_endian = self.text(order)? == ">";
                }
                if fields.len() > 3 && !matches!(self.objs[fields[3]], Obj::Plain(Value::None)) {
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
                self.objs[target] = Obj::Plain(Value::array(decode(&dt, &raw, shape, fortran)?));
                Ok(())
            }
            o => Err(format!("BUILD of a {} is not supported", o.kind())),
        }
    }
}
