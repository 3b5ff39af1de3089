//! Step 2 of resolving a profile: the `[embodiment]` section (a built-in kind or a plugin) and
//! the `[[constraint]]` plugin terms, their libraries resolved against the profile's directory.

use super::*;

/// The `[embodiment]` section: a built-in kind or a plugin; `steering_joints` are refused with
/// anything but `ackermann`.
pub(in crate::robot) fn embodiment(
    e: &RawEmbodiment,
    ck: &Checker<'_>,
    dir: &Path,
) -> Result<EmbodimentSpec, ProfileError> {
    let embodiment = if e.kind == "plugin" {
        plugin_embodiment(e, ck, dir)?
    } else {
        builtin_embodiment(e, ck)?
    };
    if !e.steering_joints.is_empty() && builtin_kind(&embodiment) != Some(EmbodimentKind::Ackermann)
    {
        return Err(ck.invalid(
            "embodiment.steering_joints",
            format!("only used with kind = \"ackermann\", not \"{}\"", e.kind),
        ));
    }
    Ok(embodiment)
}

/// `kind = "plugin"`: `library` and `plugin` are required and non-empty, the library is
/// resolved against `dir`, `config` defaults to empty.
fn plugin_embodiment(
    e: &RawEmbodiment,
    ck: &Checker<'_>,
    dir: &Path,
) -> Result<EmbodimentSpec, ProfileError> {
    let library = e
        .library
        .as_deref()
        .ok_or_else(|| ck.invalid("embodiment.library", "required with kind = \"plugin\""))?;
    ck.non_empty("embodiment.library", library)?;
    let plugin = e
        .plugin
        .as_deref()
        .ok_or_else(|| ck.invalid("embodiment.plugin", "required with kind = \"plugin\""))?;
    ck.non_empty("embodiment.plugin", plugin)?;
    if let Some(ms) = e.deadline_ms {
        plugin_deadline(ck, "embodiment.deadline_ms", ms)?;
    }
    Ok(EmbodimentSpec::Plugin(PluginRef {
        library: resolve_path(dir, library),
        plugin: plugin.to_string(),
        config: e.config.clone().unwrap_or_default(),
        weight: 1.0,
        deadline_ms: e.deadline_ms,
        isolation: e.isolation,
        declared_in: ck.file.to_path_buf(),
    }))
}

/// A plugin's `deadline_ms`: in `[0, MAX_PLUGIN_DEADLINE_MS]` (0: none).
fn plugin_deadline(ck: &Checker<'_>, field: &str, ms: f64) -> Result<(), ProfileError> {
    let ms = ck.non_negative(field, ms)?;
    if ms > MAX_PLUGIN_DEADLINE_MS {
        return Err(ck.invalid(
            field,
            format!("at most {MAX_PLUGIN_DEADLINE_MS} ms (0: no deadline), got {ms}"),
        ));
    }
    Ok(())
}

/// A built-in `kind`, which allows none of the plugin fields (`library`, `plugin`, `config`).
fn builtin_embodiment(e: &RawEmbodiment, ck: &Checker<'_>) -> Result<EmbodimentSpec, ProfileError> {
    let kind = EmbodimentKind::from_name(&e.kind).ok_or_else(|| {
        ck.invalid(
            "embodiment.kind",
            format!(
                "unknown embodiment `{}`; expected one of differential_drive, ackermann, \
                 omnidirectional, plugin",
                e.kind
            ),
        )
    })?;
    for (field, present) in [
        ("embodiment.library", e.library.is_some()),
        ("embodiment.plugin", e.plugin.is_some()),
        ("embodiment.config", e.config.is_some()),
        ("embodiment.deadline_ms", e.deadline_ms.is_some()),
        ("embodiment.isolation", e.isolation.is_some()),
    ] {
        if present {
            return Err(ck.invalid(field, "only allowed with kind = \"plugin\""));
        }
    }
    Ok(EmbodimentSpec::Builtin(kind))
}

/// The built-in kind of an embodiment, `None` for a plugin.
pub(in crate::robot) fn builtin_kind(embodiment: &EmbodimentSpec) -> Option<EmbodimentKind> {
    match embodiment {
        EmbodimentSpec::Builtin(k) => Some(*k),
        EmbodimentSpec::Plugin(_) => None,
    }
}

/// The `[[constraint]]` plugin terms in declaration order: `library` and `plugin` non-empty,
/// `weight >= 0`, `deadline_ms` in `[0, MAX_PLUGIN_DEADLINE_MS]`, the library resolved
/// against `dir`.
pub(in crate::robot) fn constraints(
    raw: &[RawConstraint],
    ck: &Checker<'_>,
    dir: &Path,
) -> Result<Vec<PluginRef>, ProfileError> {
    let mut constraints = Vec::with_capacity(raw.len());
    for (i, c) in raw.iter().enumerate() {
        ck.non_empty(&format!("constraint[{i}].library"), &c.library)?;
        ck.non_empty(&format!("constraint[{i}].plugin"), &c.plugin)?;
        let weight = ck
            .within(
                &format!("constraint[{i}].weight"),
                c.weight,
                WEIGHT_RANGE,
                true,
            )
            .map_err(|e| match e {
                // Which term it is about: the plugin's name in the message.
                ProfileError::Invalid {
                    file,
                    field,
                    message,
                } => ProfileError::Invalid {
                    file,
                    field,
                    message: format!("{message} (plugin `{}`)", c.plugin),
                },
                other => other,
            })?;
        if let Some(ms) = c.deadline_ms {
            plugin_deadline(ck, &format!("constraint[{i}].deadline_ms"), ms)?;
        }
        constraints.push(PluginRef {
            library: resolve_path(dir, &c.library),
            plugin: c.plugin.clone(),
            config: c.config.clone(),
            weight,
            deadline_ms: c.deadline_ms,
            isolation: c.isolation,
            declared_in: ck.file.to_path_buf(),
        });
    }
    Ok(constraints)
}
