//! One way the three binaries (rt-loop, infer-server, hapticctl) parse their command lines:
//! a negative number is a flag's value, never taken for a flag (`--rate-hz -1` reaches the
//! range check and its message, instead of clap's "unexpected argument '-1'"). A usage error
//! exits with status 2 in all three (clap's own; docs/control-plane.md, "Exit status").
use clap::{CommandFactory, FromArgMatches};

/// `command` and all its subcommands with negative numbers accepted as values.
pub fn allow_negative_numbers(command: clap::Command) -> clap::Command {
    #[allow(deprecated)]
    command
        .allow_negative_numbers(true)
        .mut_subcommands(allow_negative_numbers)
}

/// Parses the process's arguments into `T` (exits with clap's message and status 2 on a
/// usage error, as `T::parse()` does).
pub fn parse<T: CommandFactory + FromArgMatches>() -> T {
    parse_from(std::env::args_os())
}

/// [`parse`] over given arguments (tests).
pub fn parse_from<T, I, A>(args: I) -> T
where
    T: CommandFactory + FromArgMatches,
    I: IntoIterator<Item = A>,
    A: Into<std::ffi::OsString> + Clone,
{
    try_parse_from(args).unwrap_or_else(|e| e.exit())
}

/// [`parse_from`] returning clap's error instead of exiting.
pub fn try_parse_from<T, I, A>(args: I) -> Result<T, clap::Error>
where
    T: CommandFactory + FromArgMatches,
    I: IntoIterator<Item = A>,
    A: Into<std::ffi::OsString> + Clone,
{
    let mut matches = allow_negative_numbers(T::command()).try_get_matches_from(args)?;
    T::from_arg_matches_mut(&mut matches)
}
