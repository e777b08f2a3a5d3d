//! What the peers of a run must share, compared before the first step: the dataset (its
//! `dataset.json` and training frames), the recipe, the build and the step they start
//! from. A peer started on anything else is refused, naming what differs.

use sha2::{Digest, Sha256};
use talkin_peers::{Collective, PeerError};

/// One peer's fingerprint: SHA-256 of each part, and its step.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fingerprint {
    pub dataset: [u8; 32],
    pub recipe: [u8; 32],
    pub build: [u8; 32],
    pub step: u64,
}

const LEN: usize = 32 * 3 + 8;

impl Fingerprint {
    /// The fingerprint of a run on the dataset of `dataset_sha256` with training frames
    /// `frames`, options recorded as `recipe` (JSON), by the executable at `build` (its
    /// bytes; `None`: unreadable, hashed as empty), at step `step`.
    pub fn new(
        dataset_sha256: &str,
        frames: &[usize],
        recipe: &str,
        build: Option<&[u8]>,
        step: usize,
    ) -> Fingerprint {
        let mut d = Sha256::new();
        d.update(dataset_sha256.as_bytes());
        for f in frames {
            d.update((*f as u64).to_le_bytes());
        }
        Fingerprint {
            dataset: d.finalize().into(),
            recipe: Sha256::digest(recipe.as_bytes()).into(),
            build: Sha256::digest(build.unwrap_or_default()).into(),
            step: step as u64,
        }
    }

    fn to_bytes(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(LEN);
        v.extend_from_slice(&self.dataset);
        v.extend_from_slice(&self.recipe);
        v.extend_from_slice(&self.build);
        v.extend_from_slice(&self.step.to_le_bytes());
        v
    }

    fn from_bytes(b: &[u8]) -> Option<Fingerprint> {
        (b.len() == LEN).then(|| Fingerprint {
            dataset: b[0..32].try_into().expect("32 bytes"),
            recipe: b[32..64].try_into().expect("32 bytes"),
            build: b[64..96].try_into().expect("32 bytes"),
            step: u64::from_le_bytes(b[96..104].try_into().expect("8 bytes")),
        })
    }
}

/// Gathers every peer's fingerprint and refuses the run, on every peer, if any differs
/// from peer 0's, naming the peer and what differs.
pub fn register(peers: &mut dyn Collective, mine: &Fingerprint) -> Result<(), PeerError> {
    let all = peers.all_gather(&mine.to_bytes(), "the peers' registration")?;
    let prints: Vec<Option<Fingerprint>> = all.iter().map(|b| Fingerprint::from_bytes(b)).collect();
    let Some(Some(first)) = prints.first() else {
        return Err(PeerError::Mismatch("peer 0 sent no fingerprint".into()));
    };
    let hex = |h: &[u8; 32]| {
        h[..6]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect::<String>()
    };
    let mut problems = Vec::new();
    for (rank, p) in prints.iter().enumerate().skip(1) {
        let Some(p) = p else {
            problems.push(format!("peer {rank} sent no fingerprint"));
            continue;
        };
        let parts = [
            (
                "dataset (dataset.json and training frames",
                &p.dataset,
                &first.dataset,
            ),
            ("recipe (the recorded options", &p.recipe, &first.recipe),
            ("build (the talkin executable", &p.build, &first.build),
        ];
        let mut differs: Vec<String> = parts
            .iter()
            .filter(|(_, a, b)| a != b)
            .map(|(what, a, b)| format!("its {what}, sha256 {}... against {}...)", hex(a), hex(b)))
            .collect();
        if p.step != first.step {
            differs.push(format!("its step ({} against {})", p.step, first.step));
        }
        if !differs.is_empty() {
            problems.push(format!(
                "peer {rank} differs from peer 0 in {}",
                differs.join(", ")
            ));
        }
    }
    if problems.is_empty() {
        Ok(())
    } else {
        Err(PeerError::Mismatch(format!(
            "the peers were not started on the same run, refused before the first step: {}",
            problems.join("; ")
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use talkin_peers::threads::ThreadPeers;

    #[test]
    fn a_peer_on_another_dataset_is_refused_on_every_peer_naming_it() {
        let ok = Fingerprint::new("aa", &[0, 1], "{}", Some(b"exe"), 0);
        let other = Fingerprint::new("bb", &[0, 1], "{}", Some(b"exe"), 0);
        let results: Vec<Result<(), PeerError>> = std::thread::scope(|s| {
            let hs: Vec<_> = ThreadPeers::group(3)
                .into_iter()
                .map(|mut p| {
                    let mine = if p.rank() == 2 {
                        other.clone()
                    } else {
                        ok.clone()
                    };
                    s.spawn(move || register(&mut p, &mine))
                })
                .collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        });
        for r in results {
            let e = r.unwrap_err().to_string();
            assert!(
                e.contains("peer 2 differs from peer 0 in its dataset"),
                "{e}"
            );
            assert!(!e.contains("peer 1"), "{e}");
        }
    }

    #[test]
    fn same_runs_register_and_every_part_is_named() {
        let a = Fingerprint::new("aa", &[0], "{}", Some(b"exe"), 5);
        let b = Fingerprint::new("aa", &[0], "{\"lr\":1}", Some(b"exe2"), 6);
        let run = |prints: [Fingerprint; 2]| -> Vec<Result<(), PeerError>> {
            std::thread::scope(|s| {
                let hs: Vec<_> = ThreadPeers::group(2)
                    .into_iter()
                    .zip(prints)
                    .map(|(mut p, f)| s.spawn(move || register(&mut p, &f)))
                    .collect();
                hs.into_iter().map(|h| h.join().unwrap()).collect()
            })
        };
        assert!(run([a.clone(), a.clone()]).iter().all(|r| r.is_ok()));
        let e = run([a, b]).remove(1).unwrap_err().to_string();
        for part in ["its recipe", "its build", "its step (6 against 5)"] {
            assert!(e.contains(part), "{e}");
        }
    }
}
