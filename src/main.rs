//! The `talkin` command line: argument parsing, progress and exit codes. The work lives in
//! the engine crate.

mod cli;
mod progress;

use clap::Parser;

/// Keeps freed tensor pages mapped: glibc's default malloc page-faults every large burn
/// tensor (~1.7x slower training).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay` (index 15 in both its v2 and v3 option enums).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// A training step frees and reallocates the same few hundred MB of tensors; with
/// mimalloc's default 10 ms purge delay every step gave them back to the OS and
/// page-faulted (and zeroed) them again: ~15% of a step. -1 keeps freed memory mapped.
#[allow(unsafe_code)]
fn keep_freed_memory_mapped() {
    // SAFETY: sets a process-wide allocator option (an atomic store inside mimalloc)
    // before any other thread exists.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
}

fn main() -> std::process::ExitCode {
    keep_freed_memory_mapped();
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            match e.downcast_ref::<cli::train::Interrupted>() {
                Some(interrupted) => std::process::ExitCode::from(interrupted.exit_code()),
                None => std::process::ExitCode::FAILURE,
            }
        }
    }
}
