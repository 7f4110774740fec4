//! The loop's phases: the recording's `phase` column and the telemetry row's `phase`, by name
//! in the server's status and the page.

/// The `phase` column (docs/recording-format.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Phase {
    HoldZero = 0,
    RampUp = 1,
    HoldMax = 2,
    RampDown = 3,
    Position = 4,
    Reproduction = 5,
    Done = 6,
}

impl Phase {
    /// Every phase, in column-value order.
    pub const ALL: [Phase; 7] = [
        Phase::HoldZero,
        Phase::RampUp,
        Phase::HoldMax,
        Phase::RampDown,
        Phase::Position,
        Phase::Reproduction,
        Phase::Done,
    ];

    /// The phase a column value names, `None` for a value no phase has.
    pub fn from_u8(v: u8) -> Option<Phase> {
        Phase::ALL.get(usize::from(v)).copied()
    }

    /// Its name in status and on the page.
    pub fn name(self) -> &'static str {
        PHASE_NAMES[self as usize]
    }
}

/// Phase names, indexed by column value.
pub const PHASE_NAMES: [&str; 7] = [
    "hold-zero",
    "ramp-up",
    "hold-max",
    "ramp-down",
    "position",
    "reproduction",
    "done",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_values_and_names_agree() {
        for (i, p) in Phase::ALL.iter().enumerate() {
            assert_eq!(*p as usize, i);
            assert_eq!(Phase::from_u8(i as u8), Some(*p));
        }
        assert_eq!(Phase::from_u8(7), None);
        assert_eq!(Phase::Done.name(), "done");
        assert_eq!(Phase::Reproduction.name(), "reproduction");
    }
}
