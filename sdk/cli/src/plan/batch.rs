//! `human2nav plan --bench CALLS --batch B`: the throughput of `Human2Nav::plan_batch` against
//! the same planners planned one by one, on one and on two threads.

use super::bar;
use human2nav_core::ablation::Arm;
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings};
use human2nav_core::robot::RobotProfile;
use human2nav_core::{Observation, Planner};
use human2nav_flow::planner::{
    Backend, FlowCallStats, PlannerModel, TimedModel, bev_spec, check_dt, load_model, load_profile,
    robot_model, robot_phi,
};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

type TimedPlanner = Human2Nav<TimedModel<PlannerModel>>;

/// One measurement: plans made, wall seconds, network seconds summed over the planners.
struct Run {
    plans: usize,
    wall_s: f64,
    network_s: f64,
}

/// Prints the throughput table: per backend, for the configured planner and the raw arm,
/// `batch` planners (on one network: clones of one native model, or libtorch models loaded from
/// one folder; planner `i` of round `r` on window `r·batch + i`) planned one by one and as one
/// batch, on one thread and split over two, `rounds` rounds each after one warm-up round.
pub(super) fn batch_table(
    robot: &Path,
    model_dir: &Path,
    backends: &[Backend],
    base: &Human2NavSettings,
    wins: &[Observation],
    (calls, batch): (usize, usize),
) -> anyhow::Result<()> {
    let rounds = calls.div_ceil(batch).max(1);
    let profile = load_profile(robot)?;
    println!();
    println!(
        "batched planning: {batch} planners a round on one network, {rounds} rounds of {} windows; \
         speed-up = plans/s batched ÷ one by one on as many threads",
        wins.len()
    );
    println!(
        "| mode | backend | threads | planning | plans | plans/s | thread-ms per plan | network ms per plan | speed-up |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    let modes = [
        ("configured".to_string(), *base),
        (Arm::Raw.key().to_string(), Arm::Raw.settings(base)),
    ];
    for (mode, settings) in modes {
        for (&backend, threads) in backends.iter().flat_map(|b| [(b, 1), (b, 2)]) {
            let model = load_model(model_dir, backend)?;
            let mut one_by_one = 0.0;
            for batched in [false, true] {
                let what = format!(
                    "{mode}, {backend}, {threads} thread(s), {}",
                    if batched { "batched" } else { "one by one" }
                );
                let shape = (rounds, batch, threads);
                let r = measure(
                    &profile,
                    (&model, model_dir),
                    settings,
                    wins,
                    shape,
                    batched,
                    &what,
                )?;
                let rate = r.plans as f64 / r.wall_s;
                if !batched {
                    one_by_one = rate;
                }
                println!(
                    "| {mode} | {backend} | {threads} | {} | {} | {rate:.1} | {:.2} | {:.2} | {:.2} |",
                    if batched { "batched" } else { "one by one" },
                    r.plans,
                    r.wall_s * threads as f64 * 1e3 / r.plans as f64,
                    r.network_s * 1e3 / r.plans as f64,
                    rate / one_by_one
                );
            }
        }
    }
    println!(
        "plans are the same either way, bit for bit (tested; libtorch on the CPU runs a batch group by group, on a \
         GPU as one pass, which agrees to float rounding); network = flow-network calls, the batched sampling's \
         calls counted once for all the planners of the batch."
    );
    Ok(())
}

/// A planner on `model`'s network: a native model shared, a libtorch one loaded again from
/// `dir`.
fn planner(
    profile: &RobotProfile,
    (model, dir): (&PlannerModel, &Path),
    settings: Human2NavSettings,
) -> anyhow::Result<(TimedPlanner, Arc<Mutex<FlowCallStats>>)> {
    check_dt(model.card(), &settings)?;
    let (bev, _) = bev_spec(model.card());
    let handle = match model.try_share() {
        Some(m) => m,
        None => load_model(dir, model.backend())?,
    };
    let timed = TimedModel::new(handle);
    let stats = timed.stats();
    let phi = robot_phi(profile)?;
    Ok((
        Human2Nav::new(timed, robot_model(profile, phi), bev, settings)?,
        stats,
    ))
}

/// `rounds` rounds of `batch` plans split over `threads` threads (each planning its share of
/// the planners), batched or one by one.
fn measure(
    profile: &RobotProfile,
    model: (&PlannerModel, &Path),
    settings: Human2NavSettings,
    wins: &[Observation],
    (rounds, batch, threads): (usize, usize, usize),
    batched: bool,
    what: &str,
) -> anyhow::Result<Run> {
    let mut planners = Vec::with_capacity(batch);
    let mut stats = Vec::with_capacity(batch);
    for _ in 0..batch {
        let (p, s) = planner(profile, model, settings)?;
        planners.push(p);
        stats.push(s);
    }
    let obs = |round: usize, i: usize| &wins[(round * batch + i) % wins.len()];
    // Each thread's planners and the index of its first one.
    let share = batch.div_ceil(threads);
    let pb = bar(rounds * batch, what);
    let run_round = |first: usize, ps: &mut [TimedPlanner], round: usize| -> anyhow::Result<()> {
        let os: Vec<Observation> = (0..ps.len())
            .map(|i| obs(round, first + i).clone())
            .collect();
        ps.iter_mut().for_each(|p| p.reset());
        if batched {
            let mut refs: Vec<&mut TimedPlanner> = ps.iter_mut().collect();
            for plan in Human2Nav::plan_batch(&mut refs, &os)? {
                plan?;
            }
        } else {
            for (p, o) in ps.iter_mut().zip(&os) {
                p.plan(o)?;
            }
        }
        pb.inc(ps.len() as u64);
        Ok(())
    };
    let run_all = |planners: &mut [TimedPlanner], rounds: std::ops::Range<usize>| {
        std::thread::scope(|scope| {
            let handles: Vec<_> = planners
                .chunks_mut(share)
                .enumerate()
                .map(|(c, ps)| {
                    let mut rounds = rounds.clone();
                    scope.spawn(move || rounds.try_for_each(|r| run_round(c * share, ps, r)))
                })
                .collect();
            handles.into_iter().try_for_each(|h| {
                h.join()
                    .map_err(|_| anyhow::anyhow!("a planning thread panicked"))?
            })
        })
    };
    run_all(&mut planners, 0..1)?;
    let network_before: f64 = network_seconds(&stats)?;
    let start = Instant::now();
    run_all(&mut planners, 1..rounds + 1)?;
    let wall_s = start.elapsed().as_secs_f64();
    pb.finish_and_clear();
    Ok(Run {
        plans: rounds * batch,
        wall_s,
        network_s: network_seconds(&stats)? - network_before,
    })
}

fn network_seconds(stats: &[Arc<Mutex<FlowCallStats>>]) -> anyhow::Result<f64> {
    stats.iter().try_fold(0.0, |sum, s| {
        let s = s
            .lock()
            .map_err(|_| anyhow::anyhow!("stats lock poisoned"))?;
        Ok(sum + s.velocity_s + s.vjp_s)
    })
}
