//! A trainer joining the other peers of a data-parallel run: the registration that
//! refuses a peer on another dataset, recipe, build or step, then the link every step
//! exchanges over.

use talkin_peers::Collective;

use crate::error::TrainError;
use crate::peers::PeerLink;
use crate::peers::fingerprint::{Fingerprint, register};
use crate::recipe::record;

use super::Trainer;

impl Trainer<'_> {
    /// Registers with the other peers (every peer compares every peer's fingerprint with
    /// peer 0's and refuses the run, naming the peer and what differs) and trains as one
    /// of them from here on. Built with [`super::RunWriter::Writes`] on peer 0 only.
    pub fn join_peers(&mut self, mut collective: Box<dyn Collective>) -> Result<(), TrainError> {
        let mut recipe = record::to_json(&self.opts).map_err(|e| TrainError::Recipe {
            file: self.out.join(crate::recipe::RECIPE_FILE),
            problem: e,
        })?;
        // Where each peer computes is its own business.
        if let Some(o) = recipe.get_mut("options").and_then(|o| o.as_object_mut()) {
            o.remove("device");
        }
        let exe = std::env::current_exe().and_then(std::fs::read).ok();
        let mine = Fingerprint::new(
            &self.dataset_sha256,
            &self.progress.frames,
            &recipe.to_string(),
            exe.as_deref(),
            self.progress.step,
        );
        register(collective.as_mut(), &mine)?;
        let mut link = PeerLink::new(collective);
        link.local_elapsed = self.progress.elapsed;
        link.joined_at = self.progress.elapsed;
        self.peers = Some(link);
        Ok(())
    }

    /// The link to the other peers (`None`: alone).
    pub fn peers(&self) -> Option<&PeerLink> {
        self.peers.as_ref()
    }
}
