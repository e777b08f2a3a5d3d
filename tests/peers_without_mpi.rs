//! A build without the `mpi` feature (the default) trains alone, and a launch that asks
//! for peers exits 1 saying how to build with MPI, before it reads the dataset or
//! creates the run.

#![cfg(not(feature = "mpi"))]

mod common;

use common::cli::{p, stderr, talkin};

#[test]
fn peers_asked_of_a_build_without_mpi_exit_1_naming_the_feature() {
    let dir = common::temp_dir("peers_without_mpi");
    let data = dir.join("no-such-data");
    let run = dir.join("run");
    let out = talkin(&[
        "train",
        "--data",
        p(&data),
        "--out",
        p(&run),
        "--nodes",
        "2",
    ]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("--nodes 2"), "{err}");
    assert!(
        err.contains("cargo build --release --features mpi"),
        "{err}"
    );
    assert!(!run.exists(), "the refused run created {}", run.display());

    // An MPI launcher's two ranks, as mpirun would set them.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_talkin"))
        .args(["train", "--data", p(&data), "--out", p(&run)])
        .env("OMPI_COMM_WORLD_SIZE", "2")
        .env("OMPI_COMM_WORLD_RANK", "1")
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("one of 2 peers"), "{err}");
    assert!(err.contains("--features mpi"), "{err}");
}
