//! Generates the default synthetic scene, times it and writes a contact sheet of a few
//! frames (RGB over segmentation). Ignored by default; run with
//! `SYNTH_PREVIEW_OUT=/tmp/synth [SYNTH_PREVIEW_SIZE=..] [SYNTH_PREVIEW_FRAMES=..]
//! [SYNTH_PREVIEW_IDENTITIES=..] cargo test --release -p talkin-engine --test synth_preview -- --ignored --nocapture`.

use std::path::PathBuf;
use std::time::Instant;

use talkin_data::dataset::Dataset;
use talkin_synth::{SynthConfig, generate};

#[test]
#[ignore = "slow: generates the full default scene"]
fn default_scene_preview() {
    let out = PathBuf::from(
        std::env::var("SYNTH_PREVIEW_OUT").unwrap_or_else(|_| "/tmp/talkin-synth-preview".into()),
    );
    let mut cfg = SynthConfig::default();
    let knob = |name: &str| {
        std::env::var(name)
            .ok()
            .map(|v| v.parse::<usize>().unwrap())
    };
    if let Some(size) = knob("SYNTH_PREVIEW_SIZE") {
        cfg.size = size as u32;
    }
    if let Some(frames) = knob("SYNTH_PREVIEW_FRAMES") {
        cfg.frames = frames;
    }
    if let Some(identities) = knob("SYNTH_PREVIEW_IDENTITIES") {
        cfg.identities = identities;
    }
    let start = Instant::now();
    let ds = generate(&cfg, &out, &mut |_, _| {}).unwrap();
    let elapsed = start.elapsed().as_secs_f64();
    println!(
        "generated {} frames of {:?} in {elapsed:.2} s",
        ds.frames.len(),
        cfg.image_size()
    );
    let ds = Dataset::load(&out).unwrap();
    // Every frame: head and hands visible, mask == (seg > 0).
    for i in 0..ds.frames.len() {
        let img = ds.images(i).unwrap();
        let mut count = [0usize; 5];
        for (m, s) in img.mask.pixels().zip(img.segmentation.pixels()) {
            assert_eq!(m.0[0] == 255, s.0[0] > 0, "frame {i}");
            count[s.0[0] as usize] += 1;
        }
        assert!(
            count[3] > 0 && count[4] > 0,
            "frame {i} ({}): label counts {count:?}",
            ds.frames[i].split
        );
    }

    // Contact sheet: per identity, 4 frames of different splits; RGB row over seg row.
    let palette = [
        [0u8, 0, 0],
        [80, 80, 200],
        [60, 180, 60],
        [230, 60, 60],
        [240, 200, 40],
    ];
    let picks: Vec<usize> = (0..ds.subjects.len())
        .flat_map(|s| {
            let of = |split| {
                ds.frames
                    .iter()
                    .position(|f| f.subject == s && f.split == split)
                    .unwrap()
            };
            use talkin_data::dataset::Split::*;
            [
                of(Train),
                of(Train) + 3,
                of(TestSame),
                of(TestCross),
                of(TestOod),
            ]
        })
        .collect();
    let (w, h) = (ds.frames[0].camera.width, ds.frames[0].camera.height);
    let cols = 5u32;
    let rows = picks.len() as u32 / cols;
    let mut sheet = image::RgbImage::new(w * cols, h * rows * 2);
    for (k, &i) in picks.iter().enumerate() {
        let img = ds.images(i).unwrap();
        let (cx, cy) = ((k as u32 % cols) * w, (k as u32 / cols) * 2 * h);
        for y in 0..h {
            for x in 0..w {
                sheet.put_pixel(cx + x, cy + y, *img.rgb.get_pixel(x, y));
                let l = img.segmentation.get_pixel(x, y).0[0] as usize;
                sheet.put_pixel(cx + x, cy + h + y, image::Rgb(palette[l]));
            }
        }
    }
    sheet.save(out.join("contact_sheet.png")).unwrap();
    println!("contact sheet: {}", out.join("contact_sheet.png").display());
}
