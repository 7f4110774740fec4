//! The model contract (infer-server/src/model/contract.rs and contract_check.rs, compiled here as
//! they are, so the target needs neither ONNX Runtime nor the server): a model's `haptics.*`
//! metadata entries and its declared inputs and outputs, as ONNX Runtime reports them, are
//! accepted or refused with a `ModelError`, never a panic; what is accepted is what the engine
//! may allocate: a features shape of ones and `n`, a state shape within the element cap.
//!
//! Input: metadata lines (features, kind, units, provenance, state size, previous force,
//! reference steps; an empty line is a missing entry), a 0xFF byte, then the declared tensors, 3 bytes + dims each.
#![no_main]

#[path = "../../infer-server/src/model/contract.rs"]
#[allow(dead_code)]
mod contract;
#[path = "../../infer-server/src/model/contract_check.rs"]
#[allow(dead_code)]
mod contract_check;

use contract_check::{check_declared, parse_metadata, Declared, ModelError};

/// Names a declared tensor can have: the contract's, and one it does not know.
const NAMES: [&str; 7] = ["features", "h_in", "c_in", "force", "h_out", "c_out", "x"];
const KEYS: [&str; 7] = [
    contract::META_FEATURES,
    contract::META_KIND,
    contract::META_UNITS,
    contract::META_PROVENANCE,
    contract::META_STATE_SIZE,
    contract::META_PREVIOUS_FORCE,
    contract::META_REFERENCE,
];

/// The declared inputs and outputs described by `spec`.
fn declared(spec: &[u8]) -> (Vec<Declared>, Vec<Declared>) {
    let (mut inputs, mut outputs) = (Vec::new(), Vec::new());
    let mut rest = spec;
    while let [name, flags, rank, tail @ ..] = rest {
        let rank = (*rank % 5) as usize;
        let mut dims = Vec::with_capacity(rank);
        let mut tail = tail;
        for _ in 0..rank {
            let Some((&d, t)) = tail.split_first() else {
                break;
            };
            tail = t;
            // Mostly small dimensions, -1 (dynamic), or a few huge ones.
            dims.push(match d {
                0..=199 => i64::from(d % 20),
                200..=239 => -1,
                240..=249 => 1 << (d - 200),
                _ => i64::MAX - i64::from(d),
            });
        }
        rest = tail;
        let name = NAMES[usize::from(*name) % NAMES.len()].to_string();
        let shape = if flags & 2 == 0 {
            Ok(dims)
        } else {
            Err(ModelError::BadShape {
                name: name.clone(),
                detail: "must be a float32 tensor, is Int64".into(),
            })
        };
        if flags & 1 == 0 {
            inputs.push((name, shape));
        } else {
            outputs.push((name, shape));
        }
    }
    (inputs, outputs)
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let split = data.iter().position(|&b| b == 0xff).unwrap_or(data.len());
    let text = String::from_utf8_lossy(&data[..split]);
    let values: Vec<&str> = text.split('\n').collect();
    let custom = |key: &str| {
        let i = KEYS.iter().position(|k| *k == key)?;
        values
            .get(i)
            .filter(|v| !v.is_empty())
            .map(|v| v.to_string())
    };
    if let Ok(schema) = contract::FeatureSchema::parse(values[0]) {
        for (i, name) in schema.names().iter().enumerate() {
            assert_eq!(schema.index_of(name), Some(i), "names are unique");
        }
    }
    let Ok(meta) = parse_metadata(custom) else {
        return;
    };
    let n = meta.features.len();
    assert!(n > 0 && meta.features.iter().all(|f| !f.is_empty()));
    if meta.kind == contract::ModelKind::Stateful {
        assert!(meta.state_size.is_some_and(|h| h > 0));
    }
    if let Some(r) = &meta.reference {
        // what the engine steps without another check: a row per force, each of n values
        assert!(!r.force.is_empty() && r.force.len() <= contract::MAX_REFERENCE_STEPS);
        assert_eq!(r.inputs.len(), r.force.len());
        assert!(r.inputs.iter().all(|row| row.len() == n));
        assert!(r.tolerance_n > 0.0 && r.tolerance_n <= contract::MAX_REFERENCE_TOLERANCE_N);
    }
    let _ = contract_check::map_features(&meta.features, &contract::FeatureSchema::standard());
    let (inputs, outputs) = declared(data.get(split + 1..).unwrap_or(&[]));
    let Ok(sig) = check_declared(&inputs, &outputs, &meta) else {
        return;
    };
    let (last, leading) = sig.features_shape.split_last().expect("rank 2 or 3");
    assert_eq!(*last, n as i64);
    assert!(leading.iter().all(|&d| d == 1));
    match (&sig.state_shape, meta.kind) {
        (None, contract::ModelKind::Stateless) => {}
        (Some(state), contract::ModelKind::Stateful) => {
            let elements = contract::checked_elements(state).expect("checked before accepting");
            assert!(elements <= contract::MAX_TENSOR_ELEMENTS);
            assert!(state.iter().all(|&d| d >= 0));
            if let Some(h) = meta.state_size {
                assert_eq!(state.last().copied(), Some(h as i64));
            }
        }
        other => panic!("state shape {other:?} for a {} model", meta.kind),
    }
});
