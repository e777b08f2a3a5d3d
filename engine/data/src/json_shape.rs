//! Reading fixed-shape numeric arrays out of JSON with errors that name the field, the
//! expected shape and what was found. serde's own messages ("invalid length 20") do not
//! say which of a thousand frames was wrong.

use serde_json::Value;

/// A JSON value that is not the shape (or not finite) where a field demands it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("field `{field}`: expected {expected}, found {found}")]
pub struct ShapeError {
    /// Full path of the field, e.g. `frames[12].params.body_pose`.
    pub field: String,
    pub expected: String,
    pub found: String,
}

fn describe(v: &Value) -> String {
    match v {
        Value::Null => "null".into(),
        Value::Bool(_) => "a boolean".into(),
        Value::Number(n) => format!("the number {n}"),
        Value::String(s) => format!("the string {s:?}"),
        Value::Array(a) => format!("an array of {} elements", a.len()),
        Value::Object(_) => "an object".into(),
    }
}

fn err(field: &str, expected: impl Into<String>, found: String) -> ShapeError {
    ShapeError {
        field: field.to_string(),
        expected: expected.into(),
        found,
    }
}

/// The member `key` of object `v` (at `path`), or an error naming `path.key`.
pub fn member<'a>(v: &'a Value, path: &str, key: &str) -> Result<&'a Value, ShapeError> {
    let field = if path.is_empty() {
        key.to_string()
    } else {
        format!("{path}.{key}")
    };
    match v {
        Value::Object(map) => map
            .get(key)
            .ok_or_else(|| err(&field, "a value", "nothing (missing)".into())),
        other => Err(err(path, "an object", describe(other))),
    }
}

/// A finite number.
pub fn number(v: &Value, field: &str) -> Result<f64, ShapeError> {
    match v.as_f64() {
        Some(x) if x.is_finite() => Ok(x),
        Some(x) => Err(err(field, "a finite number", format!("{x}"))),
        None => Err(err(field, "a number", describe(v))),
    }
}

/// A non-negative integer that fits `usize`.
pub fn index(v: &Value, field: &str) -> Result<usize, ShapeError> {
    v.as_u64()
        .and_then(|x| usize::try_from(x).ok())
        .ok_or_else(|| err(field, "a non-negative integer", describe(v)))
}

/// A string.
pub fn string<'a>(v: &'a Value, field: &str) -> Result<&'a str, ShapeError> {
    v.as_str()
        .ok_or_else(|| err(field, "a string", describe(v)))
}

/// An array of exactly `n` finite numbers.
pub fn vector(v: &Value, field: &str, n: usize) -> Result<Vec<f64>, ShapeError> {
    let expected = format!("an array of {n} finite numbers");
    let Value::Array(items) = v else {
        return Err(err(field, expected, describe(v)));
    };
    if items.len() != n {
        return Err(err(field, expected, describe(v)));
    }
    items
        .iter()
        .enumerate()
        .map(|(i, x)| number(x, &format!("{field}[{i}]")))
        .collect()
}

/// An array of at least `min` finite numbers (e.g. expression coefficients, where extra
/// trailing coefficients are allowed and ignored by the caller).
pub fn vector_at_least(v: &Value, field: &str, min: usize) -> Result<Vec<f64>, ShapeError> {
    let Value::Array(items) = v else {
        return Err(err(
            field,
            format!("an array of at least {min} numbers"),
            describe(v),
        ));
    };
    if items.len() < min {
        return Err(err(
            field,
            format!("an array of at least {min} numbers"),
            describe(v),
        ));
    }
    vector(v, field, items.len())
}

/// A `rows x cols` matrix as nested arrays (row-major), all finite. A flat array of
/// `rows * cols` numbers is accepted too (some exporters flatten poses).
pub fn matrix(v: &Value, field: &str, rows: usize, cols: usize) -> Result<Vec<f64>, ShapeError> {
    let expected = format!("{rows} x {cols} finite numbers (nested arrays, or flat)");
    let Value::Array(items) = v else {
        return Err(err(field, expected, describe(v)));
    };
    if items.len() == rows * cols && items.iter().all(|x| !x.is_array()) {
        return vector(v, field, rows * cols);
    }
    if items.len() != rows {
        return Err(err(field, expected, describe(v)));
    }
    let mut out = Vec::with_capacity(rows * cols);
    for (r, row) in items.iter().enumerate() {
        let row_field = format!("{field}[{r}]");
        match vector(row, &row_field, cols) {
            Ok(vals) => out.extend(vals),
            Err(e) if e.field == row_field => {
                return Err(err(
                    field,
                    expected,
                    format!("row {r} is {}", describe(row)),
                ));
            }
            Err(e) => return Err(e),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn errors_name_the_field_and_shape() {
        let v = json!({"body_pose": [[0, 0, 0], [1, 2]]});
        let e = matrix(
            member(&v, "frames[3].params", "body_pose").unwrap(),
            "frames[3].params.body_pose",
            2,
            3,
        )
        .unwrap_err();
        assert_eq!(e.field, "frames[3].params.body_pose");
        assert!(e.expected.contains("2 x 3"), "{e}");
        assert!(e.found.contains("row 1"), "{e}");
        let missing = member(&v, "frames[3].params", "jaw_pose").unwrap_err();
        assert_eq!(missing.field, "frames[3].params.jaw_pose");
    }

    #[test]
    fn flat_and_nested_matrices_agree() {
        let nested = matrix(&json!([[1, 2, 3], [4, 5, 6]]), "m", 2, 3).unwrap();
        let flat = matrix(&json!([1, 2, 3, 4, 5, 6]), "m", 2, 3).unwrap();
        assert_eq!(nested, flat);
    }

    #[test]
    fn strings_and_nulls_are_not_numbers() {
        assert!(vector(&json!([1, "x", 3]), "v", 3).unwrap_err().field == "v[1]");
        assert!(number(&Value::Null, "n").is_err());
    }
}
