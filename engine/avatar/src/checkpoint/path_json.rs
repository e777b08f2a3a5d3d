//! Paths in JSON that round-trip whatever their bytes: a UTF-8 path is a JSON string (the
//! form every run has always written), any other a `{"unix_bytes": [..]}` object of its
//! raw bytes. serde's own `PathBuf` refuses non-UTF-8 paths, which made a dataset or
//! `--lpips-dir` path in another encoding fail at the first checkpoint, after training.

use std::path::{Path, PathBuf};

use serde::de::Error as _;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use serde_json::{Value, json};

/// The JSON form of `path` (a string when it is UTF-8).
pub fn to_json(path: &Path) -> Result<Value, String> {
    if let Some(s) = path.to_str() {
        return Ok(Value::String(s.to_string()));
    }
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        Ok(json!({ "unix_bytes": path.as_os_str().as_bytes() }))
    }
    #[cfg(not(unix))]
    {
        Err(format!(
            "{}: not valid Unicode; rename it or pass another path",
            path.display()
        ))
    }
}

/// The path `value` holds (see [`to_json`]).
pub fn from_json(value: &Value) -> Result<PathBuf, String> {
    match value {
        Value::String(s) => Ok(PathBuf::from(s)),
        Value::Object(o) if o.len() == 1 && o.contains_key("unix_bytes") => {
            let bytes: Vec<u8> = serde_json::from_value(o["unix_bytes"].clone())
                .map_err(|e| format!("`unix_bytes`: {e}"))?;
            #[cfg(unix)]
            {
                use std::os::unix::ffi::OsStringExt;
                Ok(PathBuf::from(std::ffi::OsString::from_vec(bytes)))
            }
            #[cfg(not(unix))]
            {
                Err(format!(
                    "a Unix path of {} bytes that is not Unicode cannot be used here",
                    bytes.len()
                ))
            }
        }
        other => Err(format!(
            "expected a path (a string or {{\"unix_bytes\": [..]}}), found {other}"
        )),
    }
}

/// For `#[serde(with = "path_json::serde_path")]` on a `PathBuf`.
pub mod serde_path {
    use super::*;

    pub fn serialize<S: Serializer>(path: &Path, s: S) -> Result<S::Ok, S::Error> {
        to_json(path)
            .map_err(serde::ser::Error::custom)?
            .serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<PathBuf, D::Error> {
        from_json(&Value::deserialize(d)?).map_err(D::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utf8_paths_stay_strings_and_others_round_trip() {
        let plain = Path::new("out/data");
        assert_eq!(to_json(plain).unwrap(), json!("out/data"));
        assert_eq!(from_json(&json!("out/data")).unwrap(), plain);
        #[cfg(unix)]
        {
            use std::os::unix::ffi::OsStrExt;
            let odd = Path::new(std::ffi::OsStr::from_bytes(b"data-\xff\xfe"));
            let v = to_json(odd).unwrap();
            assert_eq!(v, json!({"unix_bytes": [100, 97, 116, 97, 45, 255, 254]}));
            assert_eq!(from_json(&v).unwrap(), odd);
        }
        assert!(from_json(&json!(3)).is_err());
        assert!(from_json(&json!({"unix_bytes": [300]})).is_err());
    }
}
