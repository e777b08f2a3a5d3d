//! The same seed gives the same run on any number of cores: a step's rays are cut into
//! chunks by the batch alone, the chunks run as rayon tasks and their gradients are
//! summed in chunk order, and the fused kernels sum their parallel parts in a fixed
//! order. Two processes, one and three rayon threads, write the same training log bit
//! for bit (a 1024-ray batch: four chunks).

mod common;

use std::process::Command;

use common::cli::{p, synth_training_scene};

fn train_log(data: &std::path::Path, run: &std::path::Path, threads: &str) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_talkin"))
        .env("RAYON_NUM_THREADS", threads)
        .args([
            "-q",
            "train",
            "--data",
            p(data),
            "--out",
            p(run),
            "--steps",
            "12",
        ])
        .args(["--batch", "1024", "--patches", "0", "--occ-every", "4"])
        .args(["--grid-resolution", "32", "--seed", "3"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Step, loss, MSE, PSNR, rays, samples, the grid: the columns that hold no times.
    std::fs::read_to_string(run.join("train_log.csv"))
        .unwrap()
        .lines()
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            [0, 2, 3, 4, 5, 6, 10].map(|i| c[i]).join(",")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn one_and_three_threads_train_the_same_bits() {
    let base = common::temp_dir("threads");
    let data = base.join("data");
    synth_training_scene(&data);
    let one = train_log(&data, &base.join("one"), "1");
    let three = train_log(&data, &base.join("three"), "3");
    assert_eq!(one.lines().count(), 13, "a header and 12 steps:\n{one}");
    assert_eq!(one, three);
}
