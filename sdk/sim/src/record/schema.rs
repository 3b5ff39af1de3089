//! The JSON Schemas of the messages a recording writes, one per Foxglove schema name.

use serde_json::{Map, Value, json};

// JSON Schemas of the messages written, by schema name.

fn s_num() -> Value {
    json!({"type": "number"})
}
fn s_int() -> Value {
    json!({"type": "integer"})
}
fn s_str() -> Value {
    json!({"type": "string"})
}
fn s_obj(title: &str, props: Vec<(&str, Value)>) -> Value {
    let props: Map<String, Value> = props.into_iter().map(|(k, v)| (k.to_string(), v)).collect();
    json!({"title": title, "type": "object", "properties": props})
}
fn s_arr(items: Value) -> Value {
    json!({"type": "array", "items": items})
}
fn s_time() -> Value {
    s_obj("time", vec![("sec", s_int()), ("nsec", s_int())])
}
fn s_vec3() -> Value {
    s_obj(
        "foxglove.Vector3",
        vec![("x", s_num()), ("y", s_num()), ("z", s_num())],
    )
}
fn s_quat() -> Value {
    s_obj(
        "foxglove.Quaternion",
        vec![
            ("x", s_num()),
            ("y", s_num()),
            ("z", s_num()),
            ("w", s_num()),
        ],
    )
}
fn s_pose() -> Value {
    s_obj(
        "foxglove.Pose",
        vec![("position", s_vec3()), ("orientation", s_quat())],
    )
}
fn s_color() -> Value {
    s_obj(
        "foxglove.Color",
        vec![
            ("r", s_num()),
            ("g", s_num()),
            ("b", s_num()),
            ("a", s_num()),
        ],
    )
}

/// The JSON Schema of the messages of `name` (one of [`TOPICS`](super::TOPICS)' schema
/// names), describing the fields the recorder ([`super`]) writes.
pub(super) fn schema_of(name: &str) -> Value {
    let mut schema = match name {
        "foxglove.FrameTransform" => s_obj(
            name,
            vec![
                ("timestamp", s_time()),
                ("parent_frame_id", s_str()),
                ("child_frame_id", s_str()),
                ("translation", s_vec3()),
                ("rotation", s_quat()),
            ],
        ),
        "foxglove.PoseInFrame" => s_obj(
            name,
            vec![
                ("timestamp", s_time()),
                ("frame_id", s_str()),
                ("pose", s_pose()),
            ],
        ),
        "foxglove.PosesInFrame" => s_obj(
            name,
            vec![
                ("timestamp", s_time()),
                ("frame_id", s_str()),
                ("poses", s_arr(s_pose())),
            ],
        ),
        "foxglove.Log" => s_obj(
            name,
            vec![
                ("timestamp", s_time()),
                ("level", s_int()),
                ("message", s_str()),
                ("name", s_str()),
                ("file", s_str()),
                ("line", s_int()),
            ],
        ),
        _ => scene_update_schema(),
    };
    if let Value::Object(map) = &mut schema {
        map.insert(
            "$schema".into(),
            Value::from("https://json-schema.org/draft/2020-12/schema"),
        );
    }
    schema
}

fn scene_update_schema() -> Value {
    let shape = |title: &str, extra: Vec<(&str, Value)>| {
        let mut props = vec![("pose", s_pose()), ("size", s_vec3()), ("color", s_color())];
        props.extend(extra);
        s_obj(title, props)
    };
    let any = || s_arr(json!({"type": "object"}));
    let entity = s_obj(
        "foxglove.SceneEntity",
        vec![
            ("timestamp", s_time()),
            ("frame_id", s_str()),
            ("id", s_str()),
            (
                "lifetime",
                s_obj("duration", vec![("sec", s_int()), ("nsec", s_int())]),
            ),
            ("frame_locked", json!({"type": "boolean"})),
            (
                "metadata",
                s_arr(s_obj(
                    "foxglove.KeyValuePair",
                    vec![("key", s_str()), ("value", s_str())],
                )),
            ),
            ("arrows", any()),
            ("cubes", s_arr(shape("foxglove.CubePrimitive", vec![]))),
            ("spheres", any()),
            (
                "cylinders",
                s_arr(shape(
                    "foxglove.CylinderPrimitive",
                    vec![("bottom_scale", s_num()), ("top_scale", s_num())],
                )),
            ),
            (
                "lines",
                s_arr(s_obj(
                    "foxglove.LinePrimitive",
                    vec![
                        ("type", s_int()),
                        ("pose", s_pose()),
                        ("thickness", s_num()),
                        ("scale_invariant", json!({"type": "boolean"})),
                        ("points", s_arr(s_vec3())),
                        ("color", s_color()),
                        ("colors", s_arr(s_color())),
                        ("indices", s_arr(s_int())),
                    ],
                )),
            ),
            ("triangles", any()),
            ("texts", any()),
            ("models", any()),
        ],
    );
    s_obj(
        "foxglove.SceneUpdate",
        vec![
            (
                "deletions",
                s_arr(s_obj(
                    "foxglove.SceneEntityDeletion",
                    vec![("timestamp", s_time()), ("type", s_int()), ("id", s_str())],
                )),
            ),
            ("entities", s_arr(entity)),
        ],
    )
}
