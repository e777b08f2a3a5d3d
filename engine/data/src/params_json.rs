//! Frame parameters as JSON: the `params` object of `dataset.json`, poses files, motion
//! files and the server's requests, named and shaped as SMPLer-X exports them. Errors name
//! the field's full path and the expected shape.

use glam::DVec3;
use serde::Serialize;
use serde_json::Value;
use talkin_human::body::{FrameParams, N_BODY_JOINTS, N_EXPRESSION, N_HAND_JOINTS};

use crate::json_shape::{self, ShapeError};

/// Largest magnitude of any pose, expression or translation value. Anything beyond is not
/// a pose (radians, coefficients of a few units, metres) and would only overflow f32.
pub const PARAM_LIMIT: f64 = 1e3;

/// The JSON wire form of [`FrameParams`].
pub trait ParamsJson: Sized {
    /// Parses a `params` object; `path` names it in errors (e.g. `frames[3].params`).
    /// Expression may carry more than 10 coefficients (the first 10 are kept: see
    /// [`expression_count`]); everything else must have exactly its shape, and every
    /// value be finite and within [`PARAM_LIMIT`].
    fn from_json(v: &Value, path: &str) -> Result<Self, ShapeError>;
    /// The `params` object, rounded to 1e-9 so written JSON stays short and byte-stable.
    fn to_json(&self) -> Value;
}

impl ParamsJson for FrameParams {
    fn from_json(v: &Value, path: &str) -> Result<Self, ShapeError> {
        let field = |k: &str| format!("{path}.{k}");
        let vec3 = |k: &str| -> Result<DVec3, ShapeError> {
            let x = json_shape::vector(json_shape::member(v, path, k)?, &field(k), 3)?;
            Ok(DVec3::new(x[0], x[1], x[2]))
        };
        let rows = |k: &str, n: usize, out: &mut [DVec3]| -> Result<(), ShapeError> {
            let x = json_shape::matrix(json_shape::member(v, path, k)?, &field(k), n, 3)?;
            for (i, r) in out.iter_mut().enumerate() {
                *r = DVec3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
            }
            Ok(())
        };
        let mut p = FrameParams {
            global_orient: vec3("global_orient")?,
            jaw_pose: vec3("jaw_pose")?,
            leye_pose: vec3("leye_pose")?,
            reye_pose: vec3("reye_pose")?,
            transl: vec3("transl")?,
            ..Default::default()
        };
        rows("body_pose", N_BODY_JOINTS - 1, &mut p.body_pose)?;
        rows("left_hand_pose", N_HAND_JOINTS, &mut p.left_hand_pose)?;
        rows("right_hand_pose", N_HAND_JOINTS, &mut p.right_hand_pose)?;
        let e = json_shape::vector_at_least(
            json_shape::member(v, path, "expression")?,
            &field("expression"),
            N_EXPRESSION,
        )?;
        p.expression.copy_from_slice(&e[..N_EXPRESSION]);
        check_param_limits(&p, path)?;
        Ok(p)
    }

    fn to_json(&self) -> Value {
        #[derive(Serialize)]
        struct Wire<'a> {
            global_orient: [f64; 3],
            body_pose: Vec<[f64; 3]>,
            jaw_pose: [f64; 3],
            leye_pose: [f64; 3],
            reye_pose: [f64; 3],
            left_hand_pose: Vec<[f64; 3]>,
            right_hand_pose: Vec<[f64; 3]>,
            expression: &'a [f64],
            transl: [f64; 3],
        }
        let rows = |r: &[DVec3]| r.iter().map(|v| round6(v.to_array())).collect::<Vec<_>>();
        let expression: Vec<f64> = self
            .expression
            .iter()
            .map(|x| round6([*x, 0.0, 0.0])[0])
            .collect();
        serde_json::to_value(Wire {
            global_orient: round6(self.global_orient.to_array()),
            body_pose: rows(&self.body_pose),
            jaw_pose: round6(self.jaw_pose.to_array()),
            leye_pose: round6(self.leye_pose.to_array()),
            reye_pose: round6(self.reye_pose.to_array()),
            left_hand_pose: rows(&self.left_hand_pose),
            right_hand_pose: rows(&self.right_hand_pose),
            expression: &expression,
            transl: round6(self.transl.to_array()),
        })
        .expect("plain numbers always serialise")
    }
}

/// How many expression coefficients a `params` object carries (the engine conditions on
/// the first [`N_EXPRESSION`]); `None` if it has no expression array.
pub fn expression_count(v: &Value) -> Option<usize> {
    v.get("expression").and_then(Value::as_array).map(Vec::len)
}

/// Every value of `p` finite and within [`PARAM_LIMIT`]; the error names the element
/// (`path.body_pose[3][1]`). Parsing checks it; a pose from elsewhere (a motion file)
/// is checked with it.
pub fn check_param_limits(p: &FrameParams, path: &str) -> Result<(), ShapeError> {
    let too_big = |name: String, x: f64| ShapeError {
        field: format!("{path}.{name}"),
        expected: format!("a value within +-{PARAM_LIMIT} (radians, expression units or metres)"),
        found: format!("the number {x}"),
    };
    let vec3 = |name: &str, v: DVec3| -> Result<(), ShapeError> {
        match v
            .to_array()
            .iter()
            .position(|x| x.is_nan() || x.abs() > PARAM_LIMIT)
        {
            Some(k) => Err(too_big(format!("{name}[{k}]"), v[k])),
            None => Ok(()),
        }
    };
    let rows = |name: &str, r: &[DVec3]| -> Result<(), ShapeError> {
        r.iter()
            .enumerate()
            .try_for_each(|(i, v)| vec3(&format!("{name}[{i}]"), *v))
    };
    vec3("global_orient", p.global_orient)?;
    rows("body_pose", &p.body_pose)?;
    vec3("jaw_pose", p.jaw_pose)?;
    vec3("leye_pose", p.leye_pose)?;
    vec3("reye_pose", p.reye_pose)?;
    rows("left_hand_pose", &p.left_hand_pose)?;
    rows("right_hand_pose", &p.right_hand_pose)?;
    vec3("transl", p.transl)?;
    match p
        .expression
        .iter()
        .position(|x| x.is_nan() || x.abs() > PARAM_LIMIT)
    {
        Some(k) => Err(too_big(format!("expression[{k}]"), p.expression[k])),
        None => Ok(()),
    }
}

/// Rounds to 1e-9 so written JSON stays short and byte-stable.
fn round6(v: [f64; 3]) -> [f64; 3] {
    v.map(|x| (x * 1e9).round() / 1e9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_round_trip() {
        let mut p = FrameParams::default();
        p.body_pose[3] = DVec3::new(0.1, -0.2, 0.3);
        p.right_hand_pose[14] = DVec3::new(0.5, 0.0, -0.25);
        p.expression[9] = -1.5;
        p.transl = DVec3::new(0.0, 1.0, 2.0);
        let back = FrameParams::from_json(&p.to_json(), "params").unwrap();
        assert_eq!(back, p);
    }

    /// A body pose of 1e300 is not a pose: the element is named.
    #[test]
    fn absurd_values_name_their_element() {
        let mut v = FrameParams::default().to_json();
        v["body_pose"][4][1] = serde_json::json!(1e300);
        let e = FrameParams::from_json(&v, "frames[2].params").unwrap_err();
        assert_eq!(e.field, "frames[2].params.body_pose[4][1]");
        let mut v = FrameParams::default().to_json();
        v["expression"][3] = serde_json::json!(-2e3);
        let e = FrameParams::from_json(&v, "p").unwrap_err();
        assert_eq!(e.field, "p.expression[3]");
        let mut v = FrameParams::default().to_json();
        v["transl"] = serde_json::json!([0.0, 999.0, -1000.0]);
        assert!(FrameParams::from_json(&v, "p").is_ok());
    }

    #[test]
    fn wrong_shape_names_the_field() {
        let mut v = FrameParams::default().to_json();
        v["left_hand_pose"] = serde_json::json!([[0, 0, 0]]);
        let e = FrameParams::from_json(&v, "frames[7].params").unwrap_err();
        assert_eq!(e.field, "frames[7].params.left_hand_pose");
        assert!(e.expected.contains("15 x 3"));
    }
}
