//! How far a robot that cannot turn tighter than a radius `r` is from a point: the length of
//! the shortest forward Dubins path from a pose to a point, with the final heading free, and
//! the time to the point when the robot may also back up ([`time_to_point`]).
//!
//! For a robot that turns in place (`r = 0`) this is the straight-line distance. For a car it is
//! longer wherever the point is not ahead: a point beside the car, inside one of its two turning
//! circles, needs a loop forward, or backing up and then driving forward: a two-point turn.
//!
//! The shortest forward path to a point is an arc followed by a straight line (`CS`) or by a
//! second arc of the other direction (`CC`) (Bui, Souères, Boissonnat and Laumond, 1994). Every
//! path of these four words (`LS`, `RS`, `RL`, `LR`) that reaches the point is constructed in
//! closed form and the shortest one is returned. [`time_to_point`] adds backward paths (the
//! same words mirrored) and one cusp: backing straight up, then forward, or the other way.

use crate::se2::Pose2;
use std::f64::consts::TAU;

/// The angle `a` in `[0, 2π)`.
fn wrap_tau(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w >= TAU { 0.0 } else { w }
}

/// The length of the shortest forward path from `pose` to `goal` for a turning radius
/// `radius` (m; `0` or less: the straight-line distance). Finite for finite inputs.
pub fn distance_to_point(pose: &Pose2, goal: [f64; 2], radius: f64) -> f64 {
    let (dx, dy) = (goal[0] - pose.x, goal[1] - pose.y);
    if radius <= 0.0 {
        return dx.hypot(dy);
    }
    let (s, c) = pose.theta.sin_cos();
    let x = c * dx + s * dy;
    let y = -s * dx + c * dy;
    shortest(x, y, radius).0
}

/// Number of cusp positions [`time_to_point`] tries on each side: backing up (or driving
/// ahead) straight for `2r·i/CUSP_STEPS`, `i = 1 … CUSP_STEPS`, before the last leg.
pub const CUSP_STEPS: usize = 8;

/// How long a robot with turning radius `radius` (m; `0` or less: it turns in place) needs to
/// reach `goal` from `pose` at a constant `forward` speed, or `reverse` speed when backing up
/// (m/s; `reverse` 0: it cannot). The fastest of: forward along the shortest forward path;
/// backward along the shortest backward one; backing straight up for a while, then forward;
/// driving straight ahead for a while, then backward ([`CUSP_STEPS`] cusp positions up to two
/// radii away). Speeds are reached at once: it ranks poses by how far the goal is for this
/// robot, not by when the robot gets there. Finite for finite inputs and positive `forward`.
pub fn time_to_point(pose: &Pose2, goal: [f64; 2], radius: f64, forward: f64, reverse: f64) -> f64 {
    let (dx, dy) = (goal[0] - pose.x, goal[1] - pose.y);
    if radius <= 0.0 {
        return dx.hypot(dy) / forward;
    }
    let (s, c) = pose.theta.sin_cos();
    let x = c * dx + s * dy;
    let y = -s * dx + c * dy;
    let ahead = |x: f64, y: f64| shortest(x, y, radius).0 / forward;
    let mut best = ahead(x, y);
    if reverse > 0.0 {
        // Backing up along a path is driving forward along its mirror image.
        let back = |x: f64, y: f64| shortest(-x, y, radius).0 / reverse;
        best = best.min(back(x, y));
        for i in 1..=CUSP_STEPS {
            let b = 2.0 * radius * i as f64 / CUSP_STEPS as f64;
            best = best
                .min(b / reverse + ahead(x + b, y))
                .min(b / forward + back(x - b, y));
        }
    }
    best
}

/// The path words of [`shortest`], for tests.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Word {
    /// Left arc of `a` rad, then `s` m straight.
    Ls { a: f64, s: f64 },
    /// Right arc of `a` rad, then `s` m straight.
    Rs { a: f64, s: f64 },
    /// Right arc of `a` rad, then left arc of `b` rad.
    Rl { a: f64, b: f64 },
    /// Left arc of `a` rad, then right arc of `b` rad.
    Lr { a: f64, b: f64 },
}

/// The shortest of the four words to the point `(x, y)` of the robot frame (heading along `x`),
/// and its length.
fn shortest(x: f64, y: f64, r: f64) -> (f64, Word) {
    let mut best = (f64::INFINITY, Word::Ls { a: 0.0, s: 0.0 });
    let mut offer = |len: f64, word: Word| {
        if len < best.0 {
            best = (len, word);
        }
    };
    // A right turn is a left turn in the mirrored frame.
    if let Some((a, s)) = left_straight(x, y, r) {
        offer(r * a + s, Word::Ls { a, s });
    }
    if let Some((a, s)) = left_straight(x, -y, r) {
        offer(r * a + s, Word::Rs { a, s });
    }
    if let Some((a, b)) = right_left(x, y, r) {
        offer(r * (a + b), Word::Rl { a, b });
    }
    if let Some((a, b)) = right_left(x, -y, r) {
        offer(r * (a + b), Word::Lr { a, b });
    }
    if best.0.is_finite() {
        best
    } else {
        // Unreachable for finite inputs (a point is outside at least one turning circle);
        // non-finite inputs end here.
        (x.hypot(y), best.1)
    }
}

/// `LS`: a left arc of `a` rad on the circle centred at `(0, r)`, then `s` m straight, when the
/// point is not inside that circle.
fn left_straight(x: f64, y: f64, r: f64) -> Option<(f64, f64)> {
    let (cx, cy) = (x, y - r);
    let d2 = cx * cx + cy * cy;
    // (Also `None` for a NaN.)
    if d2.partial_cmp(&(r * r)).is_none_or(|o| o.is_lt()) {
        return None;
    }
    let s = (d2 - r * r).sqrt();
    // The straight leaves the circle along its tangent: seen from the centre, the point lies at
    // the tangent point's angle (the heading minus π/2) turned by atan2(s, r).
    let a = wrap_tau(cy.atan2(cx) + r.atan2(s));
    Some((a, s))
}

/// `RL`: a right arc of `a` rad on the circle centred at `(0, −r)`, then a left arc of `b` rad on
/// a circle of radius `r` that touches it, when the point is at a distance between `r` and `3r`
/// from the right circle's centre.
fn right_left(x: f64, y: f64, r: f64) -> Option<(f64, f64)> {
    // After the right arc `a` the robot is at q = (r sin a, r cos a − r) heading −a, and the
    // left circle's centre is c = (2r sin a, 2r cos a − r). |p − c| = r gives
    // ρ cos(a − φ) = (ρ² + 3r²) / (4r ρ) with ρ, φ the point's polar form about (0, −r).
    let (px, py) = (x, y + r);
    let rho = px.hypot(py);
    if rho.is_nan() || rho <= 0.0 {
        return None;
    }
    let cos = (rho * rho + 3.0 * r * r) / (4.0 * r * rho);
    if cos.is_nan() || cos > 1.0 {
        return None;
    }
    let phi = px.atan2(py);
    let spread = cos.acos();
    let mut best: Option<(f64, f64)> = None;
    for a in [wrap_tau(phi - spread), wrap_tau(phi + spread)] {
        let (sa, ca) = a.sin_cos();
        let (cx, cy) = (2.0 * r * sa, 2.0 * r * ca - r);
        // On the left circle the robot starts at angle atan2(−cos a, −sin a) about its centre
        // and turns counter-clockwise to the point.
        let start = (-ca).atan2(-sa);
        let b = wrap_tau((y - cy).atan2(x - cx) - start);
        if best.is_none_or(|(a0, b0)| a + b < a0 + b0) {
            best = Some((a, b));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// Drives `word` from the origin (heading along x) in small steps and returns where it ends.
    fn drive(word: Word, r: f64) -> (f64, f64) {
        let mut p = Pose2::IDENTITY;
        let arc = |p: &mut Pose2, angle: f64, left: bool| {
            let n = 20_000;
            let step = angle / n as f64;
            for _ in 0..n {
                // Exact arc of `step` rad.
                let turn = if left { step } else { -step };
                let chord = 2.0 * r * (0.5 * step).sin();
                let mid = p.theta + 0.5 * turn;
                p.x += chord * mid.cos();
                p.y += chord * mid.sin();
                p.theta += turn;
            }
        };
        let straight = |p: &mut Pose2, s: f64| {
            p.x += s * p.theta.cos();
            p.y += s * p.theta.sin();
        };
        match word {
            Word::Ls { a, s } => {
                arc(&mut p, a, true);
                straight(&mut p, s);
            }
            Word::Rs { a, s } => {
                arc(&mut p, a, false);
                straight(&mut p, s);
            }
            Word::Rl { a, b } => {
                arc(&mut p, a, false);
                arc(&mut p, b, true);
            }
            Word::Lr { a, b } => {
                arc(&mut p, a, true);
                arc(&mut p, b, false);
            }
        }
        (p.x, p.y)
    }

    #[test]
    fn known_lengths() {
        let r = 1.6;
        let o = Pose2::IDENTITY;
        assert_eq!(distance_to_point(&o, [3.0, 4.0], 0.0), 5.0);
        assert!((distance_to_point(&o, [7.0, 0.0], r) - 7.0).abs() < 1e-12);
        // A quarter and a half turn of the left circle.
        assert!((distance_to_point(&o, [r, r], r) - 0.5 * PI * r).abs() < 1e-12);
        assert!((distance_to_point(&o, [0.0, 2.0 * r], r) - PI * r).abs() < 1e-12);
        assert!((distance_to_point(&o, [0.0, -2.0 * r], r) - PI * r).abs() < 1e-12);
        // Straight behind: half a turn and back past the start.
        let behind = distance_to_point(&o, [-5.0, 0.0], r);
        assert!(
            behind > PI * r && behind < PI * r + 5.0 + 2.0 * r,
            "{behind}"
        );
        // The pose's frame: a car facing the goal needs no turn.
        let facing = Pose2::new(1.0, 1.0, 0.25 * PI);
        assert!((distance_to_point(&facing, [3.0, 3.0], r) - 8f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn a_point_beside_the_car_needs_a_loop() {
        let r = 1.6;
        let o = Pose2::IDENTITY;
        // Inside the left turning circle, close by: shorter by air than any arc reaches.
        let beside = distance_to_point(&o, [0.3, 0.8], r);
        assert!(beside > PI * r, "{beside}");
        // The same point once the car has turned toward it is close.
        let turned = Pose2::new(0.0, 0.0, (0.8f64).atan2(0.3));
        assert!((distance_to_point(&turned, [0.3, 0.8], r) - 0.3f64.hypot(0.8)).abs() < 1e-12);
    }

    #[test]
    fn every_word_reaches_its_point_and_none_beats_the_straight_line() {
        let r = 1.3;
        let mut worst = 0.0f64;
        for i in -12..=12 {
            for j in -12..=12 {
                let (x, y) = (0.37 * i as f64, 0.41 * j as f64);
                let (len, word) = shortest(x, y, r);
                let (ex, ey) = drive(word, r);
                worst = worst.max((ex - x).hypot(ey - y));
                assert!(len >= x.hypot(y) - 1e-9, "({x}, {y}): {len}");
                // Mirror symmetry.
                let (mirrored, _) = shortest(x, -y, r);
                assert!((mirrored - len).abs() < 1e-9, "({x}, {y})");
            }
        }
        assert!(worst < 1e-6, "a path ends {worst} m from its point");
    }

    #[test]
    fn no_sampled_path_of_the_four_words_is_shorter() {
        // Brute force: first arcs on a fine grid, each followed by the straight or the second
        // arc that reaches the point, where one does.
        let r = 1.0;
        for &(x, y) in &[
            (0.2, 0.5),
            (-0.7, 0.3),
            (2.5, 1.0),
            (-3.0, -0.2),
            (0.1, -1.9),
        ] {
            let (len, _) = shortest(x, y, r);
            let mut hits = 0;
            let n = 20_000;
            for k in 0..n {
                let a = TAU * k as f64 / n as f64;
                for left in [true, false] {
                    let side = if left { 1.0 } else { -1.0 };
                    // Pose after the first arc.
                    let (qx, qy, qh) = (r * a.sin(), side * r * (1.0 - a.cos()), side * a);
                    // Straight: the point must lie on the ray ahead.
                    let (dx, dy) = (x - qx, y - qy);
                    let along = dx * qh.cos() + dy * qh.sin();
                    let across = -dx * qh.sin() + dy * qh.cos();
                    if along >= 0.0 && across.abs() < 5e-3 {
                        hits += 1;
                        assert!(r * a + along >= len - 2e-2, "({x}, {y}) straight at {a}");
                    }
                    // Second arc of the other direction: the point on that circle.
                    let (cx, cy) = (qx + side * r * qh.sin(), qy - side * r * qh.cos());
                    if ((x - cx).hypot(y - cy) - r).abs() < 5e-3 {
                        hits += 1;
                        let start = (qy - cy).atan2(qx - cx);
                        let end = (y - cy).atan2(x - cx);
                        let b = wrap_tau(side * (start - end));
                        assert!(r * (a + b) >= len - 2e-2, "({x}, {y}) arcs at {a}");
                    }
                }
            }
            assert!(hits > 0, "({x}, {y}): no sampled path reaches it");
        }
    }

    #[test]
    fn backing_up_reaches_a_point_beside_the_car_sooner_than_a_loop() {
        let (r, v, back) = (1.6, 1.5, 0.8);
        let o = Pose2::IDENTITY;
        // Ahead: the straight line at the forward speed, reversing or not.
        assert!((time_to_point(&o, [6.0, 0.0], r, v, back) - 4.0).abs() < 1e-12);
        // Straight behind: backing up at the reverse speed.
        assert!((time_to_point(&o, [-2.0, 0.0], r, v, back) - 2.0 / back).abs() < 1e-12);
        // Beside the car, inside its left turning circle: a loop forward without reversing,
        // a two-point turn with it, and never faster than the straight line.
        let p = [0.3, 0.8];
        let looped = time_to_point(&o, p, r, v, 0.0);
        assert!((looped - distance_to_point(&o, p, r) / v).abs() < 1e-12);
        let turned = time_to_point(&o, p, r, v, back);
        assert!(turned < 0.6 * looped, "{turned} against {looped}");
        assert!(turned >= 0.3f64.hypot(0.8) / v);
        // A robot that turns in place: the straight line.
        assert!((time_to_point(&o, p, 0.0, v, back) - 0.3f64.hypot(0.8) / v).abs() < 1e-12);
    }

    #[test]
    fn the_two_point_turn_is_a_path_the_car_can_drive() {
        // Back up b, then the forward word from there: it ends on the point.
        let r = 1.6;
        let p = (0.3, 0.8);
        let b = 2.0 * r * 5.0 / CUSP_STEPS as f64;
        let (_, word) = shortest(p.0 + b, p.1, r);
        let (ex, ey) = drive(word, r);
        assert!((ex - b - p.0).hypot(ey - p.1) < 1e-6);
    }

    #[test]
    fn non_finite_inputs_do_not_panic() {
        let o = Pose2::IDENTITY;
        assert!(!distance_to_point(&o, [f64::NAN, 1.0], 1.0).is_finite());
        assert!(!distance_to_point(&o, [f64::INFINITY, 1.0], 1.0).is_finite());
        assert!(!distance_to_point(&Pose2::new(0.0, 0.0, f64::NAN), [1.0, 1.0], 1.0).is_finite());
        assert!(!time_to_point(&o, [f64::NAN, 1.0], 1.0, 1.0, 0.5).is_finite());
    }
}
