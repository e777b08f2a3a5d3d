//! The `talkin` command line: argument parsing, progress and exit codes. The work lives in
//! the engine crate.

mod cli;
mod progress;

use clap::Parser;

/// Keeps freed tensor pages mapped: glibc's default malloc page-faults every large burn
/// tensor (~1.7x slower training).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
