//! Step 3 of resolving a profile: what it takes from its URDF (the base link, the footprint,
//! the wheel and steering joints).

use super::*;

/// What the profile takes from its URDF (lengths in m, positions in the base-link frame).
pub(in crate::robot) struct UrdfFacts {
    /// The URDF, resolved against the profile's directory.
    pub(in crate::robot) path: PathBuf,
    /// `base_link` as written, or the URDF's root link.
    pub(in crate::robot) base_link: String,
    /// Radius of the disc about the base-link origin covering the footprint (m).
    pub(in crate::robot) footprint_radius: f64,
    /// Where `footprint_radius` came from.
    pub(in crate::robot) footprint_source: Provenance,
    /// The footprint's xy shapes (the override disc when `[footprint] radius` is given).
    pub(in crate::robot) footprint_shapes: Vec<FootprintShape>,
    /// The measured `embodiment.wheel_joints`, in the order listed.
    pub(in crate::robot) wheel_joints: Vec<WheelJoint>,
    /// The measured `embodiment.steering_joints`, in the order listed.
    pub(in crate::robot) steering_joints: Vec<SteeringJoint>,
    /// Spread of the wheel centres along the base link's y axis (m), with two or more wheels
    /// that are not all on one line along x.
    pub(in crate::robot) track_width: Option<f64>,
}

/// Loads the URDF named by `raw.urdf` (or parses `text`, its contents given in memory), picks
/// the base link and measures the footprint, then the wheel joints and the steering joints
/// (each checked to exist, in the order listed).
pub(in crate::robot) fn urdf(
    raw: &RawProfile,
    ck: &Checker<'_>,
    dir: &Path,
    footprint_override: Option<f64>,
    text: Option<&str>,
) -> Result<UrdfFacts, ProfileError> {
    let path = resolve_path(dir, &raw.urdf);
    let model = match text {
        Some(text) => UrdfModel::parse(text, &path, ck.file)?,
        None => UrdfModel::load(&path, ck.file)?,
    };
    let urdf_name = raw.urdf.as_str();
    let base_link = match &raw.base_link {
        Some(b) => {
            if !model.has_link(b) {
                return Err(ck.invalid("base_link", format!("no link `{b}` in {urdf_name}")));
            }
            b.clone()
        }
        None => model.root_link()?,
    };
    let (footprint_radius, footprint_source, footprint_shapes) =
        footprint(&model, &base_link, footprint_override)?;

    let e = &raw.embodiment;
    distinct_joints(e, ck)?;
    let mut wheel_joints: Vec<WheelJoint> = Vec::with_capacity(e.wheel_joints.len());
    for (i, name) in e.wheel_joints.iter().enumerate() {
        if !model.robot.joints.iter().any(|j| &j.name == name) {
            return Err(ck.invalid(
                format!("embodiment.wheel_joints[{i}]"),
                format!("no joint `{name}` in {urdf_name}"),
            ));
        }
        let wheel = model.wheel_joint(&base_link, name)?;
        // Two wheels in one place: a copied joint, whose track or wheelbase would be 0.
        if let Some(k) = wheel_joints.iter().position(|w| {
            let d = (0..3).map(|a| w.position[a] - wheel.position[a]);
            d.map(|x| x * x).sum::<f64>().sqrt() < SAME_PLACE
        }) {
            return Err(ck.invalid(
                format!("embodiment.wheel_joints[{i}]"),
                format!(
                    "joint `{name}` sits where wheel_joints[{k}] (`{}`) does, at {:?} m in the \
                     base-link frame of {urdf_name}",
                    wheel_joints[k].name, wheel.position
                ),
            ));
        }
        wheel_joints.push(wheel);
    }
    let mut steering_joints = Vec::with_capacity(e.steering_joints.len());
    for (i, name) in e.steering_joints.iter().enumerate() {
        if !model.robot.joints.iter().any(|j| &j.name == name) {
            return Err(ck.invalid(
                format!("embodiment.steering_joints[{i}]"),
                format!("no joint `{name}` in {urdf_name}"),
            ));
        }
        steering_joints.push(model.steering_joint(&base_link, name)?);
    }
    let track_width = if wheel_joints.len() >= 2 {
        let ys = wheel_joints.iter().map(|w| w.position[1]);
        let lo = ys.clone().fold(f64::INFINITY, f64::min);
        let hi = ys.fold(f64::NEG_INFINITY, f64::max);
        (hi - lo > 0.0).then_some(hi - lo)
    } else {
        None
    };
    Ok(UrdfFacts {
        path,
        base_link,
        footprint_radius,
        footprint_source,
        footprint_shapes,
        wheel_joints,
        steering_joints,
        track_width,
    })
}

/// Closer than this (m), two wheel joints are in one place.
const SAME_PLACE: f64 = 1e-6;

/// Each joint listed once in `wheel_joints` and `steering_joints` together: a joint listed
/// twice would count its wheel twice in the track, the wheelbase and the caps.
fn distinct_joints(e: &RawEmbodiment, ck: &Checker<'_>) -> Result<(), ProfileError> {
    let listed: Vec<(String, &String)> = e
        .wheel_joints
        .iter()
        .enumerate()
        .map(|(i, n)| (format!("embodiment.wheel_joints[{i}]"), n))
        .chain(
            e.steering_joints
                .iter()
                .enumerate()
                .map(|(i, n)| (format!("embodiment.steering_joints[{i}]"), n)),
        )
        .collect();
    for (k, (field, name)) in listed.iter().enumerate() {
        if let Some((first, _)) = listed[..k].iter().find(|(_, n)| n == name) {
            return Err(ck.invalid(
                field,
                format!("joint `{name}` is already {first}; list each joint once"),
            ));
        }
    }
    Ok(())
}

/// The footprint radius (m) with its provenance, and the footprint shapes: measured from the
/// base link's collision geometry, or the override disc about the origin when `[footprint]
/// radius` is given (the URDF's value, if it has one, is then only quoted in the provenance).
fn footprint(
    model: &UrdfModel,
    base_link: &str,
    footprint_override: Option<f64>,
) -> Result<(f64, Provenance, Vec<FootprintShape>), ProfileError> {
    let (radius, source) = match footprint_override {
        Some(r) => {
            let urdf_says = match model.footprint_radius(base_link) {
                Ok((u, _)) => format!("URDF base collision would give {} m", num(u)),
                Err(_) => "URDF base collision has no analytic extent".to_string(),
            };
            (
                r,
                Provenance::profile(format!(
                    "robot.toml [footprint] radius (overrides; {urdf_says})"
                )),
            )
        }
        None => {
            let (r, account) = model.footprint_radius(base_link)?;
            (r, Provenance::urdf(format!("URDF {account}")))
        }
    };
    let shapes = match footprint_override {
        Some(radius) => vec![FootprintShape::Disc {
            center: [0.0, 0.0],
            radius,
        }],
        None => model.footprint_shapes(base_link)?,
    };
    Ok((radius, source, shapes))
}
