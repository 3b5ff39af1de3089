//! `human2nav robot ...`

use clap::Subcommand;
use human2nav_core::robot::{EmbodimentSpec, Origin, PluginRef, RobotProfile};
use human2nav_plugin::{PluginHost, RobotResolution};
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
        RobotCommand::Check { profiles } => Ok(check(&profiles)),
    }
}

/// Loads every profile and resolves its plugins (library, factory, instance with its config,
/// one call; `PluginHost::resolve_robot`); prints each valid one, and one `error: ...` line on
/// stderr for each broken one. Fails when any profile is broken.
fn check(paths: &[PathBuf]) -> ExitCode {
    let mut failed = 0;
    let host = PluginHost::new();
    for (i, path) in paths.iter().enumerate() {
        let resolved = RobotProfile::load(path)
            .map_err(|e| e.to_string())
            .and_then(|mut p| {
                let r = host.resolve_robot(&p).map_err(|e| e.to_string())?;
                host.robot_embodiment(&mut p).map_err(|e| e.to_string())?;
                Ok((p, r))
            });
        match resolved {
            Ok((profile, resolution)) => {
                if i > 0 {
                    println!();
                }
                print!("{}", describe(&profile, &resolution));
            }
            Err(err) => {
                eprintln!("error: {err}");
                failed += 1;
            }
        }
    }
    if failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

fn origin(o: Origin) -> &'static str {
    match o {
        Origin::Profile => "robot.toml",
        Origin::Urdf => "URDF",
        Origin::Default => "defaults",
    }
}

fn plugin_line(r: &PluginRef) -> String {
    let config = if r.config.trim().is_empty() {
        "no config".to_string()
    } else {
        format!("config {} lines", r.config.lines().count())
    };
    format!(
        "`{}` from {} (weight {}, {config}, declared in {})",
        r.plugin,
        r.library.display(),
        r.weight,
        r.declared_in.display()
    )
}

/// The human-readable report of one profile and what resolving its plugins did.
fn describe(p: &RobotProfile, resolution: &RobotResolution) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "robot       {}", p.name);
    let _ = writeln!(s, "file        {}", p.source.display());
    if !p.description.is_empty() {
        let _ = writeln!(s, "description {}", p.description);
    }
    let _ = writeln!(
        s,
        "urdf        {} (base link `{}`)",
        p.urdf.display(),
        p.base_link
    );
    match &p.embodiment {
        EmbodimentSpec::Builtin(kind) => {
            let _ = writeln!(s, "embodiment  {kind} (built-in)");
        }
        EmbodimentSpec::Plugin(r) => {
            let _ = writeln!(s, "embodiment  plugin {}", plugin_line(r));
        }
    }
    for w in &p.wheel_joints {
        let vel = w
            .velocity_limit
            .map_or("no velocity limit".to_string(), |v| format!("{v} rad/s"));
        let _ = writeln!(
            s,
            "  wheel     {}: radius {} m, {vel}, at ({:.3}, {:.3}) m",
            w.name, w.radius, w.position[0], w.position[1]
        );
    }
    for st in &p.steering_joints {
        let _ = writeln!(
            s,
            "  steering  {}: ±{:.4} rad ({:.1}°), at ({:.3}, {:.3}) m",
            st.name,
            st.max_angle,
            st.max_angle.to_degrees(),
            st.position[0],
            st.position[1]
        );
    }
    if let Some(t) = p.track_width {
        let _ = writeln!(s, "  track     {t:.3} m");
    }
    if let Some(l) = p.wheelbase {
        let _ = writeln!(s, "  wheelbase {l:.3} m");
    }
    let _ = writeln!(
        s,
        "footprint   radius {:.4} m  [{}]",
        p.footprint_radius, p.footprint_source
    );
    for shape in &p.footprint_shapes {
        let _ = writeln!(s, "  collides  {shape}");
    }
    let _ = writeln!(s, "limits");
    for e in p.limit_table() {
        let value = e.value.map_or("none".to_string(), |v| format!("{v:.4}"));
        let _ = writeln!(
            s,
            "  {:<18} {:>8} {:<6} [{}]",
            e.name, value, e.unit, e.source
        );
    }
    if let Some(c) = &p.limits.coupled {
        let _ = writeln!(
            s,
            "  {:<18} {:.4}·|v_x| + {:.4}·|v_y| + {:.4}·|omega| <= {:.4} m/s  [declared by the embodiment]",
            "coupled", c.v, c.lateral, c.omega, c.max
        );
    }
    if p.min_turning_radius > 0.0 {
        let _ = writeln!(
            s,
            "  {:<18} {:>8.4} {:<6} [1 / kappa_max]",
            "min_turning_radius", p.min_turning_radius, "m"
        );
    }
    let c = &p.controller;
    let _ = writeln!(
        s,
        "controller  k_x {} 1/s, k_y {} 1/m², k_theta {} 1/s, k_d {}, lookahead {} s  [{}]",
        c.k_x,
        c.k_y,
        c.k_theta,
        c.k_d,
        c.lookahead,
        origin(p.controller_source)
    );
    let g = &p.guidance;
    let _ = writeln!(
        s,
        "cost        lambda_v {}, lambda_a {}, lambda_omega {}, lambda_kappa {}, lambda_lateral {}, \
         lambda_reverse {}, lambda_coupled {}, gamma {}, delta {}  [{}]",
        g.lambda_v,
        g.lambda_a,
        g.lambda_omega,
        g.lambda_kappa,
        g.lambda_lateral,
        g.lambda_reverse,
        g.lambda_coupled,
        g.gamma,
        g.delta,
        origin(p.guidance_source)
    );
    if p.constraints.is_empty() {
        let _ = writeln!(s, "constraints none (built-in Eq. 8-9 terms only)");
    } else {
        for (i, r) in p.constraints.iter().enumerate() {
            let _ = writeln!(s, "constraint  [{i}] {}", plugin_line(r));
        }
    }
    for line in resolution.embodiment.iter().chain(&resolution.constraints) {
        let _ = writeln!(s, "resolved    {line}");
    }
    let _ = writeln!(s, "ok");
    s
}
