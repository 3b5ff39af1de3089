//! `human2nav plugin ...`

use clap::Subcommand;
use human2nav_plugin::inspect_library;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Subcommand)]
pub enum PluginCommand {
    /// Load a plugin library and print its name, version, ABI version, what it provides and
    /// everything the host checked (file, tables, function slots, sizes; each factory's
    /// instance when it can be created without a config).
    ///
    /// The OS's library extension and the `lib` prefix may be omitted, and `{profile}` stands
    /// for this binary's cargo profile (`debug` or `release`), e.g.
    /// `human2nav plugin inspect 'target/{profile}/human2nav_personal_space'`.
    Inspect {
        /// Path of the library.
        library: PathBuf,
    },
}

pub fn run(cmd: PluginCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        PluginCommand::Inspect { library } => {
            // Loads the library with every check and reports them (human2nav_plugin::inspect).
            let report = inspect_library(&library);
            print!("{}", report.render());
            match report.error {
                Some(e) => Err(e.into()),
                None => Ok(ExitCode::SUCCESS),
            }
        }
    }
}
