//! Fuzz targets for everything the SDK reads from a user or a plugin, on the stable toolchain.
//!
//! Each [`Target`] has seeds (the shipped files, or small inline samples of a dataset format)
//! and a function that feeds one input to the real reader: through a temporary regular file
//! where the reader takes a path, else directly. Inputs are seeds changed by [`mutate()`]: bit and
//! byte flips, insertions, truncation, numbers replaced by extremes (`1e300`, `NaN`, `-0`,
//! `2^63`, ...), values of the wrong type, duplicated and dropped lines (duplicated keys), deep
//! nesting, long strings and splices of other seeds.
//!
//! The `capi_*` targets call the C API's `extern "C"` functions through its Rust library, as a C
//! program would, and check what its header promises (a status, a message on failure, finite
//! outputs, a planner that a bad call leaves usable).
//!
//! A target passes when every call returns (`Ok` or `Err`): a panic is a bug. The bounded run
//! ([`run_bounded`], what `cargo test -p human2nav-fuzz` does) lets a panic fail the test; the
//! long run (the `human2nav-fuzz` binary) catches panics only to count and save them.

pub mod mutate;
pub mod targets;

pub use mutate::mutate;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;

/// A fuzz target: seeds and the call under test.
pub struct Target {
    /// Short name (`robot_toml`, `eth_obsmat`, ...).
    pub name: &'static str,
    /// What it feeds and to which reader.
    pub covers: &'static str,
    /// Seeds the inputs are mutated from.
    pub seeds: fn() -> Vec<Vec<u8>>,
    /// Feeds one input; must return (whatever it returns) for every input.
    pub exec: fn(&Scratch, &[u8]),
}

impl std::fmt::Debug for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Target").field("name", &self.name).finish()
    }
}

/// A per-target scratch directory for the temporary files readers need.
#[derive(Debug)]
pub struct Scratch {
    dir: PathBuf,
}

impl Scratch {
    /// A fresh directory under the system temp directory, unique to this process and target.
    pub fn new(target: &str) -> std::io::Result<Self> {
        let dir = std::env::temp_dir().join(format!(
            "human2nav-fuzz-{}-{target}-{}",
            std::process::id(),
            rand::random::<u32>()
        ));
        std::fs::create_dir_all(&dir)?;
        Ok(Self { dir })
    }

    /// The directory.
    pub fn dir(&self) -> &std::path::Path {
        &self.dir
    }

    /// Writes `bytes` to `name` inside the directory and returns its path.
    pub fn write(&self, name: &str, bytes: &[u8]) -> PathBuf {
        let p = self.dir.join(name);
        if let Some(parent) = p.parent() {
            let _ = std::fs::create_dir_all(parent);
        }
        if let Err(e) = std::fs::write(&p, bytes) {
            // The harness's own failure, not the reader's: stop loudly.
            panic!("fuzz harness cannot write {}: {e}", p.display());
        }
        p
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// One input for `target` drawn by `rng`: mostly a mutated seed, sometimes a seed as it is or
/// random bytes.
pub fn next_input(rng: &mut ChaCha8Rng, seeds: &[Vec<u8>]) -> Vec<u8> {
    let roll = rng.random_range(0..100);
    if seeds.is_empty() || roll < 2 {
        let n = rng.random_range(0..256);
        return (0..n).map(|_| rng.random()).collect();
    }
    let seed = &seeds[rng.random_range(0..seeds.len())];
    if roll < 5 {
        return seed.clone();
    }
    mutate(rng, seed, seeds)
}

/// Number of cases per target of the bounded run: `HUMAN2NAV_FUZZ_CASES`, default 256.
pub fn bounded_cases() -> u64 {
    std::env::var("HUMAN2NAV_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(256)
}

/// Seconds per target of the bounded run when `HUMAN2NAV_FUZZ_SECONDS` is set (then it runs
/// for that long with at least [`bounded_cases`] cases).
pub fn bounded_seconds() -> Option<f64> {
    std::env::var("HUMAN2NAV_FUZZ_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
}

/// Runs `target` on a fixed seed (deterministic: the same inputs every run) for
/// [`bounded_cases`] cases, or for [`bounded_seconds`]. A panic propagates (the test fails);
/// the failing input is printed in Rust escape form first. Returns the number of executions.
pub fn run_bounded(target: &Target) -> u64 {
    let scratch = Scratch::new(target.name).expect("temp directory");
    let seeds = (target.seeds)();
    let mut rng = ChaCha8Rng::seed_from_u64(0x6875_6d61_6e32_6e61 ^ fnv(target.name.as_bytes()));
    let cases = bounded_cases();
    let until = bounded_seconds()
        .map(|s| std::time::Instant::now() + std::time::Duration::from_secs_f64(s.max(0.0)));
    let mut n = 0u64;
    while n < cases || until.is_some_and(|t| std::time::Instant::now() < t) {
        let input = next_input(&mut rng, &seeds);
        let guard = Reporter {
            target: target.name,
            case: n,
            input: &input,
        };
        (target.exec)(&scratch, &input);
        std::mem::forget(guard);
        n += 1;
    }
    n
}

/// Prints the input of a case that panicked (its `Drop` runs only while unwinding).
struct Reporter<'a> {
    target: &'a str,
    case: u64,
    input: &'a [u8],
}

impl Drop for Reporter<'_> {
    fn drop(&mut self) {
        eprintln!(
            "fuzz target `{}` panicked on case {} with input (escaped):\n{}",
            self.target,
            self.case,
            self.input.escape_ascii()
        );
    }
}

/// FNV-1a of `bytes` (seeds and crash file names).
pub fn fnv(bytes: &[u8]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}
