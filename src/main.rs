//! The `talkin` command line: argument parsing, progress and exit codes. The work lives in
//! the workspace's crates (`grids`, `nets` and `engine/*`), re-exported by the `talkin`
//! library.

mod cli;
mod progress;
mod verbosity;

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
    verbosity::init(args.quiet, args.verbose);
    let result = cli::run(args);
    // Each read of a GPU tensor waits for the device's queued work (`-v` shows the count).
    tracing::debug!("device readbacks: {}", talkin::nets::device_readbacks());
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", report(&e));
            if let Some(hint) = cli::import::convert_hint(&e) {
                eprintln!("hint: {hint}");
            }
            match e.downcast_ref::<cli::train::Interrupted>() {
                Some(interrupted) => std::process::ExitCode::from(interrupted.exit_code()),
                None => std::process::ExitCode::FAILURE,
            }
        }
    }
}

/// The error and its causes, each once: library errors often name their cause in their
/// own message (`"{file}: {source}"`) and also return it as `source()`, so a cause whose
/// text is already in the report is not repeated.
fn report(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if text.is_empty() || out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_cause_is_reported_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file");
        let inner = anyhow::Error::new(io).context("/data/dataset.json: No such file");
        let e = inner.context("cannot load the dataset in /data");
        assert_eq!(
            report(&e),
            "cannot load the dataset in /data: /data/dataset.json: No such file"
        );
        let plain = anyhow::anyhow!("a").context("b");
        assert_eq!(report(&plain), "b: a");
    }
}
