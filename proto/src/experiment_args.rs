//! The experiment options a start asks for: ramp rate, cycles, first peak force, peak step.
//! Written once for everything that starts an experiment: `rt-loop run` and `rt-loop serve`
//! (the defaults of the runs it starts), `hapticctl experiment start`, and the loop's mailbox,
//! which carries them as the start command's four values. With cargo feature `args` they are
//! a `clap::Args` group (`--ramp-rate`, `--cycles`, `--f-max-start`, `--f-max-step`) that each
//! command line flattens; hapticctl gets them from this crate without linking rt-loop.

/// What a start may set; `None` leaves the loop's configured value.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "args", derive(clap::Args))]
pub struct ExperimentArgs {
    /// Force ramp rate, N/s.
    #[cfg_attr(feature = "args", arg(long))]
    pub ramp_rate: Option<f64>,
    /// Number of ramp cycles.
    #[cfg_attr(feature = "args", arg(long))]
    pub cycles: Option<u32>,
    /// Peak force of the first cycle, N.
    #[cfg_attr(feature = "args", arg(long))]
    pub f_max_start: Option<f64>,
    /// Peak force added each cycle, N.
    #[cfg_attr(feature = "args", arg(long))]
    pub f_max_step: Option<f64>,
}

/// Why the values of a start were refused.
pub const BAD_VALUES: &str = "bad experiment parameter (ramp rate > 0, cycles integer 1..1000, f_max_start > 0, f_max_step >= 0)";

impl ExperimentArgs {
    /// The mailbox's encoding: `[ramp_rate, cycles, f_max_start, f_max_step]`, NaN = not set.
    pub fn to_values(&self) -> [f64; 4] {
        let or_nan = |v: Option<f64>| v.unwrap_or(f64::NAN);
        [
            or_nan(self.ramp_rate),
            or_nan(self.cycles.map(f64::from)),
            or_nan(self.f_max_start),
            or_nan(self.f_max_step),
        ]
    }

    /// Reads the mailbox's four values (NaN = not set), checked like any outside input: a
    /// ramp rate > 0, cycles a whole number in 1..=1000, a first peak > 0, a step >= 0, all
    /// finite; anything else is refused with [`BAD_VALUES`].
    pub fn from_values(values: &[f64; 4]) -> Result<ExperimentArgs, &'static str> {
        Self::checked(values).map_err(|_| BAD_VALUES)
    }

    /// [`Self::from_values`], the refusal naming the first bad value: its index into
    /// [`VALUE_NAMES`] (the command decoder reports it).
    pub fn checked(values: &[f64; 4]) -> Result<ExperimentArgs, usize> {
        let mut out = [None; 4];
        for (i, v) in values.iter().enumerate() {
            if v.is_nan() {
                continue;
            }
            let ok = v.is_finite()
                && match i {
                    0 => *v > 0.0,
                    1 => *v >= 1.0 && v.fract() == 0.0 && *v <= 1000.0,
                    2 => *v > 0.0,
                    _ => *v >= 0.0,
                };
            if !ok {
                return Err(i);
            }
            out[i] = Some(*v);
        }
        Ok(ExperimentArgs {
            ramp_rate: out[0],
            cycles: out[1].map(|c| c as u32),
            f_max_start: out[2],
            f_max_step: out[3],
        })
    }
}

/// What each of the four values must be, in [`ExperimentArgs::to_values`] order (the names a
/// refused command's decode error gives).
pub const VALUE_NAMES: [&str; 4] = [
    "Command::Start.args.ramp_rate (finite, > 0)",
    "Command::Start.args.cycles (whole number 1..=1000)",
    "Command::Start.args.f_max_start (finite, > 0)",
    "Command::Start.args.f_max_step (finite, >= 0)",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_round_trip_and_bad_ones_are_refused() {
        let a = ExperimentArgs {
            ramp_rate: Some(2.5),
            cycles: Some(7),
            f_max_start: None,
            f_max_step: Some(0.0),
        };
        assert_eq!(ExperimentArgs::from_values(&a.to_values()), Ok(a));
        assert_eq!(
            ExperimentArgs::from_values(&[f64::NAN; 4]),
            Ok(ExperimentArgs::default())
        );
        for bad in [
            [0.0, f64::NAN, f64::NAN, f64::NAN],
            [f64::NAN, 1.5, f64::NAN, f64::NAN],
            [f64::NAN, 1001.0, f64::NAN, f64::NAN],
            [f64::NAN, f64::NAN, f64::INFINITY, f64::NAN],
            [f64::NAN, f64::NAN, f64::NAN, -1.0],
        ] {
            assert_eq!(
                ExperimentArgs::from_values(&bad),
                Err(BAD_VALUES),
                "{bad:?}"
            );
        }
    }
}
