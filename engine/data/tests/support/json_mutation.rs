//! Damaging a valid JSON document one leaf at a time, shared by the property tests of the
//! dataset loader and of the importers (each includes this file with `#[path]`).

use proptest::prelude::*;
use serde_json::Value;

/// Sets a leaf of `v` picked by `pick` (an index below the length it is given) to `to`.
pub fn mutate_leaf(v: &mut Value, pick: &mut impl FnMut(usize) -> usize, to: Value) {
    match v {
        Value::Object(m) if !m.is_empty() => {
            let key = m.keys().nth(pick(m.len())).cloned().unwrap_or_default();
            if let Some(child) = m.get_mut(&key) {
                mutate_leaf(child, pick, to);
            }
        }
        Value::Array(a) if !a.is_empty() => {
            let k = pick(a.len());
            mutate_leaf(&mut a[k], pick, to);
        }
        leaf => *leaf = to,
    }
}

/// A value a field should not hold: null, the wrong type, huge, subnormal, empty or
/// ragged.
pub fn odd_value() -> impl Strategy<Value = Value> {
    prop_oneof![
        Just(Value::Null),
        any::<bool>().prop_map(Value::Bool),
        any::<f64>().prop_map(|x| serde_json::json!(x)),
        prop::sample::select(vec![1e300, -1e300, 1e3, 1e3 + 1e-9, 1e6, 0.0, -0.0, 1e-320])
            .prop_map(|x| serde_json::json!(x)),
        any::<i64>().prop_map(|x| serde_json::json!(x)),
        ".{0,12}".prop_map(Value::String),
        Just(serde_json::json!([])),
        Just(serde_json::json!({})),
        Just(serde_json::json!([[1.0, 2.0], [3.0]])),
    ]
}
