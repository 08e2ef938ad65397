//! The benchmarked methods and where their results live.
//!
//! A method's result for a state is either its own run folder or another method's: `no-simulation` and
//! `physics-only` reuse `trand`'s t=0 reconstruction and differ only at t=1; `views-6` *is* `trand`
//! (six views is the default) and owns no folder at all.

use trand_io::State;

/// One row of the benchmark.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Full TRAN-D: object-aware 2DGS at t=0 (6 views), physics + refinement at t=1.
    Trand,
    /// t=0 without the object-aware 3D loss; full update at t=1.
    NoObjectLoss,
    /// trand's t=0; t=1 refinement without the physics simulation.
    NoSimulation,
    /// trand's t=0; t=1 physics simulation without the refinement.
    PhysicsOnly,
    /// Plain 2DGS at t=0 (no object channels); full update at t=1.
    #[serde(rename = "plain-2dgs")]
    Plain2dgs,
    /// trand with 3 training views.
    #[serde(rename = "views-3")]
    Views3,
    /// trand with 6 training views (identical to [`Method::Trand`]).
    #[serde(rename = "views-6")]
    Views6,
    /// trand with 12 training views.
    #[serde(rename = "views-12")]
    Views12,
}

/// What `trand update` does at t=1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Update {
    /// Physics simulation and refinement.
    Full,
    /// Refinement only (`--physics off`).
    NoPhysics,
    /// Simulation only (`--refine off`).
    NoRefine,
}

impl Method {
    /// Every method, in table order.
    pub const ALL: [Method; 8] = [
        Method::Trand,
        Method::NoObjectLoss,
        Method::NoSimulation,
        Method::PhysicsOnly,
        Method::Plain2dgs,
        Method::Views3,
        Method::Views6,
        Method::Views12,
    ];

    /// The name used on the command line and as the run folder name.
    pub fn name(self) -> &'static str {
        match self {
            Method::Trand => "trand",
            Method::NoObjectLoss => "no-object-loss",
            Method::NoSimulation => "no-simulation",
            Method::PhysicsOnly => "physics-only",
            Method::Plain2dgs => "plain-2dgs",
            Method::Views3 => "views-3",
            Method::Views6 => "views-6",
            Method::Views12 => "views-12",
        }
    }

    /// The method whose run folder holds this method's result at `state`.
    pub fn source(self, state: State) -> Method {
        match (self, state) {
            (Method::Views6, _) => Method::Trand,
            (Method::NoSimulation | Method::PhysicsOnly, State::T0) => Method::Trand,
            (m, _) => m,
        }
    }

    /// Whether this method has its own run folder at `state`.
    pub fn owns(self, state: State) -> bool {
        self.source(state) == self
    }

    /// `trand reconstruct --method` for a method that owns its t=0 run.
    pub fn reconstruct_method(self) -> &'static str {
        match self {
            Method::NoObjectLoss => "no-object-loss",
            Method::Plain2dgs => "plain-2dgs",
            _ => "trand",
        }
    }

    /// `trand reconstruct --views` for a method that owns its t=0 run.
    pub fn views(self) -> u32 {
        match self {
            Method::Views3 => 3,
            Method::Views12 => 12,
            _ => 6,
        }
    }

    /// What the t=1 update of this method does.
    pub fn update(self) -> Update {
        match self {
            Method::NoSimulation => Update::NoPhysics,
            Method::PhysicsOnly => Update::NoRefine,
            _ => Update::Full,
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Method::ALL.iter().map(|m| m.name()).collect();
                format!(
                    "unknown method `{s}` (expected one of {})",
                    names.join(", ")
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_match_serde() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
            assert_eq!(serde_json::to_value(m).unwrap(), m.name());
        }
        assert!(
            "views-4"
                .parse::<Method>()
                .unwrap_err()
                .contains("views-12")
        );
    }

    #[test]
    fn reused_runs_point_at_trand() {
        assert_eq!(Method::NoSimulation.source(State::T0), Method::Trand);
        assert_eq!(Method::NoSimulation.source(State::T1), Method::NoSimulation);
        assert_eq!(Method::Views6.source(State::T1), Method::Trand);
        assert!(Method::Plain2dgs.owns(State::T0) && Method::Plain2dgs.owns(State::T1));
        assert_eq!(Method::PhysicsOnly.update(), Update::NoRefine);
    }
}
