//! The long fuzz run: `cargo run -p human2nav-fuzz --release -- --seconds 600 [--out DIR]
//! [--seed N] [TARGET...]`.
//!
//! Runs every target (or the named ones) for an equal share of the time on random seeds and
//! prints `target | executions | crashes | distinct crash sites`. Panics are caught here only
//! to count them: each crashing input is saved as `<out>/<target>/crash-<hash>` (default out
//! `out/fuzz`) with the panic message beside it, so it can be replayed with
//! `--replay <target> <file>`. A call that does not return within 30 s is reported as a hang:
//! its input is saved and the run stops (the thread cannot be interrupted).

use human2nav_fuzz::{Scratch, fnv, next_input, targets};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Where the last panic happened and what it said (set by the panic hook).
static LAST_PANIC: Mutex<Option<(String, String)>> = Mutex::new(None);

struct Args {
    seconds: f64,
    out: PathBuf,
    seed: Option<u64>,
    names: Vec<String>,
    replay: Option<(String, PathBuf)>,
}

fn usage() -> ! {
    eprintln!(
        "usage: human2nav-fuzz [--seconds S] [--out DIR] [--seed N] [TARGET...]\n       \
         human2nav-fuzz --replay TARGET FILE\n       human2nav-fuzz --list"
    );
    std::process::exit(2)
}

fn parse_args() -> Args {
    let mut a = Args {
        seconds: 60.0,
        out: PathBuf::from("out/fuzz"),
        seed: None,
        names: Vec::new(),
        replay: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--seconds" => {
                a.seconds = it
                    .next()
                    .and_then(|v| v.parse().ok())
                    .unwrap_or_else(|| usage())
            }
            "--out" => a.out = it.next().map(PathBuf::from).unwrap_or_else(|| usage()),
            "--seed" => {
                a.seed = Some(
                    it.next()
                        .and_then(|v| v.parse().ok())
                        .unwrap_or_else(|| usage()),
                )
            }
            "--replay" => {
                let (Some(t), Some(f)) = (it.next(), it.next()) else {
                    usage()
                };
                a.replay = Some((t, PathBuf::from(f)));
            }
            "--list" => {
                for t in targets::all() {
                    println!("{:<14} {}", t.name, t.covers);
                }
                std::process::exit(0);
            }
            "-h" | "--help" => usage(),
            name => a.names.push(name.to_string()),
        }
    }
    a
}

/// Per-target results.
#[derive(Default)]
struct Tally {
    execs: u64,
    crashes: u64,
    sites: BTreeSet<String>,
}

fn main() {
    let args = parse_args();
    if let Some((name, file)) = &args.replay {
        // Replay: no catching, so the panic and its backtrace show as usual.
        let t = targets::by_name(name).unwrap_or_else(|| usage());
        let input = std::fs::read(file).unwrap_or_else(|e| {
            eprintln!("cannot read {}: {e}", file.display());
            std::process::exit(2)
        });
        let scratch = Scratch::new(t.name).expect("temp directory");
        (t.exec)(&scratch, &input);
        println!("{}: returned", t.name);
        return;
    }
    let all = targets::all();
    let chosen: Vec<_> = all
        .into_iter()
        .filter(|t| args.names.is_empty() || args.names.iter().any(|n| n == t.name))
        .collect();
    if chosen.is_empty() {
        usage();
    }
    std::panic::set_hook(Box::new(|info| {
        let site = info
            .location()
            .map(|l| format!("{}:{}", l.file(), l.line()))
            .unwrap_or_else(|| "unknown".into());
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_default();
        if let Ok(mut g) = LAST_PANIC.lock() {
            *g = Some((site, msg));
        }
    }));

    // Hang watchdog: the start of the current call (ms since `t0`, 0 when idle) and its input.
    let t0 = Instant::now();
    let started = Arc::new(AtomicU64::new(0));
    let current: Arc<Mutex<(String, Vec<u8>)>> = Arc::new(Mutex::new((String::new(), Vec::new())));
    {
        let (started, current, out) = (started.clone(), current.clone(), args.out.clone());
        std::thread::spawn(move || {
            loop {
                std::thread::sleep(Duration::from_secs(1));
                let s = started.load(Ordering::Relaxed);
                let now = t0.elapsed().as_millis() as u64;
                if s != 0 && now.saturating_sub(s) > 30_000 {
                    if let Ok(g) = current.lock() {
                        let p = save(&out, &g.0, "hang", &g.1, "no return within 30 s");
                        eprintln!("HANG in target `{}`: input saved as {}", g.0, p.display());
                    }
                    std::process::exit(3);
                }
            }
        });
    }

    let share = args.seconds / chosen.len() as f64;
    let base_seed = args.seed.unwrap_or_else(rand::random);
    println!(
        "fuzzing {} targets for {:.0} s each (seed {base_seed})",
        chosen.len(),
        share
    );
    let mut rows = Vec::new();
    for (k, t) in chosen.iter().enumerate() {
        let scratch = Scratch::new(t.name).expect("temp directory");
        let seeds = (t.seeds)();
        let mut rng = ChaCha8Rng::seed_from_u64(base_seed ^ fnv(t.name.as_bytes()) ^ k as u64);
        let mut tally = Tally::default();
        let end = Instant::now() + Duration::from_secs_f64(share);
        while Instant::now() < end {
            let input = next_input(&mut rng, &seeds);
            if let Ok(mut g) = current.lock() {
                g.0.clear();
                g.0.push_str(t.name);
                g.1.clone_from(&input);
            }
            started.store(t0.elapsed().as_millis().max(1) as u64, Ordering::Relaxed);
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                (t.exec)(&scratch, &input)
            }));
            started.store(0, Ordering::Relaxed);
            tally.execs += 1;
            if r.is_err() {
                tally.crashes += 1;
                let (site, msg) = LAST_PANIC
                    .lock()
                    .ok()
                    .and_then(|mut g| g.take())
                    .unwrap_or_else(|| ("unknown".into(), String::new()));
                if tally.sites.insert(site.clone()) {
                    let p = save(
                        &args.out,
                        t.name,
                        "crash",
                        &input,
                        &format!("{site}: {msg}"),
                    );
                    eprintln!(
                        "CRASH in `{}` at {site}: {msg} (input {})",
                        t.name,
                        p.display()
                    );
                }
            }
        }
        println!(
            "{:<14} {:>10} execs {:>6} crashes",
            t.name, tally.execs, tally.crashes
        );
        rows.push((t.name, tally));
    }
    println!("\n| target | executions | crashes | distinct crash sites |\n|---|---|---|---|");
    let (mut e, mut c) = (0, 0);
    for (name, t) in &rows {
        e += t.execs;
        c += t.crashes;
        let sites = if t.sites.is_empty() {
            "0".to_string()
        } else {
            format!(
                "{} ({})",
                t.sites.len(),
                t.sites.iter().cloned().collect::<Vec<_>>().join(", ")
            )
        };
        println!("| `{name}` | {} | {} | {sites} |", t.execs, t.crashes);
    }
    println!("| total | {e} | {c} | |");
    if c > 0 {
        std::process::exit(1);
    }
}

/// Saves a crashing input and its message under `out/<target>/`; returns the input's path.
fn save(out: &Path, target: &str, kind: &str, input: &[u8], message: &str) -> PathBuf {
    let dir = out.join(target);
    let _ = std::fs::create_dir_all(&dir);
    let p = dir.join(format!("{kind}-{:016x}", fnv(input)));
    let _ = std::fs::write(&p, input);
    let _ = std::fs::write(p.with_extension("txt"), message);
    p
}
