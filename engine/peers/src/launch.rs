//! Which peer this process is, from `--nodes`/`--node-rank` and the variables launchers
//! set. MPI's launcher (`mpirun`, or `srun` under Slurm) starts the peers and tells each
//! its rank; the flags say what the user expects and are checked against it. Scheduler
//! variables (Slurm's `SLURM_NTASKS`, torchrun's `WORLD_SIZE`) without an MPI launcher
//! mean a job that asked for several peers but started them alone: refused, not run as
//! N unrelated single runs.

/// What started this process.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Launcher {
    /// One process, no peers.
    Alone,
    /// An MPI launcher; `via` names the variables it set.
    Mpi { via: &'static str },
}

/// This process's place among the peers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Launch {
    pub size: usize,
    pub rank: usize,
    pub launcher: Launcher,
}

/// A launch that cannot run, naming the flag or variable at fault.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LaunchError {
    #[error("{name} must be {expected}, got {value:?}")]
    Value {
        name: String,
        expected: &'static str,
        value: String,
    },
    #[error("--node-rank {rank} is out of range for {size} peers (0 to {})", size - 1)]
    RankOutOfRange { rank: usize, size: usize },
    #[error("--node-rank {0} needs --nodes (how many peers in all)")]
    RankWithoutNodes(usize),
    #[error(
        "{what}, but this process was not started by an MPI launcher: start every peer with \
         one `mpirun -n {size} talkin train ...` (or `srun` inside a Slurm allocation); \
         {alone}"
    )]
    NoLauncher {
        what: String,
        size: usize,
        alone: &'static str,
    },
    #[error("{flag} says {flag_value}, but {via} started this process as {mpi_value}")]
    Disagrees {
        flag: &'static str,
        flag_value: usize,
        via: &'static str,
        mpi_value: usize,
    },
    #[error(
        "{asked}, but this talkin was built without MPI and trains alone: build it with \
         `cargo build --release --features mpi` (needs Open MPI and libclang: `apt-get install \
         openmpi-bin libopenmpi-dev libclang-dev`) and start the peers with `mpirun -n {size} \
         talkin train ...`; to train alone, leave --nodes out"
    )]
    NoMpi { asked: String, size: usize },
}

/// The MPI launchers' variables, most specific first: (size, rank, what sets them).
const MPI_VARS: [(&str, &str, &str); 2] = [
    (
        "OMPI_COMM_WORLD_SIZE",
        "OMPI_COMM_WORLD_RANK",
        "Open MPI's mpirun",
    ),
    (
        "PMI_SIZE",
        "PMI_RANK",
        "a PMI launcher (MPICH's mpiexec, srun)",
    ),
];

/// Schedulers' variables that ask for several processes.
const SCHEDULER_VARS: [(&str, &str); 2] = [
    ("SLURM_NTASKS", "Slurm's SLURM_NTASKS"),
    ("WORLD_SIZE", "torchrun's WORLD_SIZE"),
];

impl Launch {
    /// One process, no peers.
    pub fn alone() -> Launch {
        Launch {
            size: 1,
            rank: 0,
            launcher: Launcher::Alone,
        }
    }

    /// Whether this process has peers (or was started by an MPI launcher, even of one).
    pub fn is_peer(&self) -> bool {
        self.launcher != Launcher::Alone
    }

    /// The launch from the flags and the process's environment.
    pub fn resolve(nodes: Option<usize>, node_rank: Option<usize>) -> Result<Launch, LaunchError> {
        Launch::resolve_in(nodes, node_rank, &|k| std::env::var(k).ok())
    }

    /// The launch of a build without MPI: alone, or [`LaunchError::NoMpi`] (saying how to
    /// build with MPI) where `--nodes`, an MPI launcher or a scheduler asks for peers.
    pub fn resolve_alone(
        nodes: Option<usize>,
        node_rank: Option<usize>,
    ) -> Result<Launch, LaunchError> {
        Launch::resolve_alone_in(nodes, node_rank, &|k| std::env::var(k).ok())
    }

    /// [`Launch::resolve_alone`] with the environment read through `env`.
    pub fn resolve_alone_in(
        nodes: Option<usize>,
        node_rank: Option<usize>,
        env: &dyn Fn(&str) -> Option<String>,
    ) -> Result<Launch, LaunchError> {
        if let Some(size) = nodes.filter(|&n| n > 1) {
            return Err(LaunchError::NoMpi {
                asked: format!("--nodes {size} asks for {size} peers"),
                size,
            });
        }
        match Launch::resolve_in(nodes, node_rank, env) {
            Ok(launch) if launch.size > 1 => {
                let via = match launch.launcher {
                    Launcher::Mpi { via } => via,
                    Launcher::Alone => "the launcher",
                };
                Err(LaunchError::NoMpi {
                    asked: format!("{via} started this process as one of {} peers", launch.size),
                    size: launch.size,
                })
            }
            Ok(_) => Ok(Launch::alone()),
            Err(LaunchError::NoLauncher { what, size, .. }) => {
                Err(LaunchError::NoMpi { asked: what, size })
            }
            Err(e) => Err(e),
        }
    }

    /// [`Launch::resolve`] with the environment read through `env`.
    pub fn resolve_in(
        nodes: Option<usize>,
        node_rank: Option<usize>,
        env: &dyn Fn(&str) -> Option<String>,
    ) -> Result<Launch, LaunchError> {
        if nodes == Some(0) {
            return Err(LaunchError::Value {
                name: "--nodes".into(),
                expected: "at least 1",
                value: "0".into(),
            });
        }
        match (nodes, node_rank) {
            (None, Some(rank)) => return Err(LaunchError::RankWithoutNodes(rank)),
            (Some(size), Some(rank)) if rank >= size => {
                return Err(LaunchError::RankOutOfRange { rank, size });
            }
            _ => {}
        }
        let number = |name: &str| -> Result<Option<usize>, LaunchError> {
            match env(name) {
                None => Ok(None),
                Some(v) => v
                    .trim()
                    .parse::<usize>()
                    .map(Some)
                    .map_err(|_| LaunchError::Value {
                        name: name.to_string(),
                        expected: "a whole number",
                        value: v,
                    }),
            }
        };
        for (size_var, rank_var, via) in MPI_VARS {
            let (Some(size), Some(rank)) = (number(size_var)?, number(rank_var)?) else {
                continue;
            };
            if size == 0 || rank >= size {
                return Err(LaunchError::Value {
                    name: rank_var.to_string(),
                    expected: "below its size variable",
                    value: format!("{rank} of {size}"),
                });
            }
            check_flags(nodes, node_rank, size, rank, via)?;
            return Ok(Launch {
                size,
                rank,
                launcher: Launcher::Mpi { via },
            });
        }
        // srun --mpi=pmix sets PMIx's rank before MPI starts, and Slurm's task count.
        if let Some(rank) = number("PMIX_RANK")? {
            let via = "a PMIx launcher (srun --mpi=pmix)";
            let Some(size) = nodes.or(number("SLURM_NTASKS")?) else {
                return Err(LaunchError::Value {
                    name: "SLURM_NTASKS".into(),
                    expected: "set beside PMIX_RANK (or --nodes given)",
                    value: "unset".into(),
                });
            };
            check_flags(None, node_rank, size, rank, via)?;
            if rank >= size {
                return Err(LaunchError::Value {
                    name: "PMIX_RANK".into(),
                    expected: "below SLURM_NTASKS (or --nodes)",
                    value: format!("{rank} of {size}"),
                });
            }
            return Ok(Launch {
                size,
                rank,
                launcher: Launcher::Mpi { via },
            });
        }
        // No MPI launcher: alone, unless the flags or a scheduler ask for more.
        if let Some(size) = nodes {
            if size > 1 {
                return Err(LaunchError::NoLauncher {
                    what: format!("--nodes {size} asks for {size} peers"),
                    size,
                    alone: "without peers, leave --nodes out",
                });
            }
            return Ok(Launch::alone());
        }
        for (var, name) in SCHEDULER_VARS {
            if let Some(size) = number(var)?.filter(|&n| n > 1) {
                return Err(LaunchError::NoLauncher {
                    what: format!("{name} is {size}"),
                    size,
                    alone: "to train alone in this allocation, give --nodes 1",
                });
            }
        }
        Ok(Launch::alone())
    }
}

/// Refuses `--nodes` or `--node-rank` that disagree with the `size` and `rank` a launcher
/// (`via`) gave this process.
pub(crate) fn check_flags(
    nodes: Option<usize>,
    node_rank: Option<usize>,
    size: usize,
    rank: usize,
    via: &'static str,
) -> Result<(), LaunchError> {
    for (flag, given, actual) in [("--nodes", nodes, size), ("--node-rank", node_rank, rank)] {
        if let Some(v) = given.filter(|&v| v != actual) {
            return Err(LaunchError::Disagrees {
                flag,
                flag_value: v,
                via,
                mpi_value: actual,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(vars: &[(&str, &str)]) -> impl Fn(&str) -> Option<String> {
        let vars: Vec<(String, String)> = vars
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        move |k| vars.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone())
    }

    #[test]
    fn alone_without_flags_or_launchers() {
        assert_eq!(
            Launch::resolve_in(None, None, &env(&[])),
            Ok(Launch::alone())
        );
        assert_eq!(
            Launch::resolve_in(Some(1), Some(0), &env(&[])),
            Ok(Launch::alone())
        );
        // --nodes 1 overrides an allocation's task count.
        assert_eq!(
            Launch::resolve_in(Some(1), None, &env(&[("SLURM_NTASKS", "4")])),
            Ok(Launch::alone())
        );
    }

    #[test]
    fn mpirun_gives_the_rank_and_the_flags_must_agree() {
        let mpi = env(&[("OMPI_COMM_WORLD_SIZE", "2"), ("OMPI_COMM_WORLD_RANK", "1")]);
        let l = Launch::resolve_in(Some(2), Some(1), &mpi).unwrap();
        assert_eq!((l.size, l.rank), (2, 1));
        assert!(l.is_peer());
        assert_eq!(Launch::resolve_in(None, None, &mpi).unwrap().rank, 1);
        let e = Launch::resolve_in(Some(3), None, &mpi).unwrap_err();
        assert!(e.to_string().contains("--nodes says 3"), "{e}");
        let e = Launch::resolve_in(Some(2), Some(0), &mpi).unwrap_err();
        assert!(e.to_string().contains("--node-rank says 0"), "{e}");
        // PMI's variables (MPICH, srun) too.
        let pmi = env(&[("PMI_SIZE", "4"), ("PMI_RANK", "3")]);
        assert_eq!(Launch::resolve_in(None, None, &pmi).unwrap().rank, 3);
        // srun --mpi=pmix: PMIx's rank and Slurm's task count.
        let pmix = env(&[
            ("PMIX_RANK", "1"),
            ("SLURM_NTASKS", "2"),
            ("SLURM_PROCID", "1"),
        ]);
        let l = Launch::resolve_in(None, None, &pmix).unwrap();
        assert_eq!((l.size, l.rank), (2, 1));
    }

    #[test]
    fn a_build_without_mpi_refuses_peers_naming_the_feature() {
        let none = env(&[]);
        assert_eq!(
            Launch::resolve_alone_in(None, None, &none),
            Ok(Launch::alone())
        );
        assert_eq!(
            Launch::resolve_alone_in(Some(1), Some(0), &none),
            Ok(Launch::alone())
        );
        let mpi2 = env(&[("OMPI_COMM_WORLD_SIZE", "2"), ("OMPI_COMM_WORLD_RANK", "0")]);
        let slurm = env(&[("SLURM_NTASKS", "4")]);
        for (nodes, env, says) in [
            (
                Some(2),
                &none as &dyn Fn(&str) -> Option<String>,
                "--nodes 2 asks for 2 peers",
            ),
            (Some(2), &mpi2, "--nodes 2 asks for 2 peers"),
            (
                None,
                &mpi2,
                "Open MPI's mpirun started this process as one of 2 peers",
            ),
            (None, &slurm, "SLURM_NTASKS"),
        ] {
            let e = Launch::resolve_alone_in(nodes, None, env).unwrap_err();
            assert!(matches!(e, LaunchError::NoMpi { .. }), "{e}");
            let msg = e.to_string();
            assert!(msg.contains(says), "{msg}");
            assert!(msg.contains("--features mpi"), "{msg}");
        }
        // One rank under mpirun trains alone; a bad flag is still named as such.
        let mpi1 = env(&[("OMPI_COMM_WORLD_SIZE", "1"), ("OMPI_COMM_WORLD_RANK", "0")]);
        assert_eq!(
            Launch::resolve_alone_in(None, None, &mpi1),
            Ok(Launch::alone())
        );
        let e = Launch::resolve_alone_in(None, Some(1), &none).unwrap_err();
        assert_eq!(e, LaunchError::RankWithoutNodes(1));
    }

    #[test]
    fn bad_values_name_the_flag_or_variable() {
        let none = env(&[]);
        let e = Launch::resolve_in(Some(2), Some(2), &none).unwrap_err();
        assert_eq!(e, LaunchError::RankOutOfRange { rank: 2, size: 2 });
        assert!(e.to_string().contains("--node-rank 2"));
        assert!(
            Launch::resolve_in(Some(0), None, &none)
                .unwrap_err()
                .to_string()
                .contains("--nodes")
        );
        assert!(
            Launch::resolve_in(None, Some(1), &none)
                .unwrap_err()
                .to_string()
                .contains("--nodes")
        );
        let e = Launch::resolve_in(Some(2), Some(0), &none).unwrap_err();
        assert!(e.to_string().contains("mpirun -n 2"), "{e}");
        let e = Launch::resolve_in(None, None, &env(&[("WORLD_SIZE", "8")])).unwrap_err();
        assert!(e.to_string().contains("torchrun's WORLD_SIZE is 8"), "{e}");
        let e = Launch::resolve_in(None, None, &env(&[("SLURM_NTASKS", "x")])).unwrap_err();
        assert!(e.to_string().contains("SLURM_NTASKS"), "{e}");
        let bad = env(&[("OMPI_COMM_WORLD_SIZE", "2"), ("OMPI_COMM_WORLD_RANK", "5")]);
        assert!(
            Launch::resolve_in(None, None, &bad)
                .unwrap_err()
                .to_string()
                .contains("OMPI_COMM_WORLD_RANK")
        );
    }
}
