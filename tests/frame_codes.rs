//! Per-frame codes through a whole run: a run with frame codes (into F_body and D_nr)
//! trains with occupancy updates, writes its codes with the checkpoint, learns the codes
//! of the frames it visited and no other, resumes, and renders an unseen pose with the
//! codes' mean; with `--frame-code-dropout 1` every step trains with the codes' mean, so
//! every code moves alike. Its own test binary: one trainer at a time in the process
//! (see `resume.rs`).

mod common;

use talkin::avatar::Avatar;
use talkin::grids::SamplerKind;
use talkin::nets::read_floats;
use talkin::render::avatar::RenderFrame;
use talkin::train::{Budget, TrainOptions, Trainer};

#[test]
fn a_run_with_frame_codes_trains_saves_resumes_and_renders() {
    let dataset = common::synthetic_scene("frame_codes_scene", 1, 48, 1);
    let opts = TrainOptions {
        frame_code_dim: 8,
        frame_code_deform: true,
        distortion: 0.01,
        ..common::small_train_opts(SamplerKind::Accelerated, 6)
    };
    let run = common::temp_dir("frame_codes_run");
    let mut trainer = Trainer::new(&dataset, &run, &opts).unwrap();
    let frames = trainer.training_frames().len();
    for _ in 0..6 {
        trainer.step().unwrap();
    }
    trainer.save().unwrap();
    drop(trainer);

    let avatar = Avatar::load(&run).unwrap();
    let codes = avatar
        .field
        .frame_codes
        .as_ref()
        .expect("the checkpoint holds the codes")
        .val();
    assert_eq!(codes.dims(), [frames, 8]);
    let codes = read_floats(codes).unwrap();
    let moved = codes
        .chunks_exact(8)
        .filter(|row| row.iter().any(|&v| v != 0.0))
        .count();
    // Six steps visit at most six frames; every code starts at zero and only a visited
    // frame's code has a gradient.
    assert!(
        (1..=6).contains(&moved),
        "{moved} of {frames} codes moved in 6 steps"
    );
    assert!(codes.iter().all(|v| v.is_finite()));

    // An unseen pose renders with the codes' mean.
    let f = &dataset.frames[0];
    let rgb = avatar.render(0, &f.params, &f.camera, None).unwrap().rgb;
    assert!(rgb.iter().all(|v| v.is_finite()));

    // The run resumes with its codes and goes on.
    let mut resumed = Trainer::resume(&dataset, &run).unwrap();
    assert_eq!(resumed.steps_taken(), 6);
    resumed.set_budget(Budget::Steps(8)).unwrap();
    resumed.run(&mut |_| {}).unwrap();

    // Every step with the mean: each code takes the same gradient (a 1/frames share of
    // the mean's), so all of them move, and alike; no frame's own code is ever read.
    let dropout = TrainOptions {
        frame_code_dropout: 1.0,
        ..opts
    };
    let run = common::temp_dir("frame_codes_dropout_run");
    let mut trainer = Trainer::new(&dataset, &run, &dropout).unwrap();
    for _ in 0..4 {
        trainer.step().unwrap();
    }
    let codes = trainer.inference_field().frame_codes.expect("codes").val();
    let codes = read_floats(codes).unwrap();
    let first = &codes[..8];
    assert!(
        first.iter().any(|&v| v != 0.0),
        "the mean's gradient moves the codes"
    );
    for row in codes.chunks_exact(8) {
        assert_eq!(row, first, "every code moves alike under the mean");
    }
}
