//! The incremental 2-D linear programs of RVO2 (`linearProgram1/2/3`), solved exactly.
//!
//! A [`Line`] is a directed line; the permitted half-plane is on its **left**: a velocity `v`
//! satisfies the line when `det(direction, point − v) ≤ 0`. The programs find the velocity
//! closest to an optimisation velocity (or furthest along a direction) inside all half-planes
//! and inside the disc of radius `max_speed`, by Seidel-style incremental insertion:
//! expected linear time, exact up to floating point.
//!
//! When the half-planes have no common point inside the disc, [`linear_program3`] returns the
//! velocity that minimises the maximum violation (the "least penetrating" velocity of ORCA),
//! solved as a 3-D program projected onto the plane, again as in RVO2.

use std::ops::{Add, Mul, Neg, Sub};

/// Two lines are treated as parallel when `|det(d₁, d₂)| ≤ EPSILON` (RVO2's `RVO_EPSILON`).
pub const EPSILON: f64 = 1e-5;

/// A plane vector (a velocity or a position), world frame, SI units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Vec2 {
    pub x: f64,
    pub y: f64,
}

impl Vec2 {
    pub const ZERO: Vec2 = Vec2 { x: 0.0, y: 0.0 };

    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }

    /// Dot product.
    pub fn dot(self, o: Vec2) -> f64 {
        self.x * o.x + self.y * o.y
    }

    /// The 2-D cross product `self.x·o.y − self.y·o.x` (RVO2's `det`).
    pub fn det(self, o: Vec2) -> f64 {
        self.x * o.y - self.y * o.x
    }

    /// Squared length.
    pub fn norm_sq(self) -> f64 {
        self.dot(self)
    }

    /// Length.
    pub fn norm(self) -> f64 {
        self.norm_sq().sqrt()
    }

    /// The unit vector along `self` (`self` itself when its length is zero).
    pub fn normalized(self) -> Vec2 {
        let n = self.norm();
        if n > 0.0 { self * (1.0 / n) } else { self }
    }

    pub fn to_array(self) -> [f64; 2] {
        [self.x, self.y]
    }

    pub fn from_array(a: [f64; 2]) -> Self {
        Self::new(a[0], a[1])
    }
}

impl Add for Vec2 {
    type Output = Vec2;
    fn add(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x + o.x, self.y + o.y)
    }
}

impl Sub for Vec2 {
    type Output = Vec2;
    fn sub(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x - o.x, self.y - o.y)
    }
}

impl Neg for Vec2 {
    type Output = Vec2;
    fn neg(self) -> Vec2 {
        Vec2::new(-self.x, -self.y)
    }
}

impl Mul<f64> for Vec2 {
    type Output = Vec2;
    fn mul(self, s: f64) -> Vec2 {
        Vec2::new(self.x * s, self.y * s)
    }
}

/// A directed line `point + t·direction` (`direction` of unit length); the permitted
/// half-plane lies to its left.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Line {
    pub point: Vec2,
    pub direction: Vec2,
}

impl Line {
    /// How far `v` lies on the forbidden (right) side of the line: `det(direction, point − v)`.
    /// Positive means violated, zero on the line, negative satisfied.
    pub fn violation(&self, v: Vec2) -> f64 {
        self.direction.det(self.point - v)
    }
}

/// Optimises on line `line_no` subject to lines `0..line_no` and the disc of radius `radius`.
///
/// With `direction_opt` the result is the extreme point furthest along `opt` (a unit vector);
/// otherwise it is the point of the line closest to `opt`. Returns `None` when the line has no
/// feasible point (RVO2 `linearProgram1` returning `false`).
#[inline]
pub fn linear_program1(
    lines: &[Line],
    line_no: usize,
    radius: f64,
    opt: Vec2,
    direction_opt: bool,
) -> Option<Vec2> {
    let line = lines[line_no];
    let dot = line.point.dot(line.direction);
    let discriminant = dot * dot + radius * radius - line.point.norm_sq();
    // A NaN (a line computed from overflowing inputs) counts as infeasible too, rather than
    // reaching `clamp` below with NaN bounds, which panics.
    if discriminant.is_nan() || discriminant < 0.0 {
        // The speed disc lies entirely on the forbidden side of this line.
        return None;
    }
    let sqrt_disc = discriminant.sqrt();
    let mut t_left = -dot - sqrt_disc;
    let mut t_right = -dot + sqrt_disc;

    for other in &lines[..line_no] {
        let denominator = line.direction.det(other.direction);
        let numerator = other.direction.det(line.point - other.point);
        if denominator.abs() <= EPSILON {
            // (Almost) parallel: either `other` forbids the whole line or none of it.
            if numerator < 0.0 {
                return None;
            }
            continue;
        }
        let t = numerator / denominator;
        if denominator >= 0.0 {
            // `other` bounds this line on the right.
            t_right = t_right.min(t);
        } else {
            // `other` bounds this line on the left.
            t_left = t_left.max(t);
        }
        if t_left.is_nan() || t_right.is_nan() || t_left > t_right {
            return None;
        }
    }

    let t = if direction_opt {
        if opt.dot(line.direction) > 0.0 {
            t_right
        } else {
            t_left
        }
    } else {
        line.direction.dot(opt - line.point).clamp(t_left, t_right)
    };
    Some(line.point + line.direction * t)
}

/// The velocity inside the disc of radius `radius` and all half-planes that is closest to `opt`
/// (or, with `direction_opt`, furthest along the unit vector `opt`).
///
/// Returns the result and the index of the first line that could not be satisfied
/// (`lines.len()` on success); on failure the result is the optimum of the lines before it,
/// as in RVO2 `linearProgram2`.
pub fn linear_program2(
    lines: &[Line],
    radius: f64,
    opt: Vec2,
    direction_opt: bool,
) -> (Vec2, usize) {
    let mut result = if direction_opt {
        opt * radius
    } else if opt.norm_sq() > radius * radius {
        opt.normalized() * radius
    } else {
        opt
    };
    for i in 0..lines.len() {
        if lines[i].violation(result) > 0.0 {
            match linear_program1(lines, i, radius, opt, direction_opt) {
                Some(r) => result = r,
                None => return (result, i),
            }
        }
    }
    (result, lines.len())
}

/// Completes an infeasible program: starting from `result` (the output of
/// [`linear_program2`] that failed at `begin_line`), finds the velocity inside the disc that
/// minimises the largest violation of lines `num_fixed..` while keeping lines `..num_fixed`
/// (obstacle lines in RVO2; `0` here) hard, as in RVO2 `linearProgram3`.
pub fn linear_program3(
    lines: &[Line],
    num_fixed: usize,
    begin_line: usize,
    radius: f64,
    result: Vec2,
) -> Vec2 {
    linear_program3_in(
        lines,
        num_fixed,
        begin_line,
        radius,
        result,
        &mut Vec::new(),
    )
}

/// [`linear_program3`] with a caller-owned buffer for the projected lines, so that repeated
/// calls do not allocate. The result is the same.
pub fn linear_program3_in(
    lines: &[Line],
    num_fixed: usize,
    begin_line: usize,
    radius: f64,
    mut result: Vec2,
    proj: &mut Vec<Line>,
) -> Vec2 {
    let mut distance = 0.0;
    for i in begin_line..lines.len() {
        if lines[i].violation(result) > distance {
            // Project the lines before `i` onto line `i`'s family of parallel shifts: each
            // projected line holds the points equidistant (in violation) from lines `i` and `j`.
            proj.clear();
            proj.extend_from_slice(&lines[..num_fixed]);
            for j in num_fixed..i {
                let determinant = lines[i].direction.det(lines[j].direction);
                let point = if determinant.abs() <= EPSILON {
                    if lines[i].direction.dot(lines[j].direction) > 0.0 {
                        // Same direction: line `j` never binds more than line `i`.
                        continue;
                    }
                    (lines[i].point + lines[j].point) * 0.5
                } else {
                    lines[i].point
                        + lines[i].direction
                            * (lines[j].direction.det(lines[i].point - lines[j].point)
                                / determinant)
                };
                proj.push(Line {
                    point,
                    direction: (lines[j].direction - lines[i].direction).normalized(),
                });
            }
            let previous = result;
            let inward = Vec2::new(-lines[i].direction.y, lines[i].direction.x);
            let (r, fail) = linear_program2(proj, radius, inward, true);
            // Failure can only come from rounding (the previous result is feasible for the
            // projected program); keep the previous result then, like RVO2.
            result = if fail < proj.len() { previous } else { r };
            distance = lines[i].violation(result);
        }
    }
    result
}

/// Solves the full program: closest velocity to `opt` inside the disc and all half-planes, or,
/// when they are jointly infeasible, the velocity of least maximal violation.
pub fn solve(lines: &[Line], max_speed: f64, opt: Vec2) -> Vec2 {
    solve_in(lines, max_speed, opt, &mut Vec::new())
}

/// [`solve`] when the first `num_fixed` lines are obstacles' (RVO2's `numObstLines`): if no
/// velocity satisfies every line, the closest one that still satisfies those is chosen.
pub fn solve_fixed(lines: &[Line], num_fixed: usize, max_speed: f64, opt: Vec2) -> Vec2 {
    let (result, fail) = linear_program2(lines, max_speed, opt, false);
    if fail < lines.len() {
        linear_program3_in(lines, num_fixed, fail, max_speed, result, &mut Vec::new())
    } else {
        result
    }
}

/// [`solve`] with a caller-owned scratch buffer (see [`linear_program3_in`]); the result is
/// the same.
pub fn solve_in(lines: &[Line], max_speed: f64, opt: Vec2, scratch: &mut Vec<Line>) -> Vec2 {
    let (result, fail) = linear_program2(lines, max_speed, opt, false);
    if fail < lines.len() {
        linear_program3_in(lines, 0, fail, max_speed, result, scratch)
    } else {
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    fn line(px: f64, py: f64, dx: f64, dy: f64) -> Line {
        Line {
            point: Vec2::new(px, py),
            direction: Vec2::new(dx, dy).normalized(),
        }
    }

    /// Found by the `plugin_observation` fuzz target: a finite observation far out (1e300 m)
    /// made a line whose discriminant was NaN, and `clamp` panicked on NaN bounds inside the
    /// plugin. Such a line is infeasible now, whatever the solver does with it next.
    #[test]
    fn lines_from_overflowing_inputs_are_infeasible_not_a_panic() {
        let far = Line {
            point: Vec2::new(1e300, 1e300),
            direction: Vec2::new(1.0, 0.0),
        };
        assert_eq!(linear_program1(&[far], 0, 1.0, Vec2::ZERO, false), None);
        let nan = Line {
            point: Vec2::new(0.0, 0.0),
            direction: Vec2::new(f64::NAN, 0.0),
        };
        let lines = [line(0.0, -0.5, 1.0, 0.0), nan];
        assert_eq!(linear_program1(&lines, 1, 1.0, Vec2::ZERO, false), None);
        let ok = [line(0.0, -0.5, 1.0, 0.0), line(0.5, 0.0, 0.0, 1.0)];
        let _ = solve(&[far, nan], 1.0, Vec2::new(0.3, 0.0));
        assert!(linear_program1(&ok, 1, 1.0, Vec2::ZERO, false).is_some());
    }

    #[test]
    fn unconstrained_returns_opt_or_its_projection_on_the_disc() {
        let v = solve(&[], 2.0, Vec2::new(1.0, 0.5));
        assert_relative_eq!(v.x, 1.0);
        assert_relative_eq!(v.y, 0.5);
        let w = solve(&[], 1.0, Vec2::new(3.0, 4.0));
        assert_relative_eq!(w.x, 0.6, epsilon = 1e-12);
        assert_relative_eq!(w.y, 0.8, epsilon = 1e-12);
    }

    #[test]
    fn single_violated_line_projects_opt() {
        // Direction (1, 0) has its left normal (0, 1): the permitted half-plane is y ≥ 0.5.
        let l = line(0.0, 0.5, 1.0, 0.0);
        let v = solve(&[l], 5.0, Vec2::new(1.0, 0.0));
        assert_relative_eq!(v.x, 1.0, epsilon = 1e-12);
        assert_relative_eq!(v.y, 0.5, epsilon = 1e-12);
    }

    #[test]
    fn two_lines_meet_at_corner() {
        // The left normal of d is (−d.y, d.x): direction (1, 0) through (0, 1) permits y ≥ 1,
        // direction (0, 1) through (−1, 0) permits x ≤ −1. Closest point to the origin: (−1, 1).
        let a = line(0.0, 1.0, 1.0, 0.0);
        let b = line(-1.0, 0.0, 0.0, 1.0);
        let v = solve(&[a, b], 10.0, Vec2::new(0.0, 0.0));
        assert_relative_eq!(v.x, -1.0, epsilon = 1e-12);
        assert_relative_eq!(v.y, 1.0, epsilon = 1e-12);
    }

    #[test]
    fn speed_disc_binds_on_the_line() {
        // y ≥ 0.6 with max speed 1 and opt far along +x: the result is the disc ∩ line point
        // (0.8, 0.6).
        let l = line(0.0, 0.6, 1.0, 0.0);
        let v = solve(&[l], 1.0, Vec2::new(10.0, 0.0));
        assert_relative_eq!(v.x, 0.8, epsilon = 1e-12);
        assert_relative_eq!(v.y, 0.6, epsilon = 1e-12);
    }

    #[test]
    fn infeasible_pair_minimises_the_largest_violation() {
        // y ≥ 1 and y ≤ −1 (direction (−1, 0) has its left at −y): no common point; the least
        // violating velocities are on y = 0, each line violated by 1.
        let a = line(0.0, 1.0, 1.0, 0.0);
        let b = line(0.0, -1.0, -1.0, 0.0);
        let v = solve(&[a, b], 5.0, Vec2::new(2.0, 3.0));
        assert_relative_eq!(v.y, 0.0, epsilon = 1e-9);
        assert_relative_eq!(a.violation(v), 1.0, epsilon = 1e-9);
        assert_relative_eq!(b.violation(v), 1.0, epsilon = 1e-9);
    }

    #[test]
    fn line_outside_the_disc_is_infeasible() {
        // y ≥ 3 with max speed 1: linear_program1 must report failure, program 3 gets as close
        // as the disc allows: (0, 1).
        let l = line(0.0, 3.0, 1.0, 0.0);
        assert!(linear_program1(&[l], 0, 1.0, Vec2::ZERO, false).is_none());
        let v = solve(&[l], 1.0, Vec2::new(1.0, 0.0));
        assert_relative_eq!(v.x, 0.0, epsilon = 1e-9);
        assert_relative_eq!(v.y, 1.0, epsilon = 1e-9);
    }
}
