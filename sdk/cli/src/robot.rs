//! `human2nav robot ...`

use clap::Subcommand;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Subcommand)]
pub enum RobotCommand {
    /// Parse a robot profile (robot.toml + URDF) and print what was understood.
    Check {
        /// Path(s) to robot.toml files.
        #[arg(required = true)]
        profiles: Vec<PathBuf>,
    },
}

pub fn run(cmd: RobotCommand) -> anyhow::Result<ExitCode> {
    match cmd {
        RobotCommand::Check { profiles } => {
            let _ = profiles;
            anyhow::bail!("robot check: not wired yet")
        }
    }
}
