//! Typed access to JSON fields with errors that name the file and the field path.

use std::path::Path;

use serde_json::Value;

use crate::error::IoError;

pub(crate) fn read_json(path: &Path) -> Result<Value, IoError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    serde_json::from_str(&text).map_err(|source| IoError::Json {
        path: path.into(),
        source,
    })
}

/// A JSON object being read, remembering where it came from.
pub(crate) struct Obj<'a> {
    pub path: &'a Path,
    /// Dotted field path of this object, e.g. `frames[3]`; empty at the top level.
    pub at: String,
    pub value: &'a Value,
}

impl<'a> Obj<'a> {
    pub fn root(path: &'a Path, value: &'a Value) -> Result<Self, IoError> {
        if !value.is_object() {
            return Err(IoError::field(
                path,
                "(top level)",
                "expected a JSON object",
            ));
        }
        Ok(Self {
            path,
            at: String::new(),
            value,
        })
    }

    /// An element of a top-level array, named `at` (e.g. `[3]`).
    pub fn element(path: &'a Path, at: String, value: &'a Value) -> Result<Self, IoError> {
        if !value.is_object() {
            return Err(IoError::field(path, at, "expected an object"));
        }
        Ok(Self { path, at, value })
    }

    pub fn name(&self, key: &str) -> String {
        if self.at.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.at)
        }
    }

    pub fn err(&self, key: &str, reason: impl Into<String>) -> IoError {
        IoError::field(self.path, self.name(key), reason)
    }

    pub fn opt(&self, key: &str) -> Option<&'a Value> {
        self.value.get(key).filter(|v| !v.is_null())
    }

    pub fn req(&self, key: &str) -> Result<&'a Value, IoError> {
        self.opt(key).ok_or_else(|| self.err(key, "missing"))
    }

    pub fn child(&self, key: &str) -> Result<Obj<'a>, IoError> {
        let v = self.req(key)?;
        if !v.is_object() {
            return Err(self.err(key, "expected an object"));
        }
        Ok(Obj {
            path: self.path,
            at: self.name(key),
            value: v,
        })
    }

    pub fn f64(&self, key: &str) -> Result<f64, IoError> {
        self.req(key)?
            .as_f64()
            .ok_or_else(|| self.err(key, "expected a number"))
    }

    pub fn opt_f64(&self, key: &str) -> Result<Option<f64>, IoError> {
        self.opt(key)
            .map(|v| v.as_f64().ok_or_else(|| self.err(key, "expected a number")))
            .transpose()
    }

    pub fn opt_u32(&self, key: &str) -> Result<Option<u32>, IoError> {
        self.opt(key)
            .map(|v| {
                v.as_u64()
                    .and_then(|u| u32::try_from(u).ok())
                    .ok_or_else(|| self.err(key, "expected a non-negative integer"))
            })
            .transpose()
    }

    pub fn str(&self, key: &str) -> Result<&'a str, IoError> {
        self.req(key)?
            .as_str()
            .ok_or_else(|| self.err(key, "expected a string"))
    }

    pub fn opt_str(&self, key: &str) -> Result<Option<&'a str>, IoError> {
        self.opt(key)
            .map(|v| v.as_str().ok_or_else(|| self.err(key, "expected a string")))
            .transpose()
    }

    /// A flat array of exactly `n` numbers.
    pub fn floats(&self, key: &str, n: usize) -> Result<Vec<f64>, IoError> {
        let a = self
            .req(key)?
            .as_array()
            .ok_or_else(|| self.err(key, format!("expected an array of {n} numbers")))?;
        if a.len() != n {
            return Err(self.err(key, format!("expected {n} numbers, found {}", a.len())));
        }
        a.iter()
            .map(|v| v.as_f64().ok_or_else(|| self.err(key, "expected numbers")))
            .collect()
    }

    /// A 4x4 matrix given as 4 rows of 4 numbers, row-major.
    pub fn mat4(&self, key: &str) -> Result<[[f64; 4]; 4], IoError> {
        let rows = self
            .req(key)?
            .as_array()
            .ok_or_else(|| self.err(key, "expected a 4x4 array"))?;
        if rows.len() != 4 {
            return Err(self.err(key, format!("expected 4 rows, found {}", rows.len())));
        }
        let mut m = [[0.0; 4]; 4];
        for (r, row) in rows.iter().enumerate() {
            let row = row
                .as_array()
                .filter(|a| a.len() == 4)
                .ok_or_else(|| self.err(key, format!("row {r} is not 4 numbers")))?;
            for (c, v) in row.iter().enumerate() {
                m[r][c] = v
                    .as_f64()
                    .ok_or_else(|| self.err(key, format!("row {r} holds a non-number")))?;
            }
        }
        Ok(m)
    }

    /// The elements of an array of objects, each as an [`Obj`] named `key[i]`.
    pub fn objects(&self, key: &str) -> Result<Vec<Obj<'a>>, IoError> {
        let a = self
            .req(key)?
            .as_array()
            .ok_or_else(|| self.err(key, "expected an array"))?;
        a.iter()
            .enumerate()
            .map(|(i, v)| {
                let at = format!("{}[{i}]", self.name(key));
                if v.is_object() {
                    Ok(Obj {
                        path: self.path,
                        at,
                        value: v,
                    })
                } else {
                    Err(IoError::field(self.path, at, "expected an object"))
                }
            })
            .collect()
    }
}
