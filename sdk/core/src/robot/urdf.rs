//! What the robot profile reads from a URDF: the footprint radius of the base link's collision
//! geometry, wheel radii and joint velocity limits, steering limits and axle positions.
//!
//! Joint frames are composed at zero joint positions from the base link down, so wheel and
//! steering joints may sit anywhere below the base link (behind fixed joints, for instance).

use super::ProfileError;
use super::footprint::FootprintShape;
use crate::input::MAX_URDF_BYTES;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use urdf_rs::{Geometry, JointType};

/// A cylinder (or capsule) whose axis is within this angle of vertical counts as upright.
const UPRIGHT_COS: f64 = 1.0 - 1e-9;

/// Deepest element nesting a URDF may have. A URDF needs five levels
/// (`robot/link/collision/geometry/box`) and vendor extensions (`<gazebo>` plugins, say) a few
/// more; the XML parser recurses once per level, so a file nested tens of thousands deep would
/// overflow the stack. Checked on the text before it is parsed.
pub const MAX_URDF_DEPTH: usize = 64;

/// The 1-based line of the first element of `xml` nested deeper than `max`, if any.
///
/// A lexical scan that follows the parser's view of the nesting: start tags open a level, end
/// tags close one, empty-element tags (`<a/>`) do neither, and comments, CDATA sections,
/// processing instructions and declarations (`<!DOCTYPE ...>`, with an internal subset) are
/// skipped; quoted attribute values may hold `>`. Malformed text is left to the parser.
fn element_too_deep(xml: &str, max: usize) -> Option<usize> {
    let b = xml.as_bytes();
    let skip_past = |from: usize, end: &str| {
        xml[from..]
            .find(end)
            .map_or(b.len(), |k| from + k + end.len())
    };
    let mut depth = 0usize;
    let mut i = 0;
    while i < b.len() {
        if b[i] != b'<' {
            i += 1;
            continue;
        }
        let rest = &b[i..];
        if rest.starts_with(b"<!--") {
            i = skip_past(i + 4, "-->");
        } else if rest.starts_with(b"<![CDATA[") {
            i = skip_past(i + 9, "]]>");
        } else if rest.starts_with(b"<?") {
            i = skip_past(i + 2, "?>");
        } else if rest.starts_with(b"<!") {
            // A declaration; `[...]` (a DOCTYPE's internal subset) may hold `>`.
            let mut brackets = 0usize;
            let mut j = i + 2;
            while j < b.len() && !(b[j] == b'>' && brackets == 0) {
                match b[j] {
                    b'[' => brackets += 1,
                    b']' => brackets = brackets.saturating_sub(1),
                    _ => {}
                }
                j += 1;
            }
            i = j + 1;
        } else {
            let mut quote: Option<u8> = None;
            let mut j = i + 1;
            while j < b.len() {
                match (quote, b[j]) {
                    (Some(q), c) if c == q => quote = None,
                    (None, c @ (b'"' | b'\'')) => quote = Some(c),
                    (None, b'>') => break,
                    _ => {}
                }
                j += 1;
            }
            if rest.starts_with(b"</") {
                depth = depth.saturating_sub(1);
            } else if !(j < b.len() && b[j - 1] == b'/') {
                depth += 1;
                if depth > max {
                    return Some(xml[..i].matches('\n').count() + 1);
                }
            }
            i = j + 1;
        }
    }
    None
}

/// Checks that the links and joints of `robot` form a tree, as the URDF specification requires
/// (the profile walks from a wheel up to the base link; a loop or a second parent would make
/// the answer depend on the order of the file): every link and joint named once, every joint
/// between two links of the file, no link the child of two joints, no cycle. Returns each
/// child link's joint.
fn check_tree(robot: &urdf_rs::Robot, path: &Path) -> Result<HashMap<String, usize>, ProfileError> {
    let fail = |element: String, message: String| ProfileError::UrdfContent {
        urdf: path.to_path_buf(),
        element,
        message,
    };
    let mut links: HashMap<&str, usize> = HashMap::with_capacity(robot.links.len());
    for (i, l) in robot.links.iter().enumerate() {
        if let Some(first) = links.insert(l.name.as_str(), i) {
            return Err(fail(
                format!("link `{}`", l.name),
                format!("defined twice (links {first} and {i} of the file)"),
            ));
        }
    }
    let mut joints: HashMap<&str, usize> = HashMap::with_capacity(robot.joints.len());
    let mut parent_joint: HashMap<String, usize> = HashMap::with_capacity(robot.joints.len());
    for (i, j) in robot.joints.iter().enumerate() {
        let element = format!("joint `{}`", j.name);
        if let Some(first) = joints.insert(j.name.as_str(), i) {
            return Err(fail(
                element,
                format!("defined twice (joints {first} and {i} of the file)"),
            ));
        }
        for (end, link) in [("parent", &j.parent.link), ("child", &j.child.link)] {
            if !links.contains_key(link.as_str()) {
                return Err(fail(
                    element,
                    format!("its {end} link `{link}` is not defined"),
                ));
            }
        }
        if let Some(other) = parent_joint.insert(j.child.link.clone(), i) {
            return Err(fail(
                element,
                format!(
                    "link `{}` is already the child of joint `{}`; a link has one parent",
                    j.child.link, robot.joints[other].name
                ),
            ));
        }
    }
    // Each link has at most one parent: following parents from any link either reaches a
    // root or comes back to a link already on the walk (a cycle). Links known to reach a root
    // are not walked again, so this is linear in the links.
    let mut reaches_root: HashSet<&str> = HashSet::new();
    for l in &robot.links {
        let mut walk: Vec<&str> = Vec::new();
        let mut on_walk: HashSet<&str> = HashSet::new();
        let mut current = l.name.as_str();
        while !reaches_root.contains(current) {
            if !on_walk.insert(current) {
                let start = walk.iter().position(|w| *w == current).unwrap_or(0);
                let cycle = &walk[start..];
                let shown = cycle.len().min(8);
                return Err(fail(
                    format!("link `{current}`"),
                    format!(
                        "the joints form a cycle of {} links: {}{} → {current}",
                        cycle.len(),
                        cycle[..shown].join(" → "),
                        if shown < cycle.len() { " → …" } else { "" }
                    ),
                ));
            }
            walk.push(current);
            match parent_joint.get(current) {
                Some(&j) => current = robot.joints[j].parent.link.as_str(),
                None => break,
            }
        }
        reaches_root.extend(walk);
    }
    Ok(parent_joint)
}

/// A parsed URDF with its links indexed for the questions the profile asks.
#[derive(Debug)]
pub(crate) struct UrdfModel {
    pub(crate) path: PathBuf,
    pub(crate) robot: urdf_rs::Robot,
    /// Child link name → index of the joint that has it as child.
    parent_joint: HashMap<String, usize>,
}

/// One wheel joint as measured in the URDF.
#[derive(Clone, Debug, PartialEq)]
pub struct WheelJoint {
    /// Joint name.
    pub name: String,
    /// Wheel radius from the child link's cylinder or sphere (m).
    pub radius: f64,
    /// The joint's `<limit velocity>` (rad/s), when the URDF gives a positive finite one.
    pub velocity_limit: Option<f64>,
    /// Wheel centre in the base-link frame (m).
    pub position: [f64; 3],
}

/// One steering joint as measured in the URDF.
#[derive(Clone, Debug, PartialEq)]
pub struct SteeringJoint {
    /// Joint name.
    pub name: String,
    /// Largest steering angle reachable to both sides, `min(|lower|, |upper|)` (rad).
    pub max_angle: f64,
    /// Joint origin in the base-link frame (m).
    pub position: [f64; 3],
}

fn pose_to_isometry(p: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = p.xyz.0;
    let [roll, pitch, yaw] = p.rpy.0;
    // URDF rpy is fixed-axis roll, pitch, yaw: R = Rz(yaw)·Ry(pitch)·Rx(roll).
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

/// A URDF that could not be read or parsed, in one line whatever the XML parser reports.
fn load_error(path: &Path, toml: &Path, message: &str) -> ProfileError {
    ProfileError::UrdfLoad {
        file: toml.to_path_buf(),
        urdf: path.to_path_buf(),
        message: message.split_whitespace().collect::<Vec<_>>().join(" "),
    }
}

impl UrdfModel {
    /// Reads and parses `path` (a regular file of at most [`MAX_URDF_BYTES`], elements nested at
    /// most [`MAX_URDF_DEPTH`] deep); `toml` is the profile that names it (for the error).
    pub(crate) fn load(path: &Path, toml: &Path) -> Result<Self, ProfileError> {
        let text = crate::input::read_user_file(path, "URDF", MAX_URDF_BYTES)
            .map_err(|e| load_error(path, toml, &e.to_string()))?;
        Self::parse(&text, path, toml)
    }

    /// Parses URDF `text` held in memory (at most [`MAX_URDF_BYTES`], elements nested at most
    /// [`MAX_URDF_DEPTH`] deep); `path` names it and `toml` the profile in errors.
    pub(crate) fn parse(text: &str, path: &Path, toml: &Path) -> Result<Self, ProfileError> {
        let fail = |message: String| load_error(path, toml, &message);
        if text.len() as u64 > MAX_URDF_BYTES {
            return Err(fail(format!(
                "{} bytes is more than the limit of {MAX_URDF_BYTES} for a URDF",
                text.len()
            )));
        }
        if let Some(line) = element_too_deep(text, MAX_URDF_DEPTH) {
            return Err(fail(format!(
                "line {line}: elements nested more than {MAX_URDF_DEPTH} deep (the limit of a URDF)"
            )));
        }
        let robot = urdf_rs::read_from_string(text).map_err(|e| fail(e.to_string()))?;
        if robot.links.is_empty() {
            return Err(fail("the URDF has no <link>".into()));
        }
        let parent_joint = check_tree(&robot, path)?;
        Ok(Self {
            path: path.to_path_buf(),
            robot,
            parent_joint,
        })
    }

    fn content_error(
        &self,
        element: impl Into<String>,
        message: impl Into<String>,
    ) -> ProfileError {
        ProfileError::UrdfContent {
            urdf: self.path.clone(),
            element: element.into(),
            message: message.into(),
        }
    }

    fn link(&self, name: &str) -> Option<&urdf_rs::Link> {
        self.robot.links.iter().find(|l| l.name == name)
    }

    pub(crate) fn has_link(&self, name: &str) -> bool {
        self.link(name).is_some()
    }

    /// The single link that is no joint's child.
    pub(crate) fn root_link(&self) -> Result<String, ProfileError> {
        let roots: Vec<&str> = self
            .robot
            .links
            .iter()
            .filter(|l| !self.parent_joint.contains_key(&l.name))
            .map(|l| l.name.as_str())
            .collect();
        match roots.as_slice() {
            [one] => Ok((*one).to_string()),
            _ => Err(self.content_error(
                "robot",
                format!(
                    "cannot tell the root link ({} candidates: {}); set base_link in robot.toml",
                    roots.len(),
                    roots.join(", ")
                ),
            )),
        }
    }

    /// The transform base ← `link` at zero joint positions.
    fn link_in_base(&self, base: &str, link: &str) -> Result<Isometry3<f64>, ProfileError> {
        let mut transform = Isometry3::identity();
        let mut current = link.to_string();
        for _ in 0..=self.robot.joints.len() {
            if current == base {
                return Ok(transform);
            }
            let Some(&j) = self.parent_joint.get(&current) else {
                break;
            };
            let joint = &self.robot.joints[j];
            transform = pose_to_isometry(&joint.origin) * transform;
            current = joint.parent.link.clone();
        }
        Err(self.content_error(
            format!("link `{link}`"),
            format!("is not below the base link `{base}`"),
        ))
    }

    fn joint(&self, name: &str) -> Option<&urdf_rs::Joint> {
        self.robot.joints.iter().find(|j| j.name == name)
    }

    /// The joint origin in the base-link frame.
    fn joint_in_base(&self, base: &str, joint: &urdf_rs::Joint) -> Result<[f64; 3], ProfileError> {
        let t = self.link_in_base(base, &joint.parent.link)? * pose_to_isometry(&joint.origin);
        let p = t.translation.vector;
        Ok([p.x, p.y, p.z])
    }

    /// Radius of the disc, centred on the base link's origin, that covers the xy-projection of
    /// every `<collision>` of `base` (see [`super::RobotProfile`] for the rules).
    /// Also returns a short account of the geometry that set the radius.
    pub(crate) fn footprint_radius(&self, base: &str) -> Result<(f64, String), ProfileError> {
        let link = self
            .link(base)
            .ok_or_else(|| self.content_error(format!("link `{base}`"), "not found"))?;
        if link.collision.is_empty() {
            return Err(self.content_error(
                format!("link `{base}`"),
                "has no <collision> geometry; add one or set [footprint] radius in robot.toml",
            ));
        }
        let mut radius: f64 = 0.0;
        let mut account = String::new();
        for (i, c) in link.collision.iter().enumerate() {
            let element = format!("link `{base}` collision[{i}]");
            let iso = pose_to_isometry(&c.origin);
            let offset = iso.translation.vector.xy().norm();
            let axis = iso.rotation * Vector3::z();
            let upright = axis.z.abs() >= UPRIGHT_COS;
            let r = match &c.geometry {
                Geometry::Box { size } => {
                    let [a, b, h] = size.0.map(|s| 0.5 * s);
                    let mut r: f64 = 0.0;
                    for sx in [-a, a] {
                        for sy in [-b, b] {
                            for sz in [-h, h] {
                                let p = iso * Point3::new(sx, sy, sz);
                                r = r.max(p.x.hypot(p.y));
                            }
                        }
                    }
                    r
                }
                Geometry::Cylinder { radius, length } => {
                    if upright {
                        radius + offset
                    } else {
                        radius.hypot(0.5 * length) + offset
                    }
                }
                Geometry::Capsule { radius, length } => {
                    if upright {
                        radius + offset
                    } else {
                        radius + 0.5 * length + offset
                    }
                }
                Geometry::Sphere { radius } => radius + offset,
                Geometry::Mesh { filename, .. } => {
                    return Err(self.content_error(
                        element,
                        format!(
                            "mesh `{filename}` has no analytic extent; set [footprint] radius in \
                             robot.toml"
                        ),
                    ));
                }
            };
            if !(r.is_finite() && r > 0.0) {
                return Err(
                    self.content_error(element, format!("degenerate geometry (radius {r})"))
                );
            }
            if r > radius {
                radius = r;
                let n = |v: f64| format!("{}", (v * 1e4).round() / 1e4);
                let shape = match &c.geometry {
                    Geometry::Box { size } => format!("box {}×{} m", n(size.0[0]), n(size.0[1])),
                    Geometry::Cylinder { radius, .. } => format!("cylinder r {} m", n(*radius)),
                    Geometry::Capsule { radius, .. } => format!("capsule r {} m", n(*radius)),
                    Geometry::Sphere { radius } => format!("sphere r {} m", n(*radius)),
                    Geometry::Mesh { .. } => "mesh".to_string(),
                };
                account = format!("{element}: {shape}, xy offset {} m", n(offset));
            }
        }
        Ok((radius, account))
    }

    /// The xy projection of every `<collision>` of `base`, one shape each (see
    /// [`super::footprint`]): an upright box is a rectangle, an upright cylinder or capsule and a
    /// sphere a disc, and any tilted element the disc about its centre that covers its
    /// projection. Call after [`Self::footprint_radius`], which reports bad geometry.
    pub(crate) fn footprint_shapes(&self, base: &str) -> Result<Vec<FootprintShape>, ProfileError> {
        let link = self
            .link(base)
            .ok_or_else(|| self.content_error(format!("link `{base}`"), "not found"))?;
        let mut shapes = Vec::with_capacity(link.collision.len());
        for (i, c) in link.collision.iter().enumerate() {
            let iso = pose_to_isometry(&c.origin);
            let center = [iso.translation.vector.x, iso.translation.vector.y];
            let upright = (iso.rotation * Vector3::z()).z.abs() >= UPRIGHT_COS;
            let disc = |radius: f64| FootprintShape::Disc { center, radius };
            shapes.push(match &c.geometry {
                Geometry::Box { size } => {
                    let [a, b, h] = size.0.map(|s| 0.5 * s);
                    if upright {
                        let x_axis = iso.rotation * Vector3::x();
                        FootprintShape::Rect {
                            center,
                            half: [a, b],
                            yaw: x_axis.y.atan2(x_axis.x),
                        }
                    } else {
                        let mut r: f64 = 0.0;
                        for sx in [-a, a] {
                            for sy in [-b, b] {
                                for sz in [-h, h] {
                                    let p = iso * Point3::new(sx, sy, sz);
                                    r = r.max((p.x - center[0]).hypot(p.y - center[1]));
                                }
                            }
                        }
                        disc(r)
                    }
                }
                Geometry::Cylinder { radius, length } if !upright => {
                    disc(radius.hypot(0.5 * length))
                }
                Geometry::Capsule { radius, length } if !upright => disc(radius + 0.5 * length),
                Geometry::Cylinder { radius, .. }
                | Geometry::Capsule { radius, .. }
                | Geometry::Sphere { radius } => disc(*radius),
                Geometry::Mesh { filename, .. } => {
                    return Err(self.content_error(
                        format!("link `{base}` collision[{i}]"),
                        format!("mesh `{filename}` has no analytic extent"),
                    ));
                }
            });
        }
        Ok(shapes)
    }

    /// Measures a wheel joint: continuous or revolute, with a cylinder or sphere on its child.
    pub(crate) fn wheel_joint(&self, base: &str, name: &str) -> Result<WheelJoint, ProfileError> {
        let element = format!("joint `{name}`");
        let joint = self
            .joint(name)
            .ok_or_else(|| self.content_error(&element, "not found"))?;
        if !matches!(
            joint.joint_type,
            JointType::Continuous | JointType::Revolute
        ) {
            return Err(self.content_error(
                &element,
                format!(
                    "is {:?}, a wheel joint must be continuous or revolute",
                    joint.joint_type
                ),
            ));
        }
        let child = &joint.child.link;
        let link = self
            .link(child)
            .ok_or_else(|| self.content_error(format!("link `{child}`"), "not found"))?;
        let radius = link
            .collision
            .iter()
            .map(|c| &c.geometry)
            .chain(link.visual.iter().map(|v| &v.geometry))
            .find_map(|g| match g {
                Geometry::Cylinder { radius, .. } | Geometry::Sphere { radius } => Some(*radius),
                _ => None,
            })
            .filter(|r| r.is_finite() && *r > 0.0)
            .ok_or_else(|| {
                self.content_error(
                    format!("link `{child}`"),
                    "a wheel link needs a <cylinder> or <sphere> collision (or visual) geometry \
                     with a positive radius",
                )
            })?;
        let (lo, hi) = super::resolve::LENGTH_RANGE;
        if !(lo..=hi).contains(&radius) {
            return Err(self.content_error(
                format!("link `{child}`"),
                format!("wheel radius {radius:e} m is not in [{lo:e}, {hi:e}] m"),
            ));
        }
        // 0 is what a missing `velocity` attribute reads as: no limit. Anything else must be
        // a positive finite speed, never silently dropped.
        let v = joint.limit.velocity;
        if !(v.is_finite() && v >= 0.0) {
            return Err(self.content_error(
                &element,
                format!("<limit velocity=\"{v}\"> must be a finite speed >= 0 rad/s (0: none)"),
            ));
        }
        let velocity_limit = (v > 0.0).then_some(v);
        Ok(WheelJoint {
            name: name.to_string(),
            radius,
            velocity_limit,
            position: self.joint_in_base(base, joint)?,
        })
    }

    /// Measures a steering joint: revolute with limits on both sides.
    pub(crate) fn steering_joint(
        &self,
        base: &str,
        name: &str,
    ) -> Result<SteeringJoint, ProfileError> {
        let element = format!("joint `{name}`");
        let joint = self
            .joint(name)
            .ok_or_else(|| self.content_error(&element, "not found"))?;
        if joint.joint_type != JointType::Revolute {
            return Err(self.content_error(
                &element,
                format!(
                    "is {:?}, a steering joint must be revolute",
                    joint.joint_type
                ),
            ));
        }
        let max_angle = joint.limit.lower.abs().min(joint.limit.upper.abs());
        if !(max_angle.is_finite() && max_angle > 0.0 && max_angle < std::f64::consts::FRAC_PI_2) {
            return Err(self.content_error(
                &element,
                format!(
                    "<limit lower=\"{}\" upper=\"{}\"> must allow steering to both sides by less \
                     than π/2",
                    joint.limit.lower, joint.limit.upper
                ),
            ));
        }
        Ok(SteeringJoint {
            name: name.to_string(),
            max_angle,
            position: self.joint_in_base(base, joint)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::element_too_deep;

    #[test]
    fn nesting_depth_follows_elements_only() {
        let nested = |n: usize| format!("{}{}", "<a>".repeat(n), "</a>".repeat(n));
        assert_eq!(element_too_deep(&nested(3), 3), None);
        assert_eq!(element_too_deep(&nested(4), 3), Some(1));
        // Empty elements, comments, CDATA, processing instructions, a DOCTYPE with an internal
        // subset and `>` inside attribute values open no level.
        let flat = "<?xml version=\"1.0\"?>\n<!DOCTYPE r [<!ENTITY e \"<a><a>\">]>\n\
                    <r><!-- <a><a><a> --><![CDATA[<a><a><a>]]><b x=\"<a>\" y='>'/><b/></r>";
        assert_eq!(element_too_deep(flat, 1), None);
        // The line of the first element too deep.
        assert_eq!(
            element_too_deep("<r>\n<a>\n<b>\n<c/></b></a></r>", 2),
            Some(3)
        );
    }
}
