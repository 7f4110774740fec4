//! Commands, server to loop (the mailbox channel): a typed enum, and the one place that turns
//! it into the ring's fixed words and back.
//!
//! Producers (infer-server) build a [`Command`] with named fields and the loop (rt-loop's
//! mailbox) receives one; nobody else sees the positional words. Decoding checks the words like
//! any outside input: an unknown kind, an unreadable name or a start value out of range is
//! refused with a [`DecodeError`] naming the field, never misread.

use shm_ring::{layout_id, DecodeError, FixedStr, Message, FIXED_STR_WORDS};

use crate::experiment_args::{ExperimentArgs, VALUE_NAMES};

/// A small fixed command, server to loop (the mailbox). Every command carries a server-chosen
/// `id`, so a log line can name it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// Start the experiment named `experiment` (`abstraction`, `reproduction`, `shadow`, ...;
    /// the loop refuses names it does not run) with `args` over its configured defaults.
    Start {
        id: u64,
        experiment: FixedStr,
        args: ExperimentArgs,
    },
    /// Stop the running experiment (the loop ramps down safely).
    Stop { id: u64 },
    /// Set the loop parameter `name` to `value` (finite).
    SetParameter { id: u64, name: FixedStr, value: f64 },
}

impl Command {
    /// The server-chosen id.
    pub fn id(&self) -> u64 {
        match *self {
            Command::Start { id, .. } | Command::Stop { id } | Command::SetParameter { id, .. } => {
                id
            }
        }
    }
}

/// The words: `id`, `kind` tag, `name` (experiment or parameter; empty for a stop), four values
/// (a start's [`ExperimentArgs::to_values`], a set's value then NaN, a stop's all NaN).
const KIND: usize = 1;
const NAME: usize = 2;
const VALUES: usize = NAME + FIXED_STR_WORDS;
const VALUE_WORDS: usize = 4;

const KIND_START: u64 = 1;
const KIND_STOP: u64 = 2;
const KIND_SET: u64 = 3;

impl Message for Command {
    const WORDS: usize = VALUES + VALUE_WORDS;
    // The wire layout is unchanged from the positional struct, so the id is too.
    const LAYOUT_ID: u64 = layout_id(
        "Command v1: id u64, kind u64 (1 start, 2 stop, 3 set), name [u8; 32], values [f64; 4]",
    );

    fn encode(&self, out: &mut [u64]) {
        let (kind, name, values) = match *self {
            Command::Start {
                experiment, args, ..
            } => (KIND_START, experiment, args.to_values()),
            Command::Stop { .. } => (KIND_STOP, FixedStr::default(), [f64::NAN; VALUE_WORDS]),
            Command::SetParameter { name, value, .. } => {
                (KIND_SET, name, [value, f64::NAN, f64::NAN, f64::NAN])
            }
        };
        out[0] = self.id();
        out[KIND] = kind;
        out[NAME..VALUES].copy_from_slice(&name.to_words());
        for (word, value) in out[VALUES..Self::WORDS].iter_mut().zip(&values) {
            *word = value.to_bits();
        }
    }

    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        let id = w[0];
        let name = FixedStr::from_words(&w[NAME..VALUES]).ok_or(DecodeError::InvalidField {
            field: "Command.name",
            value: w[NAME],
        })?;
        let value = |i: usize| f64::from_bits(w[VALUES + i]);
        match w[KIND] {
            KIND_START => {
                let values = [value(0), value(1), value(2), value(3)];
                let args =
                    ExperimentArgs::checked(&values).map_err(|i| DecodeError::InvalidField {
                        field: VALUE_NAMES[i],
                        value: w[VALUES + i],
                    })?;
                Ok(Command::Start {
                    id,
                    experiment: name,
                    args,
                })
            }
            KIND_STOP => Ok(Command::Stop { id }),
            KIND_SET if value(0).is_finite() => Ok(Command::SetParameter {
                id,
                name,
                value: value(0),
            }),
            KIND_SET => Err(DecodeError::InvalidField {
                field: "Command::SetParameter.value (finite)",
                value: w[VALUES],
            }),
            other => Err(DecodeError::InvalidField {
                field: "Command.kind",
                value: other,
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn words(c: &Command) -> Vec<u64> {
        let mut w = vec![0u64; Command::WORDS];
        c.encode(&mut w);
        w
    }

    #[test]
    fn every_kind_round_trips_through_the_words() {
        let name = |s| FixedStr::new(s).unwrap();
        for c in [
            Command::Start {
                id: 7,
                experiment: name("abstraction"),
                args: ExperimentArgs {
                    ramp_rate: Some(1.8),
                    cycles: Some(3),
                    f_max_start: None,
                    f_max_step: Some(0.0),
                },
            },
            Command::Start {
                id: 8,
                experiment: name("shadow"),
                args: ExperimentArgs::default(),
            },
            Command::Stop { id: u64::MAX },
            Command::SetParameter {
                id: 9,
                name: name("f_max_newtons"),
                value: -2.5,
            },
        ] {
            let w = words(&c);
            assert_eq!(Command::decode(&w), Ok(c));
            assert_eq!(Command::decode(&w).unwrap().id(), c.id());
        }
        // The wire layout is the positional one: NaN where a start leaves the default.
        let w = words(&Command::Start {
            id: 1,
            experiment: name("reproduction"),
            args: ExperimentArgs {
                cycles: Some(2),
                ..Default::default()
            },
        });
        assert_eq!((w[0], w[KIND]), (1, KIND_START));
        assert!(f64::from_bits(w[VALUES]).is_nan());
        assert_eq!(f64::from_bits(w[VALUES + 1]), 2.0);
    }

    #[test]
    fn unknown_kinds_and_bad_values_are_refused_naming_the_field() {
        let stop = words(&Command::Stop { id: 1 });
        let mut w = stop.clone();
        w[KIND] = 99;
        assert_eq!(
            Command::decode(&w),
            Err(DecodeError::InvalidField {
                field: "Command.kind",
                value: 99
            })
        );
        let start = words(&Command::Start {
            id: 2,
            experiment: FixedStr::new("abstraction").unwrap(),
            args: ExperimentArgs::default(),
        });
        for (i, bad) in [
            (0, f64::INFINITY),
            (0, 0.0),
            (1, 1.5),
            (1, 1001.0),
            (2, f64::NEG_INFINITY),
            (3, -1.0),
        ] {
            let mut w = start.clone();
            w[VALUES + i] = bad.to_bits();
            assert_eq!(
                Command::decode(&w),
                Err(DecodeError::InvalidField {
                    field: VALUE_NAMES[i],
                    value: bad.to_bits()
                }),
                "value {i} = {bad}"
            );
        }
        let mut w = words(&Command::SetParameter {
            id: 3,
            name: FixedStr::new("x").unwrap(),
            value: 1.0,
        });
        w[VALUES] = f64::NAN.to_bits();
        assert!(Command::decode(&w).is_err(), "a set needs a finite value");
        let mut w = stop;
        w[NAME] |= 0xff << 56; // garbage after the NUL padding
        assert!(Command::decode(&w).is_err());
    }
}
