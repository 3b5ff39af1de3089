//! `human2nav plugin ...`

use clap::Subcommand;
use human2nav_plugin::{ABI_VERSION, PluginLibrary};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Subcommand)]
pub enum PluginCommand {
    /// Load a plugin library and print its name, version, ABI version and what it provides.
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
            let lib = PluginLibrary::load(&library)?;
            println!("library   {}", lib.path().display());
            println!("plugin    {} {}", lib.name(), lib.version());
            println!(
                "ABI       version {} (this host: {ABI_VERSION})",
                lib.abi_version()
            );
            let factories = lib.factories();
            let plural = if factories.len() == 1 {
                "factory"
            } else {
                "factories"
            };
            println!("provides  {} {plural}", factories.len());
            let width = factories.iter().map(|f| f.name.len()).max().unwrap_or(0);
            for f in factories {
                println!(
                    "  {:<11} {:<width$}  {}",
                    f.kind.to_string(),
                    f.name,
                    f.description
                );
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
