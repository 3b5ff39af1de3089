//! `Foresight`: a yardstick predictor of people for a planner under test. It reads the
//! episode's recording, so it belongs to the benchmark, never to a planner in use.
//!
//! Its forecast of each observed pedestrian is constant velocity moved a share `share` of the
//! way to where the recording has that pedestrian at each waypoint:
//! `p = p_cv + share · (p_recorded − p_cv)`. With share 0 it is constant velocity, the
//! forecast a planner makes without a predictor; with share 1 it is the recorded future of the
//! pedestrians observed now (the search's `oracle-seen`, [`crate::oracle`]). In between, every
//! predicted position is off by `1 − share` of constant velocity's error, so the forecast's ADE
//! and FDE are `1 − share` of constant velocity's on the same instants. Run with a planner's
//! own selection, it answers how good a predictor of the observed crowd the planner would need
//! to reach a success rate: the planner's success rate against the share, read at the ADE it
//! corresponds to.
//!
//! With [`ForesightSettings::within`] only the pedestrians within a radius of the robot when it plans
//! get the foresight, and the others stay at constant velocity: whether a predictor has to be
//! good about everyone in view or only about the people near the robot.
//!
//! With [`ForesightSettings::until`] the recording is followed only that far ahead, and constant
//! velocity from there on (at the velocity an observer would see then): how far ahead a
//! predictor has to be right.
//!
//! A pedestrian the recording no longer holds at a waypoint (its track has ended) keeps its
//! constant-velocity position there. In a reactive crowd people depart from their recording
//! near the robot, so there the foresight is only approximately right, as the oracle's is.

use crate::episode::Episode;
use crate::replay::CrowdReplay;
use human2nav_core::Observation;
use human2nav_core::forecast::{CrowdPredictor, Forecast, ForecastError, constant_velocity_path};
use std::collections::HashMap;

/// What a [`Foresight`] knows (module docs). The bench keys of a `human2nav` method are
/// named after its fields: `foresight`, `foresight_within`, `foresight_until`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForesightSettings {
    /// How far the forecast moves from constant velocity to the recording, 0 to 1.
    pub share: f64,
    /// Only pedestrians whose centre is this close to the robot's when it plans (m, > 0) get
    /// the foresight; infinite: everyone in view.
    pub within: f64,
    /// The recording is followed this far ahead (s, > 0); after that each pedestrian walks on
    /// from its recorded position then, at the velocity an observer would see then
    /// ([`CrowdReplay::observed_velocity`]); infinite: the whole horizon.
    pub until: f64,
}

impl ForesightSettings {
    /// `share` of the recording, for everyone in view and the whole horizon.
    pub fn share(share: f64) -> Self {
        Self {
            share,
            within: f64::INFINITY,
            until: f64::INFINITY,
        }
    }

    /// Checks every field; the error begins with the field's bench key.
    pub fn validate(&self) -> Result<(), String> {
        if !(0.0..=1.0).contains(&self.share) {
            return Err(format!(
                "foresight must be a number from 0 to 1, got {}",
                self.share
            ));
        }
        for (key, value, what) in [
            ("foresight_within", self.within, "a distance above 0 m"),
            ("foresight_until", self.until, "a time above 0 s"),
        ] {
            if value.is_nan() || value <= 0.0 {
                return Err(format!("{key} must be {what}, got {value}"));
            }
        }
        Ok(())
    }
}

/// Constant velocity moved a share of the way to the recorded future (module docs).
#[derive(Clone, Debug)]
pub struct Foresight {
    episode: Episode,
    /// The index in `episode.agents` of each recorded id.
    tracks: HashMap<u64, usize>,
    settings: ForesightSettings,
}

impl Foresight {
    /// The foresight of `episode`'s recording with `settings`, checked
    /// ([`ForesightSettings::validate`]).
    pub fn new(episode: Episode, settings: ForesightSettings) -> Result<Self, String> {
        settings.validate()?;
        let tracks = episode
            .agents
            .iter()
            .enumerate()
            .map(|(k, t)| (t.id, k))
            .collect();
        Ok(Self {
            episode,
            tracks,
            settings,
        })
    }
}

impl CrowdPredictor for Foresight {
    fn name(&self) -> &str {
        "foresight"
    }

    fn forecast(
        &mut self,
        obs: &Observation,
        horizon: usize,
        dt: f64,
    ) -> Result<Forecast, ForecastError> {
        let ForesightSettings {
            share,
            within,
            until,
        } = self.settings;
        let replay = CrowdReplay::new(&self.episode);
        Forecast::one_path_each(&obs.agents, horizon, |a| {
            let mut path = constant_velocity_path(a, horizon, dt);
            let near = (a.position[0] - obs.ego.x).hypot(a.position[1] - obs.ego.y) <= within;
            let track = self.tracks.get(&a.id).map(|&k| &self.episode.agents[k]);
            if let Some(track) = track.filter(|_| near) {
                // Where the recording is left for constant velocity, if within the horizon.
                let cut = obs.time + until;
                let from_cut = replay
                    .sample(track, cut)
                    .zip(replay.observed_velocity(track, cut));
                for (k, p) in path.iter_mut().enumerate() {
                    let t = obs.time + (k + 1) as f64 * dt;
                    let recorded = if t <= cut {
                        replay.sample(track, t).map(|s| s.position)
                    } else {
                        from_cut.map(|(s, v)| {
                            let after = t - cut;
                            [s.position[0] + v[0] * after, s.position[1] + v[1] * after]
                        })
                    };
                    if let Some(q) = recorded {
                        p[0] += share * (q[0] - p[0]);
                        p[1] += share * (q[1] - p[1]);
                    }
                }
            }
            path
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{AgentTrack, ScenarioClass};
    use human2nav_core::{AgentState, Pose2};

    /// One pedestrian recorded walking +y at 1 m/s from (2, 0) for 5 s, observed at t = 1 s
    /// walking +x at 1 m/s (a wrong velocity, so that the recording and constant velocity
    /// differ), and one observed pedestrian the recording does not hold.
    fn setup() -> (Episode, Observation) {
        let episode = Episode {
            id: "hand".into(),
            scene: "test/hand".into(),
            source: "synthetic".into(),
            scenario: ScenarioClass::CrossFlow,
            dt: 0.1,
            start: Pose2::IDENTITY,
            goal: [5.0, 0.0],
            time_budget: 12.5,
            agents: vec![AgentTrack {
                id: 7,
                start_step: 0,
                positions: (0..=50).map(|k| [2.0, 0.1 * k as f64]).collect(),
                radius: 0.3,
            }],
            density: 1,
            obstacles: Vec::new(),
            human_path: Vec::new(),
        };
        let walker = |id, x| AgentState {
            id,
            position: [x, 1.0],
            velocity: [1.0, 0.0],
            radius: 0.3,
            history: Vec::new(),
        };
        let obs = Observation {
            time: 1.0,
            goal: [5.0, 0.0],
            agents: vec![walker(7, 2.0), walker(9, -3.0)],
            ..Observation::default()
        };
        (episode, obs)
    }

    #[test]
    fn the_share_moves_constant_velocity_to_the_recording() {
        let (episode, obs) = setup();
        let at = |share: f64, agent: usize, k: usize| {
            let mut f = Foresight::new(episode.clone(), ForesightSettings::share(share)).unwrap();
            f.forecast(&obs, 10, 0.1).unwrap().position(agent, 0, k)
        };
        // Waypoint k is (k + 1) · 0.1 s after the observation: constant velocity has agent 7 at
        // (2 + 0.1 (k + 1), 1), the recording at (2, 1 + 0.1 (k + 1)).
        for k in [0, 4, 9] {
            let s = 0.1 * (k + 1) as f64;
            let cv = [2.0 + s, 1.0];
            let rec = [2.0, 1.0 + s];
            for share in [0.0, 0.25, 1.0] {
                let p = at(share, 0, k);
                for d in 0..2 {
                    let want = cv[d] + share * (rec[d] - cv[d]);
                    assert!((p[d] - want).abs() < 1e-9, "share {share}, k {k}: {p:?}");
                }
            }
            // The pedestrian the recording does not hold stays at constant velocity.
            let q = at(1.0, 1, k);
            assert!((q[0] - (-3.0 + s)).abs() < 1e-9 && (q[1] - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn within_a_radius_only_the_near_get_the_foresight() {
        let (episode, mut obs) = setup();
        // The robot at (0, 1): agent 7 at (2, 1) is 2 m away, agent 9 at (-3, 1) 3 m.
        obs.ego.y = 1.0;
        obs.agents[1].id = 7; // the far one follows the same recording if it gets it
        let cv = |agent: usize, k: usize| {
            let s = 0.1 * (k + 1) as f64;
            [obs.agents[agent].position[0] + s, 1.0]
        };
        let mut f = Foresight::new(
            episode.clone(),
            ForesightSettings {
                within: 2.5,
                ..ForesightSettings::share(1.0)
            },
        )
        .unwrap();
        let forecast = f.forecast(&obs, 10, 0.1).unwrap();
        for k in [0, 9] {
            let s = 0.1 * (k + 1) as f64;
            let near = forecast.position(0, 0, k);
            assert!((near[0] - 2.0).abs() < 1e-9 && (near[1] - (1.0 + s)).abs() < 1e-9);
            assert_eq!(forecast.position(1, 0, k), cv(1, k));
        }
    }

    #[test]
    fn until_a_horizon_the_recording_then_constant_velocity_from_it() {
        let (mut episode, obs) = setup();
        // Agent 7's recording turns at 1.5 s (0.5 s after the observation) from +y to +x.
        let track = &mut episode.agents[0];
        for (k, p) in track.positions.iter_mut().enumerate().skip(15) {
            *p = [2.0 + 0.1 * (k - 15) as f64, 1.5];
        }
        let mut f = Foresight::new(
            episode.clone(),
            ForesightSettings {
                until: 0.3,
                ..ForesightSettings::share(1.0)
            },
        )
        .unwrap();
        let forecast = f.forecast(&obs, 10, 0.1).unwrap();
        for k in 0..10 {
            let s = 0.1 * (k + 1) as f64;
            // The recording up to 0.3 s, then on at +y 1 m/s from (2, 1.3).
            let want = [2.0, 1.0 + s];
            let p = forecast.position(0, 0, k);
            assert!(
                (p[0] - want[0]).abs() < 1e-9 && (p[1] - want[1]).abs() < 1e-9,
                "k {k}: {p:?}"
            );
        }
        // Without the horizon, the turn shows.
        let mut all = Foresight::new(episode.clone(), ForesightSettings::share(1.0)).unwrap();
        assert!((all.forecast(&obs, 10, 0.1).unwrap().position(0, 0, 9)[0] - 2.5).abs() < 1e-9);
    }

    #[test]
    fn a_share_outside_zero_to_one_or_a_limit_not_above_zero_is_refused() {
        let (episode, _) = setup();
        for share in [-0.1, 1.5, f64::NAN] {
            let err = Foresight::new(episode.clone(), ForesightSettings::share(share)).unwrap_err();
            assert!(err.contains("foresight"), "{err}");
        }
        let full = ForesightSettings::share(1.0);
        for bad in [0.0, -1.0, f64::NAN] {
            for (key, settings) in [
                (
                    "foresight_within",
                    ForesightSettings {
                        within: bad,
                        ..full
                    },
                ),
                ("foresight_until", ForesightSettings { until: bad, ..full }),
            ] {
                let err = Foresight::new(episode.clone(), settings).unwrap_err();
                assert!(err.contains(key), "{err}");
            }
        }
    }
}
