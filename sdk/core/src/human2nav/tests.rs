use super::candidates::motion_count;
use super::selection::{goal_term, select_best};
use super::*;

/// A candidate's goal term, and how many of its waypoints the clearance term scores.
fn progress_checked(
    (traj, goal, w, reach): (&[Pose2], [f64; 2], &SelectionWeights, f64),
) -> (f64, usize) {
    let clearance = Clearance {
        margin: w.margin,
        collision: w.collision,
        hold: 0,
        arrival: (w.progress != Progress::End).then_some(w.arrival),
    };
    (
        goal_term(traj, goal, w, reach),
        clearance.checked(traj, Some(goal)).0,
    )
}

fn line(speed: f64) -> Vec<Pose2> {
    (1..=4)
        .map(|k| Pose2::new(0.1 * speed * k as f64, 0.0, 0.0))
        .collect()
}

#[test]
fn an_uncorrected_candidate_never_wins_over_a_corrected_one() {
    // Candidate 0 scores best but the correction failed on it.
    let candidates = vec![line(1.0), line(2.0), line(3.0)];
    let score = |i: usize| candidates[i][0].x;
    assert_eq!(
        select_best(&candidates, &[false, true, true], &score),
        Some(1)
    );
    // Without the correction, or when it failed on all, the score alone decides.
    assert_eq!(select_best(&candidates, &[], &score), Some(0));
    assert_eq!(
        select_best(&candidates, &[false, false, false], &score),
        Some(0)
    );
}

#[test]
fn the_goal_term_measures_the_end_or_the_closest_approach() {
    // 0.1 m apart along x, from 0.4 m to 4.0 m: the goal at (2, 0.5) is passed.
    let traj: Vec<Pose2> = (4..=40)
        .map(|k| Pose2::new(0.1 * k as f64, 0.0, 0.0))
        .collect();
    let goal = [2.0, 0.5];
    let d0 = 2.0f64.hypot(0.5);
    let end = SelectionWeights {
        progress: Progress::End,
        ..SelectionWeights::default()
    };
    // The end at (4, 0) is as far from the goal as the start.
    let (p, checked) = progress_checked((&traj, goal, &end, 0.1));
    assert!((p - 1.0).abs() < 1e-12, "{p}");
    assert_eq!(checked, traj.len());
    // The closest approach is 0.5 m, at (2, 0): not within 0.3 m, so not arrived.
    let closest = SelectionWeights {
        progress: Progress::Closest,
        ..end
    };
    let (p, checked) = progress_checked((&traj, goal, &closest, 0.1));
    assert!((p - 0.5 / d0).abs() < 1e-12, "{p}");
    assert_eq!(checked, traj.len());
    // Within 0.6 m it arrives at (1.7, 0), the 14th waypoint, and is checked up to there.
    let (p, checked) = progress_checked((
        &traj,
        goal,
        &SelectionWeights {
            arrival: 0.6,
            ..closest
        },
        0.1,
    ));
    assert_eq!(p, 0.0);
    assert_eq!(checked, 14);
    assert!((traj[13].x - 1.7).abs() < 1e-12);
    // A candidate leading away: its closest approach is where the robot stands.
    let away: Vec<Pose2> = traj.iter().map(|p| Pose2::new(-p.x, 0.0, 0.0)).collect();
    assert_eq!(goal_term(&away, goal, &closest, 0.1), 1.0);
    assert_eq!(progress_checked((&[], goal, &closest, 0.1)), (1.0, 0));
}

#[test]
fn a_candidate_goes_on_at_the_twist_of_its_last_step() {
    // An arc: 0.1 m and 0.05 rad a step from the robot's pose.
    let step = Pose2::new(0.1, 0.0, 0.05);
    let mut arc = vec![step];
    for _ in 1..5 {
        arc.push(arc[arc.len() - 1].compose(step));
    }
    let long = continued(&arc[..3], 2);
    assert_eq!(long.len(), 5);
    for (a, b) in long.iter().zip(&arc) {
        assert!(
            (a.x - b.x).abs() < 1e-12 && (a.y - b.y).abs() < 1e-12,
            "{a:?} {b:?}"
        );
        assert!((a.theta - b.theta).abs() < 1e-12);
    }
    // One pose: its step is from the robot's pose (the identity).
    let one = continued(&arc[..1], 4);
    assert!((one[4].x - arc[4].x).abs() < 1e-12 && (one[4].y - arc[4].y).abs() < 1e-12);
    // At rest it stays; nothing to continue from is nothing.
    let rest = continued(&[Pose2::new(1.0, 2.0, 0.3); 2], 3);
    assert!(rest.iter().all(|p| *p == Pose2::new(1.0, 2.0, 0.3)));
    assert!(continued(&[], 3).is_empty());
    assert_eq!(continued(&arc, 0), arc);
}

#[test]
fn the_time_goal_term_ranks_an_arrival_by_how_soon_it_comes() {
    // v_max·dt = 0.1 m a step; the goal 2 m ahead.
    let goal = [2.0, 0.0];
    let w = SelectionWeights {
        progress: Progress::Time,
        ..SelectionWeights::default()
    };
    let at = |speed: f64, n: usize| -> Vec<Pose2> {
        (1..=n)
            .map(|k| Pose2::new(0.1 * speed * k as f64, 0.0, 0.0))
            .collect()
    };
    // At full speed it arrives (within 0.3 m) on the 17th waypoint: 1.7 m covered.
    let (fast, checked) = progress_checked((&at(1.0, 40), goal, &w, 0.1));
    assert_eq!(checked, 17);
    assert!((fast - 1.7 / 2.0).abs() < 1e-12, "{fast}");
    // At half speed it arrives on the 34th: twice as late, and it ranks worse.
    let (slow, checked) = progress_checked((&at(0.5, 40), goal, &w, 0.1));
    assert_eq!(checked, 34);
    assert!((slow - 3.4 / 2.0).abs() < 1e-12, "{slow}");
    // Closest approach calls both arrived alike.
    let closest = SelectionWeights::default();
    assert_eq!(goal_term(&at(1.0, 40), goal, &closest, 0.1), 0.0);
    assert_eq!(goal_term(&at(0.5, 40), goal, &closest, 0.1), 0.0);
    // Not arriving: the way covered by its end plus the distance left there. Standing
    // still for as long ranks behind it, and backing away behind that.
    let (short, checked) = progress_checked((&at(0.5, 10), goal, &w, 0.1));
    assert_eq!(checked, 10);
    assert!((short - (1.0 + 1.5) / 2.0).abs() < 1e-12, "{short}");
    let rest = goal_term(&[Pose2::IDENTITY; 10], goal, &w, 0.1);
    assert!((rest - 3.0 / 2.0).abs() < 1e-12, "{rest}");
    let away = goal_term(&at(-0.5, 10), goal, &w, 0.1);
    assert!((away - 3.5 / 2.0).abs() < 1e-12, "{away}");
    assert!(fast < short && short < rest && rest < away);
    // Over as many waypoints a late arrival still beats standing still.
    let rest_40 = goal_term(&[Pose2::IDENTITY; 40], goal, &w, 0.1);
    assert!((rest_40 - 6.0 / 2.0).abs() < 1e-12, "{rest_40}");
    assert!(slow < rest_40);
    assert_eq!(progress_checked((&[], goal, &w, 0.1)), (1.0, 0));
}

#[test]
fn a_car_is_offered_its_own_count_of_motions() {
    let walker = Limits {
        v_max: 1.2,
        v_reverse_max: 0.3,
        a_max: 1.0,
        omega_max: 1.5,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    };
    let car = Limits {
        kappa_max: Some(1.0 / 1.6),
        ..walker
    };
    let count = |motions, car_motions, limits: &Limits| {
        let s = Human2NavSettings {
            motions,
            car_motions,
            ..Human2NavSettings::default()
        };
        motion_count(&s, limits)
    };
    assert_eq!(count(500, 2401, &walker), 500);
    assert_eq!(count(500, 2401, &car), 2401);
    assert_eq!(count(500, 0, &car), 500, "0: as many as motions");
    assert_eq!(count(0, 2401, &car), 0, "motions = 0: none");
    // The shipped defaults: every pair of the car's 7 × 7 grid.
    let d = Human2NavSettings::default();
    let grid = MotionGrid::new(car, GridLevels::default());
    assert_eq!(motion_count(&d, &car), grid.len());
}

#[test]
fn selection_skips_non_finite_candidates_and_scores() {
    let mut bad = line(1.0);
    bad[2].y = f64::NAN;
    let candidates = vec![bad, line(2.0), line(3.0)];
    assert_eq!(
        select_best(&candidates, &[], |i| candidates[i][0].x),
        Some(1)
    );
    let nan_for_second = |i: usize| {
        let c = &candidates[i];
        if c[0].x > 0.15 && c[0].x < 0.25 {
            f64::NAN
        } else {
            c[0].x
        }
    };
    assert_eq!(select_best(&candidates, &[], nan_for_second), Some(2));
    assert_eq!(
        select_best(&candidates[..1], &[], |i| candidates[i][0].x),
        None
    );
}
