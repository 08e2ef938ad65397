//! `RUN/run.json`: what a run folder holds, written by `trand reconstruct` and `trand update` and read
//! by `trand update`, `trand render`, `trand eval` and `trand report`.
//!
//! The fields every reader relies on are typed here. What one stage alone records (the t = 0
//! identity association and vessel tops, the t = 1 matching and relocations, ...) is written by that
//! stage from its own types into [`RunManifest::details`], which keeps every key and value of the
//! file: a reader that does not know a key passes it through untouched.
//!
//! Every field is optional when reading, so a hand-made folder with `{"state": "t0"}` is a run. The
//! file is written with its keys in alphabetical order (the order of a JSON object map), the order
//! it has always had, so that scripts diffing two runs see only changed values.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::IoError;
use crate::run_layout::RUN_JSON;
use crate::view::State;

/// The typed contents of `run.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunManifest {
    /// `"t0"` or `"t1"` (see [`RunManifest::state`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub state: Option<String>,
    /// The method's name (`trand`, `plain-2dgs`, ...).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method: Option<String>,
    /// Number of t = 0 training views.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub views: Option<u32>,
    /// The sequence folder, canonicalised.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data: Option<String>,
    /// Fingerprint of the sequence's t = 0 poses and object ids: `trand update` refuses another
    /// sequence's run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sequence_fingerprint: Option<String>,
    /// Far clamp of the rendered depth (metres); `Some(None)` is a recorded `null`, no clamp.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "present"
    )]
    pub depth_clamp_m: Option<Option<f32>>,
    /// `(object id, channel)` of every object channel of the surfels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub object_channels: Option<Vec<(u16, usize)>>,
    /// Seconds per stage (`total_s`, `wall_s`, ...).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timings: Option<BTreeMap<String, f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub num_surfels: Option<usize>,
    /// `(iteration, loss)` of every training step.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loss_curve: Option<Vec<(u32, f32)>>,
    /// Peak resident memory in MiB; written as `null` where the platform does not report it.
    #[serde(default)]
    pub peak_rss_mb: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threads: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trand_version: Option<String>,
    /// Every other key: the records of one stage, in its own types' JSON.
    #[serde(flatten)]
    pub details: Map<String, Value>,
}

/// A field that is present deserialises to `Some`, even when it is `null`.
fn present<'de, D, T>(d: D) -> Result<Option<Option<T>>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<T>::deserialize(d).map(Some)
}

impl RunManifest {
    /// The recorded state; `Ok(None)` when none is, `Err` (the reason) when it is not t0 or t1.
    pub fn state(&self) -> Result<Option<State>, String> {
        self.state.as_deref().map(str::parse).transpose()
    }

    /// Adds a stage's record under `key` (its serde JSON).
    pub fn detail(&mut self, key: &str, value: impl Serialize) -> &mut Self {
        let v = serde_json::to_value(value).expect("run records serialise to JSON");
        self.details.insert(key.to_string(), v);
        self
    }

    /// The identity rule the run used: `identity.used` at t = 0, `identity` at t = 1.
    pub fn identity_used(&self) -> Option<&str> {
        match self.details.get("identity")? {
            Value::String(s) => Some(s),
            v => v.get("used")?.as_str(),
        }
    }

    /// The file's bytes: pretty JSON, keys in alphabetical order.
    pub fn to_json(&self) -> Vec<u8> {
        let v = serde_json::to_value(self).expect("run manifests serialise to JSON");
        serde_json::to_vec_pretty(&v).expect("JSON values serialise")
    }

    /// Reads `RUN/run.json`; `Ok(None)` when the folder has none.
    pub fn read(run: &Path) -> Result<Option<Self>, IoError> {
        let path = run.join(RUN_JSON);
        if !path.is_file() {
            return Ok(None);
        }
        let text = std::fs::read(&path).map_err(|e| IoError::io(&path, e))?;
        serde_json::from_slice(&text)
            .map(Some)
            .map_err(|source| IoError::Json { path, source })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_manifest_reads_back_with_every_key() {
        let mut m = RunManifest {
            state: Some("t1".into()),
            depth_clamp_m: Some(Some(1.25)),
            object_channels: Some(vec![(3, 1), (7, 2)]),
            loss_curve: Some(vec![(1, 0.5)]),
            ..Default::default()
        };
        m.detail("identity", "overlap").detail("movable", [7u16]);
        let back: RunManifest = serde_json::from_slice(&m.to_json()).unwrap();
        assert_eq!(back, m);
        assert_eq!(back.state(), Ok(Some(State::T1)));
        assert_eq!(back.identity_used(), Some("overlap"));
    }

    #[test]
    fn keys_are_written_in_alphabetical_order_with_null_memory() {
        let m = RunManifest {
            state: Some("t0".into()),
            data: Some("/d".into()),
            ..Default::default()
        };
        let text = String::from_utf8(m.to_json()).unwrap();
        assert_eq!(
            text,
            "{\n  \"data\": \"/d\",\n  \"peak_rss_mb\": null,\n  \"state\": \"t0\"\n}"
        );
    }

    #[test]
    fn a_null_clamp_is_recorded_and_an_absent_one_is_not() {
        let null: RunManifest = serde_json::from_str(r#"{"depth_clamp_m": null}"#).unwrap();
        assert_eq!(null.depth_clamp_m, Some(None));
        let absent: RunManifest = serde_json::from_str("{}").unwrap();
        assert_eq!(absent.depth_clamp_m, None);
        assert_eq!(absent.state(), Ok(None));
    }

    #[test]
    fn an_unknown_state_is_an_error() {
        let m: RunManifest = serde_json::from_str(r#"{"state": "t7"}"#).unwrap();
        assert!(m.state().unwrap_err().contains("t7"));
    }

    #[test]
    fn the_t0_identity_record_gives_the_rule_used() {
        let m: RunManifest =
            serde_json::from_str(r#"{"identity": {"requested": "auto", "used": "ids"}}"#).unwrap();
        assert_eq!(m.identity_used(), Some("ids"));
    }
}
