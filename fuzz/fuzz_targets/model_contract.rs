//! The model contract's parsers (infer-server/src/contract.rs, compiled here as is so the
//! target needs neither ONNX Runtime nor the server): the `haptics.features` list, the
//! `haptics.kind`, and tensor shapes as declared by a model (checked element counts, before
//! anything is allocated). Any input is accepted or refused, never a panic, and an accepted
//! shape's count is the product of its dimensions, within the cap.
#![no_main]

#[path = "../../infer-server/src/contract.rs"]
#[allow(dead_code)]
mod contract;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let mut parts = text.splitn(3, '\n');
    if let Ok(schema) = contract::FeatureSchema::parse(parts.next().unwrap_or("")) {
        assert!(!schema.is_empty());
        for (i, n) in schema.names().iter().enumerate() {
            assert!(!n.is_empty());
            assert_eq!(schema.index_of(n), Some(i), "names are unique");
        }
    }
    if let Some(kind) = contract::ModelKind::parse(parts.next().unwrap_or("")) {
        assert_eq!(contract::ModelKind::parse(kind.as_str()), Some(kind));
    }
    let shape: Vec<i64> = data
        .chunks(8)
        .map(|c| {
            let mut b = [0u8; 8];
            b[..c.len()].copy_from_slice(c);
            // Mostly small dimensions, sometimes anything (negative, huge).
            let v = i64::from_le_bytes(b);
            if v & 0x100 == 0 {
                v & 0xff
            } else {
                v
            }
        })
        .collect();
    if let Ok(n) = contract::checked_elements(&shape) {
        assert!(n <= contract::MAX_TENSOR_ELEMENTS);
        let product = shape
            .iter()
            .try_fold(1i128, |acc, &d| Some(acc * d as i128));
        assert_eq!(product, Some(n as i128));
    }
});
