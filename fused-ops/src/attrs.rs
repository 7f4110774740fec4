//! Reading a node's attributes into checked parameters: typed errors that name the attribute,
//! never a panic (a panic inside ONNX Runtime's callbacks would abort the host process).

use ort::operator::KernelContext;

/// Why a node's attributes cannot make a kernel. Its text is the session's one-line error.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AttrError {
    #[error("{op}: attribute `{name}` is missing or not a {kind}")]
    Missing {
        op: &'static str,
        name: &'static str,
        kind: &'static str,
    },
    #[error("{op}: attribute `{name}` has {got} values, `{other}` has {expected}: they pair up")]
    Length {
        op: &'static str,
        name: &'static str,
        got: usize,
        other: &'static str,
        expected: usize,
    },
    #[error("{op}: attribute `{name}` = {value} is {reason}")]
    Invalid {
        op: &'static str,
        name: &'static str,
        value: f64,
        reason: &'static str,
    },
    #[error("{op}: input `{name}` must have the fixed shape {expected}, the graph declares {got}")]
    Shape {
        op: &'static str,
        name: &'static str,
        expected: String,
        got: String,
    },
}

/// Where attributes come from: ONNX Runtime's kernel info, or a map in the tests.
pub trait Attrs {
    /// A FLOAT attribute.
    fn float(&self, name: &str) -> Option<f32>;
    /// A FLOATS attribute; `None` when absent (an absent list is read as empty by the callers
    /// that allow it: ONNX cannot write an empty list without its type).
    fn floats(&self, name: &str) -> Option<Vec<f32>>;
    /// An INTS attribute.
    fn ints(&self, name: &str) -> Option<Vec<i64>>;
    /// A STRING attribute.
    fn string(&self, name: &str) -> Option<String>;
}

impl Attrs for KernelContext<'_> {
    fn float(&self, name: &str) -> Option<f32> {
        self.get::<f32>(name)
    }
    fn floats(&self, name: &str) -> Option<Vec<f32>> {
        self.get::<Vec<f32>>(name)
    }
    fn ints(&self, name: &str) -> Option<Vec<i64>> {
        self.get::<Vec<i64>>(name)
    }
    fn string(&self, name: &str) -> Option<String> {
        self.get::<String>(name)
    }
}

/// Checked reads for one operator `op`.
pub(crate) struct Reader<'a, A: Attrs + ?Sized> {
    pub op: &'static str,
    pub attrs: &'a A,
}

impl<A: Attrs + ?Sized> Reader<'_, A> {
    /// A required finite float.
    pub fn float(&self, name: &'static str) -> Result<f64, AttrError> {
        let v = self.attrs.float(name).ok_or(AttrError::Missing {
            op: self.op,
            name,
            kind: "float",
        })?;
        self.finite(name, f64::from(v))
    }

    /// A required float > 0.
    pub fn positive(&self, name: &'static str) -> Result<f64, AttrError> {
        let v = self.float(name)?;
        self.check(name, v, v > 0.0, "not positive")
    }

    /// A float list (absent = empty), every value finite.
    pub fn list(&self, name: &'static str) -> Result<Vec<f64>, AttrError> {
        let v = self.attrs.floats(name).unwrap_or_default();
        v.into_iter()
            .map(|x| self.finite(name, f64::from(x)))
            .collect()
    }

    /// A required float list of exactly `len` values, every value finite.
    pub fn list_of(
        &self,
        name: &'static str,
        len: usize,
        what: &'static str,
    ) -> Result<Vec<f64>, AttrError> {
        let v = self.list(name)?;
        self.length(name, v.len(), what, len)?;
        Ok(v)
    }

    /// `name` has `got` values where `what` says `expected`.
    fn length(
        &self,
        name: &'static str,
        got: usize,
        what: &'static str,
        expected: usize,
    ) -> Result<(), AttrError> {
        if got == expected {
            return Ok(());
        }
        Err(AttrError::Length {
            op: self.op,
            name,
            got,
            other: what,
            expected,
        })
    }

    /// A required list of sizes (INTS), every one at least 1.
    pub fn sizes(&self, name: &'static str) -> Result<Vec<usize>, AttrError> {
        let v = self.attrs.ints(name).ok_or(AttrError::Missing {
            op: self.op,
            name,
            kind: "list of ints",
        })?;
        v.into_iter()
            .map(|n| {
                self.check(name, n as f64, n >= 1, "not a size (>= 1)")
                    .map(|_| n as usize)
            })
            .collect()
    }

    /// A required comma-separated list of names (a STRING).
    pub fn names(&self, name: &'static str) -> Result<Vec<String>, AttrError> {
        let v = self.attrs.string(name).ok_or(AttrError::Missing {
            op: self.op,
            name,
            kind: "string",
        })?;
        Ok(v.split(',').map(|s| s.trim().to_string()).collect())
    }

    /// A required list of integers (INTS) of exactly `len` values.
    pub fn ints_of(
        &self,
        name: &'static str,
        len: usize,
        what: &'static str,
    ) -> Result<Vec<i64>, AttrError> {
        let v = self.attrs.ints(name).ok_or(AttrError::Missing {
            op: self.op,
            name,
            kind: "list of ints",
        })?;
        self.length(name, v.len(), what, len)?;
        Ok(v)
    }

    /// The error for `name` = `value`, which is `reason`.
    pub fn invalid(&self, name: &'static str, value: f64, reason: &'static str) -> AttrError {
        AttrError::Invalid {
            op: self.op,
            name,
            value,
            reason,
        }
    }

    /// A float list whose values are all > 0.
    pub fn positive_list(&self, name: &'static str) -> Result<Vec<f64>, AttrError> {
        let v = self.list(name)?;
        for &x in &v {
            self.check(name, x, x > 0.0, "not positive")?;
        }
        Ok(v)
    }

    /// `values` (named `name`) has as many entries as `other` (named `other_name`).
    pub fn paired(
        &self,
        name: &'static str,
        values: &[f64],
        other_name: &'static str,
        other: &[f64],
    ) -> Result<(), AttrError> {
        self.length(name, values.len(), other_name, other.len())
    }

    pub fn check(
        &self,
        name: &'static str,
        value: f64,
        ok: bool,
        reason: &'static str,
    ) -> Result<f64, AttrError> {
        if ok {
            Ok(value)
        } else {
            Err(self.invalid(name, value, reason))
        }
    }

    fn finite(&self, name: &'static str, v: f64) -> Result<f64, AttrError> {
        self.check(name, v, v.is_finite(), "not finite")
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use std::collections::HashMap;

    use super::Attrs;

    /// Attributes from a map: one value is a FLOAT, several (or none) FLOATS; the same values
    /// read as INTS where whole; strings apart.
    pub(crate) struct Map(
        pub HashMap<&'static str, Vec<f32>>,
        pub HashMap<&'static str, String>,
    );

    impl Map {
        pub fn of(pairs: &[(&'static str, Vec<f32>)]) -> Self {
            Self(pairs.iter().cloned().collect(), HashMap::new())
        }
        pub fn with(mut self, name: &'static str, v: Vec<f32>) -> Self {
            self.0.insert(name, v);
            self
        }
        pub fn with_str(mut self, name: &'static str, v: &str) -> Self {
            self.1.insert(name, v.to_string());
            self
        }
    }

    impl Attrs for Map {
        fn float(&self, name: &str) -> Option<f32> {
            self.0.get(name).filter(|v| v.len() == 1).map(|v| v[0])
        }
        fn floats(&self, name: &str) -> Option<Vec<f32>> {
            self.0.get(name).cloned()
        }
        fn ints(&self, name: &str) -> Option<Vec<i64>> {
            self.0
                .get(name)
                .map(|v| v.iter().map(|&x| x as i64).collect())
        }
        fn string(&self, name: &str) -> Option<String> {
            self.1.get(name).cloned()
        }
    }
}
