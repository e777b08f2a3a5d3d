//! The motion reader on arbitrary bytes, on damaged valid files and on hostile values: it
//! never panics, and whatever it accepts is finite (poses, translation, frame rate).
//!
//! `cargo test -p talkin-data --test motion_properties` runs 64 cases per property;
//! `PROPTEST_CASES=5000 cargo test --release -p talkin-data --test motion_properties`
//! runs many.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

#[path = "support/proptest_config.rs"]
mod proptest_config;

use proptest::prelude::*;
use proptest_config::config;
use talkin_data::array::NdArray;
use talkin_data::motion::{Motion, read_motion};
use talkin_data::npz::NpzWriter;

/// A fresh file name per case (the properties run in parallel).
fn temp(ext: &str) -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = std::env::temp_dir().join(format!("talkin_motion_props_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(format!("{}.{ext}", NEXT.fetch_add(1, Ordering::Relaxed)))
}

/// An AMASS SMPL-X file (`poses` N x 165, `trans` N x 3, `mocap_frame_rate`) with
/// `values` spread over its poses and translation.
fn amass_bytes(n: usize, values: &[f64], rate: f64) -> Vec<u8> {
    let file = temp("npz");
    let mut poses: Vec<f64> = (0..n * 165).map(|k| 0.01 * (k % 7) as f64).collect();
    let mut trans: Vec<f64> = (0..n * 3).map(|k| 0.1 * k as f64).collect();
    for (k, v) in values.iter().enumerate() {
        if k % 2 == 0 {
            let i = (k * 37) % poses.len();
            poses[i] = *v;
        } else {
            let i = (k * 11) % trans.len();
            trans[i] = *v;
        }
    }
    let mut w = NpzWriter::create(&file).unwrap();
    w.array("poses", &NdArray::f64(&[n, 165], poses).unwrap())
        .unwrap()
        .array("trans", &NdArray::f64(&[n, 3], trans).unwrap())
        .unwrap()
        .array("mocap_frame_rate", &NdArray::f64(&[], vec![rate]).unwrap())
        .unwrap();
    w.finish().unwrap();
    let bytes = std::fs::read(&file).unwrap();
    let _ = std::fs::remove_file(&file);
    bytes
}

/// Reads `bytes` as a file with extension `ext`; an accepted motion must be finite.
fn read_checked(bytes: &[u8], ext: &str) -> Result<Motion, String> {
    let file = temp(ext);
    std::fs::write(&file, bytes).unwrap();
    let read = read_motion(&file, None);
    let _ = std::fs::remove_file(&file);
    let motion = read.map_err(|e| e.to_string())?;
    assert!(
        motion.frames.iter().all(|f| f.is_finite()),
        "accepted a non-finite pose"
    );
    if let Some(fps) = motion.fps {
        assert!(fps.is_finite() && fps > 0.0, "accepted fps {fps}");
    }
    Ok(motion)
}

fn hostile() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(1e300),
        Just(-1e300),
        Just(f64::MIN_POSITIVE),
        -10.0..10.0f64,
    ]
}

proptest! {
    #![proptest_config(config(0x3071_00e5))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let _ = read_checked(&bytes, "npz");
        let _ = read_checked(&bytes, "json");
    }

    #[test]
    fn damaged_valid_files_never_panic(
        n in 1usize..4,
        flips in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in proptest::option::of(any::<prop::sample::Index>()),
    ) {
        let mut bytes = amass_bytes(n, &[], 30.0);
        for (at, byte) in flips {
            let i = at.index(bytes.len());
            bytes[i] = byte;
        }
        if let Some(cut) = cut {
            bytes.truncate(cut.index(bytes.len()));
        }
        let _ = read_checked(&bytes, "npz");
    }

    #[test]
    fn hostile_values_are_refused_or_finite(
        n in 1usize..4,
        values in proptest::collection::vec(hostile(), 1..6),
        rate in hostile(),
    ) {
        let bytes = amass_bytes(n, &values, rate);
        let accepted = read_checked(&bytes, "npz");
        let all_finite = values.iter().all(|v| v.is_finite()) && rate.is_finite() && rate > 0.0;
        if !all_finite {
            prop_assert!(accepted.is_err(), "accepted non-finite input");
        }
    }

    #[test]
    fn arbitrary_json_never_panics(text in "[\\[\\]{}\",:0-9a-z_.eE+-]{0,256}") {
        let _ = read_checked(text.as_bytes(), "json");
    }
}
