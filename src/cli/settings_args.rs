//! The run settings as command-line flags, declared from the library's table of settings
//! ([`Settings::FIELDS`]): one flag per setting, with its help text, parsed by the library
//! ([`Settings::set`]). A setting added to the library is a flag here without an edit.

use clap::{Arg, ArgAction, ArgMatches, Args, Command, FromArgMatches};
use vkinverse::settings::{Arity, Field};
use vkinverse::Settings;

/// One layer of run settings given as flags.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SettingsArgs(pub Settings);

/// The flag of setting `f`: its help is the setting's documentation, its lines joined.
fn arg(f: &Field) -> Arg {
    let help = f.help.lines().map(str::trim).collect::<Vec<_>>().join(" ");
    let arg = Arg::new(f.key).long(f.key.replace('_', "-")).help(help.trim().to_string()).action(ArgAction::Set);
    match f.arity {
        // A negative value reaches the library's own check, which names the flag.
        Arity::Value(name) => arg.value_name(name).allow_negative_numbers(true),
        Arity::Switch => arg.value_name("BOOL").num_args(0..=1).default_missing_value("true"),
    }
}

impl FromArgMatches for SettingsArgs {
    fn from_arg_matches(matches: &ArgMatches) -> Result<Self, clap::Error> {
        let mut settings = Settings::default();
        for f in Settings::FIELDS {
            if let Some(text) = matches.get_one::<String>(f.key) {
                settings.set(f.key, text).map_err(|e| clap::Error::raw(clap::error::ErrorKind::ValueValidation, format!("{} {}\n", f.flag(), e.message)))?;
            }
        }
        Ok(SettingsArgs(settings))
    }

    fn update_from_arg_matches(&mut self, matches: &ArgMatches) -> Result<(), clap::Error> {
        let update = Self::from_arg_matches(matches)?;
        for f in Settings::FIELDS {
            if matches.contains_id(f.key) && matches.value_source(f.key).is_some() {
                // Only the flags given replace this layer's values.
                self.0 = self.0.then(&update.0);
                break;
            }
        }
        Ok(())
    }
}

impl Args for SettingsArgs {
    fn augment_args(cmd: Command) -> Command {
        Settings::FIELDS.iter().fold(cmd, |cmd, f| cmd.arg(arg(f)))
    }

    fn augment_args_for_update(cmd: Command) -> Command {
        Self::augment_args(cmd)
    }
}
