//! Reference steps (`haptics.reference`, docs/model-contract.md): rows an exported model
//! carries with the force its exporter's ONNX Runtime computed for each, stepping from the zero
//! state. Whatever runs the graph steps them once when it opens it and refuses the graph where a
//! force differs by more than the entry's tolerance: it would compute another law than the one
//! exported (a kernel built before the exporter ignores attributes it does not know; a graph
//! edited after its export).
//!
//! Both processes check them, each where it opens a graph: infer-server when it loads a model
//! to serve (`model::engine`), rt-loop when a material file names an ONNX object (`object::
//! onnx`). The entry's format, its limits and the comparison live here once, so the two
//! cannot come to disagree on what "the same force" means. Off the real-time path: parsing
//! allocates.
//!
//! ```
//! use haptics_ort_host::reference::{check, parse, CheckError};
//!
//! let r = parse(r#"{"inputs":[[0.01,0.0],[0.02,0.0]],"force":[3.0,6.0],"tolerance_n":1e-4}"#, 2)
//!     .unwrap();
//! // a spring of 300 N/m agrees with its export ...
//! assert!(check(&r, |row| Ok::<f32, ()>(300.0 * row[0])).is_ok());
//! // ... one of 301 N/m does not, at the first step
//! match check(&r, |row| Ok::<f32, ()>(301.0 * row[0])) {
//!     Err(CheckError::Mismatch(m)) => assert_eq!(m.step, 0),
//!     _ => panic!("a mismatch"),
//! }
//! ```

/// The metadata key.
pub const META_REFERENCE: &str = "haptics.reference";

/// Most reference steps an entry may carry; the exporter writes 32.
pub const MAX_REFERENCE_STEPS: usize = 256;

/// The largest tolerance an entry may declare, N: a check looser than this checks nothing a
/// user would feel (the force sensor resolves about 1 mN).
pub const MAX_REFERENCE_TOLERANCE_N: f32 = 1e-3;

/// Most bytes of the entry (16 KiB: the exporter's 32 steps of nine features take about 5 KiB).
pub const MAX_REFERENCE_BYTES: usize = 16 << 10;

/// Reference steps, checked when parsed: 1 to [`MAX_REFERENCE_STEPS`] rows, each of the
/// graph's feature count, every value finite, a tolerance in (0, [`MAX_REFERENCE_TOLERANCE_N`]].
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    /// Rows in the graph's input order (the `features` tensor's columns).
    pub inputs: Vec<Vec<f32>>,
    /// The force the exporter computed for each row.
    pub force: Vec<f32>,
    pub tolerance_n: f32,
}

/// Parses an entry for a graph of `n` features; the error is the reason alone (the caller
/// names the key and the file; the entry's text is kilobytes of numbers, never quoted).
pub fn parse(raw: &str, n: usize) -> Result<Reference, String> {
    #[derive(serde::Deserialize)]
    struct Doc {
        inputs: Vec<Vec<f32>>,
        force: Vec<f32>,
        tolerance_n: f32,
    }
    if raw.len() > MAX_REFERENCE_BYTES {
        return Err(format!(
            "{} bytes, over the {MAX_REFERENCE_BYTES} bytes allowed",
            raw.len()
        ));
    }
    let doc: Doc = serde_json::from_str(raw).map_err(|e| {
        format!(
            "not a JSON object {{\"inputs\": rows, \"force\": forces, \"tolerance_n\": N}}: {e}"
        )
    })?;
    let k = doc.force.len();
    if k == 0 || k > MAX_REFERENCE_STEPS || doc.inputs.len() != k {
        return Err(format!(
            "{} input rows for {k} forces (1 to {MAX_REFERENCE_STEPS} steps, a row per force)",
            doc.inputs.len()
        ));
    }
    if let Some((i, row)) = doc.inputs.iter().enumerate().find(|(_, r)| r.len() != n) {
        return Err(format!(
            "row {i} has {} values; the graph has {n} features",
            row.len()
        ));
    }
    let all = doc.inputs.iter().flatten().chain(doc.force.iter());
    if all.copied().any(|v| !v.is_finite()) {
        return Err("a value is not finite".into());
    }
    if !(doc.tolerance_n > 0.0 && doc.tolerance_n <= MAX_REFERENCE_TOLERANCE_N) {
        return Err(format!(
            "tolerance_n {} is not in (0, {MAX_REFERENCE_TOLERANCE_N}] N",
            doc.tolerance_n
        ));
    }
    Ok(Reference {
        inputs: doc.inputs,
        force: doc.force,
        tolerance_n: doc.tolerance_n,
    })
}

/// The first step whose force is further than the tolerance from the exporter's.
#[derive(Debug, Clone, PartialEq)]
pub struct Mismatch {
    /// 0-based.
    pub step: usize,
    pub steps: usize,
    pub input: Vec<f32>,
    pub expected: f32,
    pub got: f32,
    pub tolerance: f32,
}

impl std::fmt::Display for Mismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "reference step {} of {} (input {:?}) computes {} N here, where its export computed \
             {} N (tolerance {} N)",
            self.step, self.steps, self.input, self.got, self.expected, self.tolerance
        )
    }
}

/// Why [`check`] refused: a step failed to run, or a force differs.
#[derive(Debug)]
pub enum CheckError<E> {
    Step(E),
    Mismatch(Mismatch),
}

/// Steps every row in order through `step` (which runs the graph on one row, carrying its
/// state from the previous row; the caller starts it from zeros) and compares each force with
/// the exporter's. A NaN force is a mismatch too.
pub fn check<E>(
    r: &Reference,
    mut step: impl FnMut(&[f32]) -> Result<f32, E>,
) -> Result<(), CheckError<E>> {
    let steps = r.force.len();
    for (i, (row, &expected)) in r.inputs.iter().zip(&r.force).enumerate() {
        let got = step(row).map_err(CheckError::Step)?;
        // a NaN answer is a mismatch too: written so that it compares false
        let within = (got - expected).abs() <= r.tolerance_n;
        if !within {
            return Err(CheckError::Mismatch(Mismatch {
                step: i,
                steps,
                input: row.clone(),
                expected,
                got,
                tolerance: r.tolerance_n,
            }));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(inputs: &str, force: &str, tol: &str) -> String {
        format!(r#"{{"inputs":{inputs},"force":{force},"tolerance_n":{tol}}}"#)
    }

    /// The forms of a malformed entry are tested through infer-server's `parse_reference`
    /// (contract_check.rs), which wraps this parser; here the cap it does not reach (its
    /// loader refuses a larger entry before parsing) and the happy path.
    #[test]
    fn an_entry_over_the_cap_is_refused_before_it_is_read() {
        let e = parse(&" ".repeat(MAX_REFERENCE_BYTES + 1), 2).unwrap_err();
        assert!(e.contains("bytes, over the"), "{e}");
        let r = parse(&entry("[[1,2]]", "[3]", "1e-4"), 2).unwrap();
        assert_eq!(
            (r.inputs, r.force, r.tolerance_n),
            (vec![vec![1.0, 2.0]], vec![3.0], 1e-4)
        );
    }

    #[test]
    fn check_stops_at_the_first_differing_step_and_nan_differs() {
        let r = parse(&entry("[[1],[2],[3]]", "[2,4,6]", "1e-3"), 1).unwrap();
        let mut seen = 0;
        let out = check(&r, |row| {
            seen += 1;
            Ok::<f32, ()>(if row[0] == 2.0 {
                f32::NAN
            } else {
                2.0 * row[0]
            })
        });
        match out {
            Err(CheckError::Mismatch(m)) => {
                assert_eq!((m.step, m.steps, &m.input), (1, 3, &vec![2.0]));
                assert!(m.got.is_nan() && m.expected == 4.0);
                assert!(m.to_string().contains("reference step 1 of 3"), "{m}");
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(seen, 2, "nothing stepped past the mismatch");
        let failed = check(&r, |_| Err::<f32, &str>("boom"));
        assert!(matches!(failed, Err(CheckError::Step("boom"))));
        assert!(check(&r, |row| Ok::<f32, ()>(2.0 * row[0] + 5e-4)).is_ok());
    }
}
