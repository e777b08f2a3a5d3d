//! `train`'s peers: which one this process is, and its link to the others over MPI.

use talkin_peers::{Collective, Launch};

/// Data-parallel training: one of N peers started together by an MPI launcher
/// (`mpirun -n N talkin train ...`, or `srun` in a Slurm allocation), each computing its
/// share of every step's batch; peer 0 writes the run.
#[derive(clap::Args, Debug, Clone)]
pub struct PeerArgs {
    /// How many peers the run has (checked against the launcher's; read from it when
    /// left out).
    #[arg(long, value_name = "N")]
    pub nodes: Option<usize>,
    /// This peer's rank, 0 to N-1 (checked against the launcher's).
    #[arg(long, value_name = "R")]
    pub node_rank: Option<usize>,
    /// Seconds a peer waits for the others at an exchange before it stops with exit 1,
    /// naming them (a peer that died or hangs); at most 60.
    #[arg(long, value_name = "SECS", default_value_t = PeerArgs::TIMEOUT_S)]
    pub peer_timeout: f64,
}

impl PeerArgs {
    const TIMEOUT_S: f64 = 45.0;
}

/// Alone (no flags), as `demo` trains.
impl Default for PeerArgs {
    fn default() -> Self {
        PeerArgs {
            nodes: None,
            node_rank: None,
            peer_timeout: PeerArgs::TIMEOUT_S,
        }
    }
}

/// The longest a peer waits at an exchange (a peer that died or hangs stops the others
/// within this and the 2 s a lost peer's message is given to reach the launcher: under a minute).
const MAX_TIMEOUT_S: f64 = 55.0;

/// The link to the run's other peers (`None`: this process trains alone). Refuses bad
/// flags, a launch without an MPI launcher and a build without MPI, naming the flag.
pub fn join(args: &PeerArgs) -> anyhow::Result<Option<Box<dyn Collective>>> {
    if !(args.peer_timeout > 0.0 && args.peer_timeout <= MAX_TIMEOUT_S) {
        anyhow::bail!(
            "--peer-timeout must be above 0 and at most {MAX_TIMEOUT_S} seconds, got {}",
            args.peer_timeout
        );
    }
    connect(args)
}

#[cfg(feature = "mpi")]
fn connect(args: &PeerArgs) -> anyhow::Result<Option<Box<dyn Collective>>> {
    let launch = Launch::resolve(args.nodes, args.node_rank)?;
    if !launch.is_peer() {
        return Ok(None);
    }
    use anyhow::Context;
    let within = std::time::Duration::from_secs_f64(args.peer_timeout);
    let peers = talkin_peers::mpi_world::MpiPeers::join(&launch, within)
        .with_context(|| format!("joining as peer {} of {}", launch.rank, launch.size))?;
    Ok(Some(Box::new(peers)))
}

/// A build without MPI trains alone, and says how to build with it when asked for peers.
#[cfg(not(feature = "mpi"))]
fn connect(args: &PeerArgs) -> anyhow::Result<Option<Box<dyn Collective>>> {
    Launch::resolve_alone(args.nodes, args.node_rank)?;
    Ok(None)
}
