//! Part labels derived from the mask and the posed capsules (for data without a
//! segmentation) against the built-in scene's true labels.

use talkin_data::dataset::{LABEL_NAMES, N_LABELS, derived_segmentation};
use talkin_synth::{SynthConfig, generate};

#[test]
fn derived_labels_agree_with_the_scenes_own() {
    let dir = std::env::temp_dir().join(format!("talkin_derived_labels_{}", std::process::id()));
    let cfg = SynthConfig {
        identities: 3,
        frames: 8,
        size: 96,
        seed: 0,
        motion: None,
        capture: None,
        framing: None,
    };
    let ds = generate(&cfg, &dir, &mut |_, _| {}).unwrap();
    // confusion[true][derived] over person pixels.
    let mut confusion = [[0u64; N_LABELS]; N_LABELS];
    for i in 0..ds.frames.len() {
        let truth = ds.images(i).unwrap();
        let f = &ds.frames[i];
        let derived = derived_segmentation(
            &truth.mask,
            &f.camera,
            &ds.subjects[f.subject].skeleton,
            &f.params,
        );
        for ((t, d), m) in truth
            .segmentation
            .pixels()
            .zip(derived.pixels())
            .zip(truth.mask.pixels())
        {
            if m.0[0] >= 128 {
                confusion[t.0[0] as usize][d.0[0] as usize] += 1;
            }
            if m.0[0] < 128 {
                assert_eq!(d.0[0], 0, "a background pixel got a part");
            }
        }
    }
    let recall = |l: usize| {
        let row: u64 = confusion[l].iter().sum();
        confusion[l][l] as f64 / row.max(1) as f64
    };
    let total: u64 = confusion.iter().flatten().sum();
    let agree: u64 = (0..N_LABELS).map(|l| confusion[l][l]).sum();
    let overall = agree as f64 / total as f64;
    for l in 1..N_LABELS {
        eprintln!(
            "{:>6}: recall {:.3} {:?}",
            LABEL_NAMES[l],
            recall(l),
            confusion[l]
        );
    }
    eprintln!("overall agreement {overall:.3}");
    assert!(overall > 0.94, "overall agreement {overall:.3}");
    for l in 1..N_LABELS {
        assert!(
            recall(l) > 0.92,
            "{}: recall {:.3}",
            LABEL_NAMES[l],
            recall(l)
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}
