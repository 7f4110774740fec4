//! The feature names: the ONE hand-written list of the system (rt-loop's feature extraction,
//! the segment's schema, the model contract, and the generated `train/`/`web-ui/` lists all
//! come from here).

/// Most feature values one step can carry (a `FeatureMsg` holds this many; the segment's
/// schema holds as many names).
pub const MAX_FEATURES: usize = 16;

const _: () = assert!(MAX_FEATURES == shm_ring::MAX_SCHEMA_NAMES);

/// The names the loop publishes to a served model (the shared-memory segment's schema, in
/// `FeatureMsg::values` order): the nine of thesis Table 3.1 ([`THESIS_FEATURES`]), then
/// `f_previous` = F(t-1), the force committed the step before, in N (train/'s
/// better-conditioned alternative to the ratios, used by its `*_fb` networks; not a recorded
/// column: train/ derives it from a recording).
pub const SCHEMA_NAMES: [&str; 10] = [
    "position_x",
    "velocity",
    "acceleration",
    "f_previous_x",
    "f_previous_v",
    "f_previous_a",
    "cycle_no",
    "deformation",
    "area_fx",
    "f_previous",
];

/// The nine feature names of thesis Table 3.1, in order (docs/recording-format.md): the
/// first nine of [`SCHEMA_NAMES`].
pub const THESIS_FEATURES: [&str; 9] = first(&SCHEMA_NAMES);

/// The first `N` names of `all`.
const fn first<const N: usize>(all: &[&'static str]) -> [&'static str; N] {
    let mut out = [""; N];
    let mut i = 0;
    while i < N {
        out[i] = all[i];
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thesis_features_are_the_schema_without_f_previous() {
        assert_eq!(THESIS_FEATURES[..], SCHEMA_NAMES[..9]);
        assert_eq!(SCHEMA_NAMES[9], "f_previous");
        assert!(SCHEMA_NAMES.len() <= MAX_FEATURES);
    }
}
