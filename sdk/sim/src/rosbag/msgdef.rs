//! ROS 2 message definitions as a bag carries them (MCAP schema encoding `ros2msg`): the
//! top-level type's fields, then each type it uses after a line of `=` and a `MSG: pkg/Type`
//! line.

use std::collections::BTreeMap;

/// A field's type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FieldType {
    /// A built-in: `bool`, `byte`, `char`, `int8` … `uint64`, `float32`, `float64`,
    /// `string` or `wstring` (a bound such as `string<=10` dropped).
    Builtin(String),
    /// Another message, `pkg/Type` (without `/msg/`).
    Message(String),
}

/// How many values a field holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arity {
    /// One.
    One,
    /// A fixed number (`T[N]`: no count in the data).
    Fixed(usize),
    /// A sequence (`T[]` or `T[<=N]`: a `uint32` count first).
    Sequence,
}

/// One field of a message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Field {
    /// Its name.
    pub name: String,
    /// Its element type.
    pub ty: FieldType,
    /// How many values.
    pub arity: Arity,
}

/// The definitions of a message type and of every type it uses, by `pkg/Type`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Definitions {
    /// The top-level type, `pkg/Type`.
    pub root: String,
    /// Every type's fields.
    pub types: BTreeMap<String, Vec<Field>>,
}

const BUILTINS: [&str; 15] = [
    "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64",
    "uint64", "float32", "float64", "string", "wstring",
];

/// `pkg/msg/Type` → `pkg/Type`.
pub fn normalize(name: &str) -> String {
    name.replace("/msg/", "/")
}

/// The package of `pkg/Type`.
fn package(name: &str) -> &str {
    name.split('/').next().unwrap_or("")
}

/// A field type as written (`float64`, `Point`, `geometry_msgs/Point`, `Header`) in a
/// definition of package `pkg`.
fn field_type(t: &str, pkg: &str) -> FieldType {
    let base = t.split("<=").next().unwrap_or(t);
    if BUILTINS.contains(&base) {
        FieldType::Builtin(base.to_string())
    } else if base == "Header" {
        FieldType::Message("std_msgs/Header".into())
    } else if base.contains('/') {
        FieldType::Message(normalize(base))
    } else {
        FieldType::Message(format!("{pkg}/{base}"))
    }
}

/// Parses `text`, the definitions of `root` (`pkg/msg/Type` or `pkg/Type`). Comments,
/// constants and default values are skipped; the error names the line.
pub fn parse(root: &str, text: &str) -> Result<Definitions, String> {
    let root = normalize(root);
    let mut types: BTreeMap<String, Vec<Field>> = BTreeMap::new();
    let mut current = root.clone();
    let mut fields = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        if line.chars().all(|c| c == '=') {
            types.insert(std::mem::take(&mut current), std::mem::take(&mut fields));
            continue;
        }
        if let Some(name) = line.strip_prefix("MSG:") {
            current = normalize(name.trim());
            continue;
        }
        let mut words = line.split_whitespace();
        let (Some(t), Some(name)) = (words.next(), words.next()) else {
            return Err(format!("line {}: `{line}` is not `type name`", i + 1));
        };
        if name.contains('=') || words.next().is_some_and(|w| w.starts_with('=')) {
            continue; // a constant
        }
        let (base, arity) = match t.find('[') {
            None => (t, Arity::One),
            Some(k) => {
                let inside = t[k + 1..].trim_end_matches(']');
                let arity = if inside.is_empty() || inside.starts_with("<=") {
                    Arity::Sequence
                } else {
                    Arity::Fixed(inside.parse().map_err(|_| {
                        format!(
                            "line {}: `{t}` has an array size that is not a number",
                            i + 1
                        )
                    })?)
                };
                (&t[..k], arity)
            }
        };
        fields.push(Field {
            name: name.to_string(),
            ty: field_type(base, package(&current)),
            arity,
        });
    }
    types.insert(current, fields);
    types.remove("");
    // Built-in message types a definition may use without spelling them out.
    types
        .entry("builtin_interfaces/Time".into())
        .or_insert_with(time_fields);
    types
        .entry("builtin_interfaces/Duration".into())
        .or_insert_with(time_fields);
    let defs = Definitions { root, types };
    for (name, fields) in &defs.types {
        for f in fields {
            if let FieldType::Message(m) = &f.ty
                && !defs.types.contains_key(m)
            {
                return Err(format!(
                    "`{name}.{}` is of type `{m}`, which the definition does not include",
                    f.name
                ));
            }
        }
    }
    if !defs.types.contains_key(&defs.root) {
        return Err(format!("no fields of `{}`", defs.root));
    }
    Ok(defs)
}

fn time_fields() -> Vec<Field> {
    vec![
        Field {
            name: "sec".into(),
            ty: FieldType::Builtin("int32".into()),
            arity: Arity::One,
        },
        Field {
            name: "nanosec".into(),
            ty: FieldType::Builtin("uint32".into()),
            arity: Arity::One,
        },
    ]
}

impl Definitions {
    /// The type at `path` (`pose.pose.position.x`) from the root, with its arity; `None` when a
    /// part of the path is not a field.
    pub fn field(&self, path: &str) -> Option<(&FieldType, Arity)> {
        let mut ty = &self.root;
        let mut found = None;
        for part in path.split('.') {
            let fields = self.types.get(ty)?;
            let f = fields.iter().find(|f| f.name == part)?;
            found = Some((&f.ty, f.arity));
            if let FieldType::Message(m) = &f.ty {
                ty = m;
            }
        }
        found
    }

    /// Checks that each `(path, builtin)` of `want` is a single field of that built-in type
    /// (`"[]"` after the type: a sequence; a message type instead of a built-in: that type);
    /// the error names the first that is not and what the definition has there.
    pub fn require(&self, want: &[(&str, &str)]) -> Result<(), String> {
        for (path, expected) in want {
            let (ty, arity) = match self.field(path) {
                Some(found) => found,
                None => {
                    return Err(format!(
                        "the definition of `{}` has no field `{path}` (expected {expected})",
                        self.root
                    ));
                }
            };
            let name = match ty {
                FieldType::Builtin(b) => b.clone(),
                FieldType::Message(m) => m.clone(),
            };
            let got = match arity {
                Arity::One => name,
                Arity::Fixed(n) => format!("{name}[{n}]"),
                Arity::Sequence => format!("{name}[]"),
            };
            if got != *expected {
                return Err(format!(
                    "`{}.{path}` is `{got}` in the bag's definition, expected `{expected}`",
                    self.root
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ODOM_LIKE: &str = "# comment\nstd_msgs/Header header\nstring child_frame_id\n\
        geometry_msgs/PoseWithCovariance pose\nint32 KIND=3\n\
        ================================================================================\n\
        MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n\
        ================================================================================\n\
        MSG: geometry_msgs/PoseWithCovariance\nPose pose\nfloat64[36] covariance\n\
        ================================================================================\n\
        MSG: geometry_msgs/Pose\nPoint position\nfloat64[] extra\nstring<=8 tag\n\
        ================================================================================\n\
        MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z 0.0\n";

    #[test]
    fn definitions_parse_with_arrays_bounds_defaults_and_constants() {
        let d = parse("nav_msgs/msg/Odometry", ODOM_LIKE).unwrap();
        assert_eq!(d.root, "nav_msgs/Odometry");
        assert_eq!(
            d.types["nav_msgs/Odometry"].len(),
            3,
            "the constant is skipped"
        );
        assert!(
            d.require(&[
                ("header.stamp.sec", "int32"),
                ("header.frame_id", "string"),
                ("pose.covariance", "float64[36]"),
                ("pose.pose.extra", "float64[]"),
                ("pose.pose.tag", "string"),
                ("pose.pose.position.z", "float64"),
                ("pose.pose.position", "geometry_msgs/Point"),
            ])
            .is_ok()
        );
        let e = d
            .require(&[("pose.pose.position.w", "float64")])
            .unwrap_err();
        assert!(e.contains("no field `pose.pose.position.w`"), "{e}");
        let e = d
            .require(&[("pose.pose.position.x", "float32")])
            .unwrap_err();
        assert!(
            e.contains("is `float64` in the bag's definition, expected `float32`"),
            "{e}"
        );
    }

    #[test]
    fn a_definition_missing_a_type_it_uses_is_refused() {
        let e = parse("a/B", "c/D d\n").unwrap_err();
        assert!(e.contains("`a/B.d` is of type `c/D`"), "{e}");
        let e = parse("a/B", "float64[x] d\n").unwrap_err();
        assert!(e.contains("line 1"), "{e}");
    }
}
