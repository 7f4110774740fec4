//! Commands, server to loop (the mailbox channel), and their word encoding.

use shm_ring::{layout_id, DecodeError, FixedStr, Message, FIXED_STR_WORDS};

/// What a command asks the loop to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum CommandKind {
    /// Start the experiment named in `name` with `values` as its arguments.
    StartExperiment = 1,
    /// Stop the running experiment (the loop ramps down safely).
    StopExperiment = 2,
    /// Set the loop parameter named in `name` to `values[0]`.
    SetParameter = 3,
}

impl CommandKind {
    fn from_u64(v: u64) -> Option<Self> {
        match v {
            1 => Some(CommandKind::StartExperiment),
            2 => Some(CommandKind::StopExperiment),
            3 => Some(CommandKind::SetParameter),
            _ => None,
        }
    }
}

/// Values a command carries.
pub const COMMAND_VALUES: usize = 4;

/// A small fixed command, server to loop (the mailbox). The loop validates it like any other
/// outside input: names it does not know and values out of range are refused, not applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    /// Server-chosen id, so an acknowledgement or a log line can name the command.
    pub id: u64,
    pub kind: CommandKind,
    /// Experiment name (`StartExperiment`) or parameter name (`SetParameter`).
    pub name: FixedStr,
    pub values: [f64; COMMAND_VALUES],
}

impl Message for Command {
    const WORDS: usize = 2 + FIXED_STR_WORDS + COMMAND_VALUES;
    const LAYOUT_ID: u64 = layout_id(
        "Command v1: id u64, kind u64 (1 start, 2 stop, 3 set), name [u8; 32], values [f64; 4]",
    );

    fn encode(&self, out: &mut [u64]) {
        out[0] = self.id;
        out[1] = self.kind as u64;
        out[2..2 + FIXED_STR_WORDS].copy_from_slice(&self.name.to_words());
        for (word, value) in out[2 + FIXED_STR_WORDS..].iter_mut().zip(&self.values) {
            *word = value.to_bits();
        }
    }

    fn decode(w: &[u64]) -> Result<Self, DecodeError> {
        let kind = CommandKind::from_u64(w[1]).ok_or(DecodeError::InvalidField {
            field: "Command.kind",
            value: w[1],
        })?;
        let name =
            FixedStr::from_words(&w[2..2 + FIXED_STR_WORDS]).ok_or(DecodeError::InvalidField {
                field: "Command.name",
                value: w[2],
            })?;
        let mut values = [0.0; COMMAND_VALUES];
        for (value, word) in values.iter_mut().zip(&w[2 + FIXED_STR_WORDS..Self::WORDS]) {
            *value = f64::from_bits(*word);
        }
        Ok(Command {
            id: w[0],
            kind,
            name,
            values,
        })
    }
}
