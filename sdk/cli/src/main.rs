//! The `human2nav` command-line tool: glue between the SDK crates, nothing more.

mod baseline;
mod bench;
mod compare;
mod data;
mod plan;
mod plugin;
mod replay;
mod robot;
mod scaling;
mod train;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Debug, Parser)]
#[command(
    name = "human2nav",
    version,
    about = "Crowd-navigation planning from human trajectories with feasibility-guided flow matching"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Inspect and validate robot profiles.
    #[command(subcommand)]
    Robot(robot::RobotCommand),
    /// Pedestrian data: tuple cache, statistics, benchmark episodes, association evaluation.
    #[command(subcommand)]
    Data(data::DataCommand),
    /// Inspect plugin libraries.
    #[command(subcommand)]
    Plugin(plugin::PluginCommand),
    /// Train the conditional flow-matching model (checkpoints, resume, model card, evaluation).
    Train(train::TrainArgs),
    /// Plan one step with Human2Nav and draw it (Fig. 4 style); `--bench` latency, `--eval`
    /// guided vs unguided on held-out windows.
    Plan(plan::PlanArgs),
    /// Run the closed-loop benchmark and write results.csv, report.md and the figures.
    Bench(bench::BenchArgs),
    /// Train the learned baselines (SARL).
    #[command(subcommand)]
    Baseline(baseline::BaselineCommand),
    /// SR against the amount of training data (Fig. 5): retrain on fractions of the training
    /// scenes and run Human2Nav closed loop with each model.
    Scaling(scaling::ScalingArgs),
    /// Compare a method of one benchmark run with a method of another, paired run by run
    /// (exact McNemar test per suite and robot).
    Compare(compare::CompareArgs),
    /// Plan on a ROS 2 bag (MCAP): odometry, goal, tracked people and a map in; a bag with the
    /// plans (nav_msgs/Path) and commands (geometry_msgs/Twist) and a Foxglove scene out.
    Replay(replay::ReplayArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Robot(cmd) => robot::run(cmd),
        Command::Data(cmd) => data::run(cmd),
        Command::Plugin(cmd) => plugin::run(cmd),
        Command::Train(args) => train::run(args),
        Command::Plan(args) => plan::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Baseline(cmd) => baseline::run(cmd),
        Command::Scaling(args) => scaling::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Replay(args) => replay::run(args),
    };
    match result {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}
