//! The social force model of Helbing & Molnár (1995, "Social force model for pedestrian
//! dynamics", Phys. Rev. E 51, 4282) in its circular form: the one implementation of the
//! SDK, used by the simulator's reactive crowd (`human2nav_sim::crowd`, pushed by the robot)
//! and by the data crate's prediction study (`human2nav_data::prediction`, pushed by each
//! other).
//!
//! ```text
//! a  = (v_des − v) / τ  +  Σ w(φ) · (V0/σ) · exp(−d / σ) · n
//! v' = v + a·dt (capped at v_cap),   p' = p + v'·dt   (semi-implicit Euler)
//! ```
//!
//! * `d`: the gap between the walker's disc and what pushes it (floored at minus the walker's
//!   radius, so that an overlap cannot blow the force up); `n`: the unit direction from what
//!   pushes to the walker;
//! * `τ = 0.5 s`, `V0 = 2.1 m²/s²`, `σ = 0.3 m` (Helbing & Molnár 1995): the repulsion is
//!   7 m/s² at contact, 1.3 m/s² at 0.5 m, 0.25 m/s² at 1 m;
//! * `w(φ)`: their anisotropy: 1 when the pusher lies within the walker's 200° field of view
//!   around its walking direction, else `c = 0.5`;
//! * `v_cap = 1.3 · max(|v₀|, 0.5 m/s)`: their maximal speed `1.3·v0`, with a floor (ours) that
//!   lets someone standing still step aside.
//!
//! What the desired velocity is (a recording to return to, or the walker's last velocity) is
//! the caller's.

use serde::{Deserialize, Serialize};

/// Below this speed (m/s) a walker has no walking direction: whatever pushes it is in view.
const NO_HEADING: f64 = 1e-9;

/// Parameters of the social force model (module docs). Every field is optional in TOML.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SocialForce {
    /// Relaxation time τ of the driving term (s). Default 0.5 (Helbing & Molnár 1995).
    pub relaxation_time: f64,
    /// Repulsion strength `V0/σ` at contact (m/s²). Default 7.0 = 2.1 / 0.3 (ibid.).
    pub strength: f64,
    /// Repulsion range σ (m). Default 0.3 (ibid.).
    pub range: f64,
    /// Field of view around the walking direction (degrees). Default 200 (ibid.).
    pub field_of_view_deg: f64,
    /// Weight of a pusher outside the field of view. Default 0.5 (ibid.).
    pub rear_weight: f64,
    /// Maximal speed as a multiple of the walker's own speed. Default 1.3 (ibid.).
    pub max_speed_factor: f64,
    /// The speed used for the cap is at least this (m/s). Default 0.5.
    pub min_speed: f64,
    /// Time over which a walker pushed off a recording walks back onto it (s; the simulator's
    /// reactive crowd only). Default 1.0.
    pub return_time: f64,
}

impl Default for SocialForce {
    fn default() -> Self {
        Self {
            relaxation_time: 0.5,
            strength: 7.0,
            range: 0.3,
            field_of_view_deg: 200.0,
            rear_weight: 0.5,
            max_speed_factor: 1.3,
            min_speed: 0.5,
            return_time: 1.0,
        }
    }
}

impl SocialForce {
    /// Checks every parameter; the error names the field.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let positive = [
            ("relaxation_time", self.relaxation_time),
            ("strength", self.strength),
            ("range", self.range),
            ("return_time", self.return_time),
            ("min_speed", self.min_speed),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0 && v <= 1e6) {
                return Err((name, format!("must be finite, > 0 and ≤ 1e6, got {v}")));
            }
        }
        if !(self.field_of_view_deg.is_finite()
            && self.field_of_view_deg > 0.0
            && self.field_of_view_deg <= 360.0)
        {
            return Err((
                "field_of_view_deg",
                format!("must be in (0, 360], got {}", self.field_of_view_deg),
            ));
        }
        if !(self.rear_weight.is_finite() && (0.0..=1.0).contains(&self.rear_weight)) {
            return Err((
                "rear_weight",
                format!("must be in [0, 1], got {}", self.rear_weight),
            ));
        }
        if !(self.max_speed_factor.is_finite()
            && self.max_speed_factor >= 1.0
            && self.max_speed_factor <= 10.0)
        {
            return Err((
                "max_speed_factor",
                format!("must be in [1, 10], got {}", self.max_speed_factor),
            ));
        }
        Ok(())
    }

    /// The repulsion's magnitude (m/s²) on a walker of `radius` whose disc is `gap` m from
    /// what pushes it, before the anisotropy.
    pub fn magnitude(&self, gap: f64, radius: f64) -> f64 {
        self.strength * (-gap.max(-radius) / self.range).exp()
    }

    /// The anisotropy `w(φ)` for a walker heading along `heading` (a velocity; below
    /// 1e-9 m/s, no direction) pushed along the unit `n` (from the pusher to the walker).
    pub fn weight(&self, heading: [f64; 2], n: [f64; 2]) -> f64 {
        let speed = heading[0].hypot(heading[1]);
        if speed < NO_HEADING {
            return 1.0;
        }
        // The pusher lies in direction −n from the walker.
        let cos_phi = -(heading[0] * n[0] + heading[1] * n[1]) / speed;
        if cos_phi >= (0.5 * self.field_of_view_deg).to_radians().cos() {
            1.0
        } else {
            self.rear_weight
        }
    }

    /// The repulsion (m/s²) on a walker of `radius` heading along `heading`, `gap` m from what
    /// pushes it along the unit `n`.
    pub fn push(&self, gap: f64, radius: f64, heading: [f64; 2], n: [f64; 2]) -> [f64; 2] {
        let magnitude = self.weight(heading, n) * self.magnitude(gap, radius);
        [magnitude * n[0], magnitude * n[1]]
    }

    /// The speed cap `v_cap` (m/s) of a walker whose own speed is `speed`.
    pub fn speed_cap(&self, speed: f64) -> f64 {
        self.max_speed_factor * speed.max(self.min_speed)
    }

    /// One semi-implicit Euler step of `dt` s: the walker at `position` with `velocity`
    /// driven towards `desired` (capped at `cap` first) and pushed by `push` (m/s²); its new
    /// position and velocity.
    pub fn step(
        &self,
        position: [f64; 2],
        velocity: [f64; 2],
        desired: [f64; 2],
        push: [f64; 2],
        cap: f64,
        dt: f64,
    ) -> ([f64; 2], [f64; 2]) {
        let clamp = |v: [f64; 2]| {
            let s = v[0].hypot(v[1]);
            if s > cap {
                [v[0] * cap / s, v[1] * cap / s]
            } else {
                v
            }
        };
        let desired = clamp(desired);
        let a = [
            (desired[0] - velocity[0]) / self.relaxation_time + push[0],
            (desired[1] - velocity[1]) / self.relaxation_time + push[1],
        ];
        let v = clamp([velocity[0] + a[0] * dt, velocity[1] + a[1] * dt]);
        ([position[0] + v[0] * dt, position[1] + v[1] * dt], v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn the_repulsion_has_helbing_and_molnars_strengths() {
        let f = SocialForce::default();
        assert_relative_eq!(f.magnitude(0.0, 0.3), 7.0);
        assert_relative_eq!(f.magnitude(0.5, 0.3), 7.0 * (-0.5f64 / 0.3).exp());
        // An overlap deeper than the walker's radius pushes no harder than one of the radius.
        assert_eq!(f.magnitude(-5.0, 0.3), f.magnitude(-0.3, 0.3));
    }

    #[test]
    fn a_pusher_behind_the_walker_counts_half() {
        let f = SocialForce::default();
        // Walking along +x; a pusher ahead pushes back along −x (n = −x).
        assert_eq!(f.weight([1.0, 0.0], [-1.0, 0.0]), 1.0);
        // One behind pushes along +x: outside the 200° field of view.
        assert_eq!(f.weight([1.0, 0.0], [1.0, 0.0]), 0.5);
        // 95° off the heading is inside it, 105° outside.
        let at = |deg: f64| {
            let r = (180.0 + deg).to_radians();
            f.weight([1.0, 0.0], [r.cos(), r.sin()])
        };
        assert_eq!(at(95.0), 1.0);
        assert_eq!(at(105.0), 0.5);
        // Standing still: everything is in view.
        assert_eq!(f.weight([0.0, 0.0], [1.0, 0.0]), 1.0);
    }

    #[test]
    fn a_step_relaxes_towards_the_desired_velocity_under_the_cap() {
        let f = SocialForce::default();
        let (p, v) = f.step([0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 0.0], 1.3, 0.1);
        assert_relative_eq!(v[0], 0.2);
        assert_relative_eq!(p[0], 0.02);
        // A desired velocity over the cap is capped before it drives.
        let (_, v) = f.step([0.0, 0.0], [0.0, 0.0], [10.0, 0.0], [0.0, 0.0], 1.0, 0.1);
        assert_relative_eq!(v[0], 0.2);
        // A push that would exceed the cap is capped.
        let (_, v) = f.step([0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [0.0, 100.0], 1.3, 0.1);
        assert_relative_eq!(v[0].hypot(v[1]), 1.3);
        assert_eq!(f.speed_cap(0.1), 0.65);
        assert_relative_eq!(f.speed_cap(1.0), 1.3);
    }
}
