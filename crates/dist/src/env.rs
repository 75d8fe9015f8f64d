//! The launch environment: what `torchrun`, Kubernetes PyTorchJob and Slurm (`srun`) set.

use crate::DistError;

/// torchrun's default rendezvous port.
pub const DEFAULT_PORT: u16 = 29500;

/// Where this process sits in the job.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DistEnv {
    pub rank: usize,
    pub world_size: usize,
    pub local_rank: usize,
    pub master_addr: String,
    pub master_port: u16,
    /// "torchrun" (RANK / WORLD_SIZE / …) or "slurm" (SLURM_PROCID / SLURM_NTASKS / …).
    pub source: &'static str,
    /// `TORCHELASTIC_USE_AGENT_STORE=True`: torchrun's agent hosts the TCPStore already.
    pub agent_store: bool,
    /// `TORCHELASTIC_RESTART_COUNT` (0 outside torchrun).
    pub restart_count: u64,
}

impl DistEnv {
    /// Read the process environment. `Ok(None)`: not launched as a distributed job (neither
    /// `WORLD_SIZE` nor `SLURM_NTASKS` set).
    pub fn from_env() -> Result<Option<Self>, DistError> {
        Self::from_vars(|k| std::env::var(k).ok())
    }

    /// [`DistEnv::from_env`] over any variable source (tests).
    ///
    /// torchrun variables win; Slurm's are the fallback for each missing one: `SLURM_PROCID`
    /// → RANK, `SLURM_NTASKS` → WORLD_SIZE, `SLURM_LOCALID` → LOCAL_RANK, the first host of
    /// `SLURM_JOB_NODELIST` (`SLURM_NODELIST`) → MASTER_ADDR, and MASTER_PORT defaults to
    /// 20000 + `SLURM_JOB_ID` mod 10000 under Slurm (29500 otherwise), so concurrent jobs on a
    /// node do not collide.
    pub fn from_vars(get: impl Fn(&str) -> Option<String>) -> Result<Option<Self>, DistError> {
        let vars = Vars(get);
        let torchrun = vars.get("WORLD_SIZE").is_some();
        let slurm = !torchrun && vars.get("SLURM_NTASKS").is_some();
        if !torchrun && !slurm {
            return Ok(None);
        }
        let (world_size, rank) = vars.world_size_and_rank()?;
        let local_rank = match vars.pick("LOCAL_RANK", "SLURM_LOCALID") {
            Some((k, v)) => num(&k, v)?,
            None => 0,
        };
        let master_addr = vars.master_addr(world_size)?;
        let master_port = vars.master_port()?;
        Ok(Some(DistEnv {
            rank,
            world_size,
            local_rank,
            master_addr,
            master_port,
            source: if torchrun { "torchrun" } else { "slurm" },
            agent_store: vars
                .get("TORCHELASTIC_USE_AGENT_STORE")
                .is_some_and(|v| v.trim().eq_ignore_ascii_case("true")),
            restart_count: vars
                .get("TORCHELASTIC_RESTART_COUNT")
                .and_then(|v| v.trim().parse().ok())
                .unwrap_or(0),
        }))
    }
}

/// A variable source seen through [`DistEnv::from_vars`]'s rules: blank counts as unset.
struct Vars<F: Fn(&str) -> Option<String>>(F);

impl<F: Fn(&str) -> Option<String>> Vars<F> {
    /// The value of `k`, `None` when unset or blank.
    fn get(&self, k: &str) -> Option<String> {
        (self.0)(k).filter(|v| !v.trim().is_empty())
    }

    /// `primary`'s value, else `fallback`'s, with the name of the variable that was read.
    fn pick(&self, primary: &str, fallback: &str) -> Option<(String, String)> {
        self.get(primary)
            .map(|v| (primary.to_string(), v))
            .or_else(|| self.get(fallback).map(|v| (fallback.to_string(), v)))
    }

    /// `(world_size, rank)` from WORLD_SIZE / SLURM_NTASKS and RANK / SLURM_PROCID:
    /// at least one process, and the rank below the world size.
    fn world_size_and_rank(&self) -> Result<(usize, usize), DistError> {
        let (wk, wv) = self
            .pick("WORLD_SIZE", "SLURM_NTASKS")
            .ok_or_else(|| DistError::Env {
                var: "WORLD_SIZE".into(),
                reason: "not set".into(),
            })?;
        let world_size = num(&wk, wv)?;
        if world_size == 0 {
            return Err(DistError::Env {
                var: wk,
                reason: "must be at least 1".into(),
            });
        }
        let (rk, rv) = self
            .pick("RANK", "SLURM_PROCID")
            .ok_or_else(|| DistError::Env {
                var: "RANK".into(),
                reason: format!(
                    "not set but {wk}={world_size} is: every process needs its rank (launch with \
                     torchrun, srun or `depthsense train --nproc N`)"
                ),
            })?;
        let rank = num(&rk, rv)?;
        if rank >= world_size {
            return Err(DistError::Env {
                var: rk,
                reason: format!("rank {rank} is not below {wk}={world_size}"),
            });
        }
        Ok((world_size, rank))
    }

    /// MASTER_ADDR, else the first host of the Slurm node list, else loopback for a
    /// one-process job.
    fn master_addr(&self, world_size: usize) -> Result<String, DistError> {
        Ok(match self.get("MASTER_ADDR") {
            Some(a) => a.trim().to_string(),
            None => match self
                .get("SLURM_JOB_NODELIST")
                .or_else(|| self.get("SLURM_NODELIST"))
            {
                Some(list) => first_host(&list).ok_or_else(|| DistError::Env {
                    var: "MASTER_ADDR".into(),
                    reason: format!(
                        "not set, and the first host of SLURM_JOB_NODELIST={list:?} cannot be \
                         read: set MASTER_ADDR to the first node's name"
                    ),
                })?,
                None if world_size == 1 => "127.0.0.1".into(),
                None => {
                    return Err(DistError::Env {
                        var: "MASTER_ADDR".into(),
                        reason: "not set (the address of rank 0's host)".into(),
                    })
                }
            },
        })
    }

    /// MASTER_PORT, else 20000 + SLURM_JOB_ID mod 10000, else [`DEFAULT_PORT`].
    fn master_port(&self) -> Result<u16, DistError> {
        Ok(match self.get("MASTER_PORT") {
            Some(p) => p.trim().parse::<u16>().map_err(|_| DistError::Env {
                var: "MASTER_PORT".into(),
                reason: format!("{p:?} is not a port number"),
            })?,
            None => match self
                .get("SLURM_JOB_ID")
                .and_then(|j| j.trim().parse::<u64>().ok())
            {
                Some(job) => 20000 + (job % 10000) as u16,
                None => DEFAULT_PORT,
            },
        })
    }
}

/// Parse variable `k`'s value `v` as a non-negative integer.
fn num(k: &str, v: String) -> Result<usize, DistError> {
    v.trim().parse::<usize>().map_err(|_| DistError::Env {
        var: k.to_string(),
        reason: format!("{v:?} is not a non-negative integer"),
    })
}

/// First host of a Slurm node list: `node[01-04,07],gpu3` → `node01`; `a,b` → `a`.
/// `None` for forms this does not read (e.g. several bracket groups in one name).
pub fn first_host(list: &str) -> Option<String> {
    let list = list.trim();
    // The first entry ends at the first comma outside brackets.
    let mut depth = 0i32;
    let mut end = list.len();
    for (i, c) in list.char_indices() {
        match c {
            '[' => depth += 1,
            ']' => depth -= 1,
            ',' if depth == 0 => {
                end = i;
                break;
            }
            _ => {}
        }
    }
    let entry = &list[..end];
    if entry.is_empty() {
        return None;
    }
    let Some(open) = entry.find('[') else {
        return Some(entry.to_string());
    };
    let close = entry.find(']')?;
    if close < open || entry[close + 1..].contains('[') {
        return None;
    }
    let prefix = &entry[..open];
    let first = entry[open + 1..close].split(',').next()?;
    let lo = first.split('-').next()?;
    if lo.is_empty() || !lo.chars().all(|c| c.is_ascii_digit()) {
        return None;
    }
    Some(format!("{prefix}{lo}{}", &entry[close + 1..]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn env(pairs: &[(&str, &str)]) -> Result<Option<DistEnv>, DistError> {
        let m: HashMap<String, String> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        DistEnv::from_vars(|k| m.get(k).cloned())
    }

    #[test]
    fn torchrun_variables() {
        let e = env(&[
            ("RANK", "3"),
            ("WORLD_SIZE", "8"),
            ("LOCAL_RANK", "1"),
            ("MASTER_ADDR", "10.0.0.2"),
            ("MASTER_PORT", "1234"),
        ])
        .unwrap()
        .unwrap();
        assert_eq!(
            (e.rank, e.world_size, e.local_rank, e.master_port),
            (3, 8, 1, 1234)
        );
        assert_eq!(e.master_addr, "10.0.0.2");
        assert_eq!(e.source, "torchrun");
        assert!(!e.agent_store);
        assert_eq!(env(&[]).unwrap(), None);
        let e = env(&[
            ("RANK", "0"),
            ("WORLD_SIZE", "2"),
            ("MASTER_ADDR", "h"),
            ("TORCHELASTIC_USE_AGENT_STORE", "True"),
            ("TORCHELASTIC_RESTART_COUNT", "2"),
        ])
        .unwrap()
        .unwrap();
        assert!(e.agent_store);
        assert_eq!(e.restart_count, 2);
    }

    #[test]
    fn errors_name_the_variable() {
        let e = env(&[("WORLD_SIZE", "2"), ("MASTER_ADDR", "h")]).unwrap_err();
        assert!(e.to_string().contains("RANK"), "{e}");
        let e = env(&[("WORLD_SIZE", "2"), ("RANK", "2"), ("MASTER_ADDR", "h")]).unwrap_err();
        assert!(e.to_string().contains("RANK"), "{e}");
        let e = env(&[("WORLD_SIZE", "two"), ("RANK", "0")]).unwrap_err();
        assert!(e.to_string().contains("WORLD_SIZE"), "{e}");
        let e = env(&[("WORLD_SIZE", "2"), ("RANK", "0")]).unwrap_err();
        assert!(e.to_string().contains("MASTER_ADDR"), "{e}");
        let e = env(&[
            ("WORLD_SIZE", "2"),
            ("RANK", "0"),
            ("MASTER_ADDR", "h"),
            ("MASTER_PORT", "99999"),
        ])
        .unwrap_err();
        assert!(e.to_string().contains("MASTER_PORT"), "{e}");
    }

    #[test]
    fn slurm_fallback() {
        let e = env(&[
            ("SLURM_NTASKS", "4"),
            ("SLURM_PROCID", "2"),
            ("SLURM_LOCALID", "0"),
            ("SLURM_JOB_NODELIST", "gpu[07-08]"),
            ("SLURM_JOB_ID", "123456"),
        ])
        .unwrap()
        .unwrap();
        assert_eq!((e.rank, e.world_size, e.local_rank), (2, 4, 0));
        assert_eq!(e.master_addr, "gpu07");
        assert_eq!(e.master_port, 23456);
        assert_eq!(e.source, "slurm");
    }

    #[test]
    fn nodelists() {
        assert_eq!(first_host("node[01-04,07],gpu3").as_deref(), Some("node01"));
        assert_eq!(first_host("a,b").as_deref(), Some("a"));
        assert_eq!(first_host("n[3,5]-ib").as_deref(), Some("n3-ib"));
        assert_eq!(first_host("x[1-2]y[3-4]"), None);
        assert_eq!(first_host(""), None);
    }
}
