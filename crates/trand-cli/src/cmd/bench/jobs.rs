//! The deterministic job list of a bench and its sharding.
//!
//! A **job** is one t=0 reconstruction and the t=1 updates built on it, run in order as **steps**
//! (one `(sequence, method, state)` run folder each). Jobs are independent of each other, so shard
//! `i/n` simply takes the jobs whose index in the list is `≡ i (mod n)`, and any split of the list
//! reproduces the same run folders.
//!
//! Order: sequences by name, then the t=0 owners in table order ([`Method::ALL`]); inside a job the
//! t=0 step first, then its t=1 steps in table order.

use trand_io::State;
use trand_report::Method;

/// One run folder to produce.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Step {
    pub sequence: String,
    /// The method owning the run folder ([`Method::owns`]).
    pub method: Method,
    pub state: State,
}

/// A t=0 run and the t=1 runs that start from it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Job {
    pub steps: Vec<Step>,
}

/// All jobs for `sequences` (sorted by the caller) and the selected `methods` (any order, repeats ok).
pub fn job_list(sequences: &[String], methods: &[Method]) -> Vec<Job> {
    let mut t0: Vec<Method> = methods.iter().map(|m| m.source(State::T0)).collect();
    t0.sort();
    t0.dedup();
    let mut t1: Vec<Method> = methods.iter().map(|m| m.source(State::T1)).collect();
    t1.sort();
    t1.dedup();
    let mut jobs = Vec::new();
    for s in sequences {
        for &root in &t0 {
            let step = |method, state| Step {
                sequence: s.clone(),
                method,
                state,
            };
            let mut steps = vec![step(root, State::T0)];
            steps.extend(
                t1.iter()
                    .filter(|m| m.source(State::T0) == root)
                    .map(|&m| step(m, State::T1)),
            );
            jobs.push(Job { steps });
        }
    }
    jobs
}

/// `--shard i/n`: this process runs jobs `i, i+n, i+2n, ...`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl Shard {
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// The jobs of this shard, in list order.
    pub fn take(self, jobs: Vec<Job>) -> Vec<Job> {
        jobs.into_iter()
            .enumerate()
            .filter(|(i, _)| i % self.count == self.index)
            .map(|(_, j)| j)
            .collect()
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let bad =
            |why: &str| format!("--shard `{s}`: {why} (expected i/n with 0 <= i < n, e.g. 0/2)");
        let (i, n) = s.split_once('/').ok_or_else(|| bad("no `/`"))?;
        let index: usize = i.trim().parse().map_err(|_| bad("i is not a number"))?;
        let count: usize = n.trim().parse().map_err(|_| bad("n is not a number"))?;
        if count == 0 {
            return Err(bad("n must be at least 1"));
        }
        if index >= count {
            return Err(bad("i must be below n"));
        }
        Ok(Shard { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seqs() -> Vec<String> {
        vec!["a".into(), "b".into(), "c".into()]
    }

    fn steps(jobs: &[Job]) -> Vec<Step> {
        jobs.iter().flat_map(|j| j.steps.clone()).collect()
    }

    #[test]
    fn shards_partition_the_job_list_in_order() {
        let all = job_list(&seqs(), &Method::ALL);
        for n in 1..=4 {
            let mut union: Vec<(usize, Job)> = Vec::new();
            for i in 0..n {
                let shard = Shard { index: i, count: n };
                for j in shard.take(all.clone()) {
                    let pos = all.iter().position(|x| *x == j).unwrap();
                    assert_eq!(pos % n, i);
                    union.push((pos, j));
                }
            }
            union.sort_by_key(|(p, _)| *p);
            assert_eq!(
                union.into_iter().map(|(_, j)| j).collect::<Vec<_>>(),
                all,
                "n = {n}"
            );
        }
    }

    #[test]
    fn job_list_is_deterministic_and_independent_of_method_order() {
        let mut rev = Method::ALL.to_vec();
        rev.reverse();
        rev.push(Method::Trand);
        assert_eq!(job_list(&seqs(), &Method::ALL), job_list(&seqs(), &rev));
    }

    #[test]
    fn every_owned_run_is_made_once_and_t1_follows_its_t0() {
        let all = job_list(&["s".into()], &Method::ALL);
        // t0 owners: trand, no-object-loss, plain-2dgs, views-3, views-12.
        assert_eq!(all.len(), 5);
        let st = steps(&all);
        for m in Method::ALL {
            for state in [State::T0, State::T1] {
                let n = st
                    .iter()
                    .filter(|s| s.method == m && s.state == state)
                    .count();
                assert_eq!(n, usize::from(m.owns(state)), "{m} {}", state.as_str());
            }
        }
        let trand_job = &all[0];
        assert_eq!(
            trand_job.steps[0],
            Step {
                sequence: "s".into(),
                method: Method::Trand,
                state: State::T0
            }
        );
        let t1: Vec<Method> = trand_job.steps[1..].iter().map(|s| s.method).collect();
        assert_eq!(
            t1,
            vec![Method::Trand, Method::NoSimulation, Method::PhysicsOnly]
        );
    }

    #[test]
    fn reusing_methods_pull_in_the_t0_they_need() {
        let st = steps(&job_list(&["s".into()], &[Method::PhysicsOnly]));
        let got: Vec<(Method, State)> = st.iter().map(|s| (s.method, s.state)).collect();
        assert_eq!(
            got,
            vec![(Method::Trand, State::T0), (Method::PhysicsOnly, State::T1)]
        );
    }

    #[test]
    fn bad_shard_specs_are_rejected_with_the_reason() {
        assert_eq!("1/3".parse::<Shard>(), Ok(Shard { index: 1, count: 3 }));
        assert!("0/0".parse::<Shard>().unwrap_err().contains("at least 1"));
        assert!("3/2".parse::<Shard>().unwrap_err().contains("below n"));
        assert!("x/2".parse::<Shard>().unwrap_err().contains("not a number"));
        assert!("2".parse::<Shard>().unwrap_err().contains("no `/`"));
    }
}
