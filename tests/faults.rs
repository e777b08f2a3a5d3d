//! The faults a long run meets beyond a signal or a damaged file: a second writer on the
//! same run (refused while the first lives, free once it is killed), and a full disk
//! under every writer (each fails naming the file and the OS error and leaves the disk as
//! it found it; the run resumes exactly once space is back).

mod common;

use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::cli::{p, start_trainer, stderr, talkin};
use common::layouts::{Clip, write_peoplesnapshot};
use talkin::avatar::Avatar;
use talkin::avatar::checkpoint::{self, CHECKPOINT_DIR, Checkpoint, LATEST_FILE};
use talkin::train::LOG_FILE;

/// `talkin train` on a tiny scene: 256 rays, no perceptual term, a 32-cell grid.
fn train_args<'a>(data: &'a Path, out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["train", "--data", p(data), "--out", p(out)];
    args.extend(common::cli::TINY_TRAIN_FLAGS);
    args.extend(extra);
    args
}

fn steps_of_checkpoints(run: &Path) -> Vec<usize> {
    checkpoint::step_dirs(run).iter().map(|(s, _)| *s).collect()
}

#[cfg(unix)]
#[test]
fn a_second_writer_is_refused_and_a_killed_one_leaves_no_lock() {
    let dataset = common::synthetic_scene("faults_scene_lock", 1, 48, 1);
    let base = common::temp_dir("faults_lock");
    let run = base.join("run");
    let mut first = start_trainer(&dataset.root, &run, &base.join("stderr.txt"));
    let pid = first.id();

    // Every writer is refused, naming the run and the holder, and touches nothing.
    let resume = train_args(&dataset.root, &run, &["--resume"]);
    let force = train_args(&dataset.root, &run, &["--steps", "2", "--force"]);
    let adapt_base = base.join("other");
    let adapt = [
        "adapt",
        "--run",
        p(&adapt_base),
        "--data",
        p(&dataset.root),
        "--subject",
        &dataset.subjects[0].name,
        "--out",
        p(&run),
    ];
    for args in [&resume[..], &force[..], &adapt[..]] {
        let out = talkin(args);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains(&format!("{} is being written by another", run.display()))
                && err.contains(&format!("pid {pid}")),
            "{args:?}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
        assert!(
            !steps_of_checkpoints(&run).is_empty(),
            "{args:?} cleared it"
        );
        assert!(run.join(LOG_FILE).is_file());
    }
    // A reader takes no lock: the newest verified checkpoint loads while the run writes.
    Avatar::load(&run).unwrap();

    // SIGKILL: no handler runs, the kernel drops the lock, and the next writer starts.
    first.kill().unwrap();
    first.wait().unwrap();
    let step = steps_of_checkpoints(&run)[0];
    let more = (step + 2).to_string();
    let out = talkin(&train_args(
        &dataset.root,
        &run,
        &["--resume", "--steps", &more],
    ));
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(steps_of_checkpoints(&run)[0], step + 2);
}

/// A tmpfs of `size_mb` mounted on a fresh directory, unmounted when dropped.
struct Tmpfs {
    dir: PathBuf,
}

impl Tmpfs {
    /// `None` (with a note on stderr) when the test does not run as root, which mounting
    /// needs (CI runs as root), or when the mount is refused all the same.
    fn mount(name: &str, size_mb: u32) -> Option<Tmpfs> {
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        let root = status
            .lines()
            .find_map(|l| l.strip_prefix("Uid:"))
            .and_then(|ids| ids.split_whitespace().nth(1))
            == Some("0");
        if !root {
            eprintln!("note: skipped: mounting a small tmpfs needs root (CI runs as root)");
            return None;
        }
        let dir = common::temp_dir(name);
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size_mb}m"), "tmpfs"])
            .arg(&dir)
            .output()
            .unwrap();
        if !out.status.success() {
            // Root in a container without CAP_SYS_ADMIN may not mount.
            eprintln!(
                "note: skipped: mounting a small tmpfs was refused: {}",
                stderr(&out).trim()
            );
            return None;
        }
        Some(Tmpfs { dir })
    }

    /// Fills the filesystem with a file `filler` until `free` bytes are left.
    fn fill_leaving(&self, free: u64) {
        let path = self.dir.join("filler");
        let mut file = std::fs::File::create(&path).unwrap();
        let chunk = vec![0u8; 1 << 20];
        loop {
            match file.write(&chunk) {
                Ok(0) => break,
                Ok(_) => {}
                Err(e) if e.kind() == std::io::ErrorKind::StorageFull => break,
                Err(e) => panic!("{}: {e}", path.display()),
            }
        }
        let full = file.metadata().unwrap().len();
        file.set_len(full.saturating_sub(free)).unwrap();
    }

    fn free_all(&self) {
        std::fs::remove_file(self.dir.join("filler")).unwrap();
    }

    /// Every path under the mount but the filler, relative to it.
    fn listing(&self) -> BTreeSet<String> {
        fn walk(dir: &Path, root: &Path, out: &mut BTreeSet<String>) {
            for entry in std::fs::read_dir(dir).unwrap() {
                let path = entry.unwrap().path();
                let name = path.strip_prefix(root).unwrap().display().to_string();
                if name != "filler" {
                    out.insert(name);
                }
                if path.is_dir() {
                    walk(&path, root, out);
                }
            }
        }
        let mut out = BTreeSet::new();
        walk(&self.dir, &self.dir, &mut out);
        out
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.dir).status();
    }
}

/// Runs `args` on the full disk: exit 1, an error naming a file on it and the OS error,
/// and the disk left as it was (no partial file under its final name, no temp file).
fn fails_on_full_disk(disk: &Tmpfs, args: &[&str]) -> String {
    let before = disk.listing();
    let out = talkin(args);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
    assert!(
        err.contains(&disk.dir.display().to_string()) && err.contains("No space left on device"),
        "{args:?}: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(disk.listing(), before, "{args:?} left files behind: {err}");
    err
}

/// Step, loss, mse and psnr of every row of a run's log.
fn losses(run: &Path) -> Vec<[f64; 4]> {
    let text = std::fs::read_to_string(run.join(LOG_FILE)).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|v| v.parse().unwrap()).collect();
            [c[0], c[2], c[3], c[4]]
        })
        .collect()
}

#[cfg(unix)]
#[test]
fn a_full_disk_loses_nothing_and_the_run_resumes_exactly() {
    // A checkpoint of the tiny run takes ~61 MB; a save holds three at once (the new one,
    // the previous one kept as the fallback, and the one before, removed last).
    let Some(disk) = Tmpfs::mount("faults_disk", 200) else {
        return;
    };
    let dataset = common::synthetic_scene("faults_scene_disk", 1, 48, 1);
    let data = &dataset.root;
    let base = common::temp_dir("faults_disk_inputs");
    // A checkpoint after every step, refined poses too (export-poses reads them); every
    // network built (`--plan off`), so that a checkpoint has the size the disk is
    // sized for.
    let flags: &[&str] = &[
        "--steps",
        "4",
        "--checkpoint-every",
        "0.001",
        "--refine-poses",
        "--plan",
        "off",
    ];
    let straight = base.join("straight");
    let out = talkin(&train_args(data, &straight, flags));
    assert!(out.status.success(), "{}", stderr(&out));

    // Training with 150 MB free: the third checkpoint does not fit. The run fails naming
    // the file and the OS error, and leaves the step-2 checkpoint loadable and no temp.
    disk.fill_leaving(150 << 20);
    let run = disk.dir.join("run");
    let out = talkin(&train_args(data, &run, flags));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&run.display().to_string()) && err.contains("No space left on device"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    let names: BTreeSet<String> = std::fs::read_dir(run.join(CHECKPOINT_DIR))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    let expected = [LATEST_FILE, "step-000001", "step-000002"];
    assert_eq!(names, expected.map(String::from).into(), "{err}");
    let loaded = Checkpoint::load(&run).unwrap();
    assert!(loaded.dir.ends_with("step-000002") && loaded.notes.is_empty());
    let stray: Vec<String> = disk
        .listing()
        .into_iter()
        .filter(|n| n.contains("tmp") || n.contains("partial"))
        .collect();
    assert!(stray.is_empty(), "{stray:?}");
    // A resume on a disk with no room fails at the log's rewrite and changes nothing.
    let resume = train_args(data, &run, &["--resume"]);
    disk.free_all();
    disk.fill_leaving(0);
    let err = fails_on_full_disk(&disk, &resume);
    assert!(err.contains(LOG_FILE), "{err}");
    // Space back: the resume ends where the uninterrupted run ends.
    disk.free_all();
    let out = talkin(&resume);
    assert!(out.status.success(), "{}", stderr(&out));
    let (a, b) = (losses(&straight), losses(&run));
    assert_eq!(a.len(), 4);
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x[0], y[0], "steps");
        for k in 1..4 {
            // To 1e-4: the backend's threaded reductions may order sums differently.
            assert!(
                (x[k] - y[k]).abs() <= 1e-4 * x[k].abs().max(1e-3),
                "{x:?} vs {y:?}"
            );
        }
    }
    std::fs::remove_dir_all(&run).unwrap();

    // Every other writer, each on a full disk.
    disk.fill_leaving(0);
    let eval = |json: &Path, renders: &Path| {
        vec![
            "eval".to_string(),
            "--run".into(),
            p(&straight).into(),
            "--data".into(),
            p(data).into(),
            "--split".into(),
            "test_same".into(),
            "--json".into(),
            p(json).into(),
            "--renders".into(),
            p(renders).into(),
        ]
    };
    for args in [
        // The renders fail; then the report, its renders written elsewhere.
        eval(&disk.dir.join("eval.json"), &disk.dir.join("renders")),
        eval(&disk.dir.join("eval.json"), &base.join("renders")),
    ] {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        fails_on_full_disk(&disk, &args);
    }
    let sequence = disk.dir.join("sequence");
    let render = [
        "render",
        "--run",
        p(&straight),
        "--data",
        p(data),
        "--split",
        "test_same",
        "--out",
        p(&sequence),
    ];
    fails_on_full_disk(&disk, &render);
    let exported = disk.dir.join("refined.json");
    let export = ["export-poses", "--run", p(&straight), "--out", p(&exported)];
    fails_on_full_disk(&disk, &export);
    let glb = disk.dir.join("avatar.glb");
    let subject = dataset.subjects[0].name.clone();
    let glb_export = [
        "export",
        "--run",
        p(&straight),
        "--subject",
        &subject,
        "--out",
        p(&glb),
        "--resolution",
        "32",
        // A few steps' field: a low level still gives a surface to write.
        "--level",
        "0.01",
    ];
    fails_on_full_disk(&disk, &glb_export);
    let clip = Clip::subject0(&dataset);
    let (src, model) = write_peoplesnapshot(&clip, "faults_disk_peoplesnapshot");
    let imported = disk.dir.join("imported");
    let import = common::cli::import_args("peoplesnapshot", &src, &imported, &model);
    fails_on_full_disk(&disk, &import);

    // Each of them writes once there is room.
    disk.free_all();
    for args in [&render[..], &export[..], &glb_export[..], &import[..]] {
        let out = talkin(args);
        assert!(out.status.success(), "{args:?}: {}", stderr(&out));
    }
    let args = eval(&disk.dir.join("eval.json"), &disk.dir.join("renders"));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = talkin(&args);
    assert!(out.status.success(), "{}", stderr(&out));
}
