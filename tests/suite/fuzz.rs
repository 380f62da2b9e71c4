//! The fuzz targets of every input format (`vkinverse::fuzz`) in the suite: a short run of
//! mutated seeds per target, and every regression file that a fuzzer once crashed on. The
//! long runs are `scripts/fuzz.sh`'s (libFuzzer, with coverage).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::time::{Duration, Instant};
use vkinverse::fuzz::{mutate, seeds, Fixture, Target};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `data` through `target`; a panic or an error of more than one line fails the test,
/// naming a file that holds the input.
fn check(fixture: &Fixture, target: Target, data: &[u8], label: &str) -> Duration {
    let start = Instant::now();
    let result = catch_unwind(AssertUnwindSafe(|| fixture.run(target, data)));
    let took = start.elapsed();
    let keep = || {
        let dir = repo().join("target/fuzz-failures");
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{}-{label}", target.name()));
        std::fs::write(&path, data).unwrap();
        path
    };
    match result {
        Err(_) => panic!("{} target panicked on {} (input kept)", target.name(), keep().display()),
        Ok(Err(message)) => {
            assert!(!message.is_empty() && !message.contains('\n'), "{} target: {:?} is not one line (input in {})", target.name(), message, keep().display())
        }
        Ok(Ok(())) => {}
    }
    took
}

/// Every file in `tests/data/fuzz/<target>/` (inputs that once crashed a parser) now ends
/// in a result or a one-line error.
#[test]
fn fuzz_regressions_end_in_a_result_or_a_one_line_error() {
    let fixture = Fixture::new(&repo()).unwrap();
    let mut replayed = 0;
    for target in Target::ALL {
        let dir = repo().join("tests/data/fuzz").join(target.name());
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for entry in entries {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            check(&fixture, target, &std::fs::read(&path).unwrap(), &name);
            replayed += 1;
        }
    }
    assert!(replayed >= 1, "no regression files under tests/data/fuzz");
}

/// Each target runs mutations of its seeds (the bundled and test files) for a few seconds:
/// no panic, every error one line, and no input takes more than 20 s (a hang).
#[test]
fn fuzz_targets_survive_mutated_seeds() {
    let fixture = Fixture::new(&repo()).unwrap();
    let per_target = Duration::from_secs(5);
    let mut report = Vec::new();
    for (t, target) in Target::ALL.into_iter().enumerate() {
        let seeds = seeds(&repo(), target).unwrap();
        assert!(!seeds.is_empty(), "no seed files for {}", target.name());
        let mut rng = 0x9e37_79b9_7f4a_7c15u64 ^ (t as u64 + 1);
        let start = Instant::now();
        let (mut runs, mut slowest) = (0u64, Duration::ZERO);
        // Every seed as it is first, then mutations.
        for (name, bytes) in &seeds {
            slowest = slowest.max(check(&fixture, target, bytes, name));
            runs += 1;
        }
        while start.elapsed() < per_target {
            let i = (rng % seeds.len() as u64) as usize;
            let j = ((rng >> 32) % seeds.len() as u64) as usize;
            let input = mutate(&seeds[i].1, &seeds[j].1, &mut rng);
            slowest = slowest.max(check(&fixture, target, &input, &format!("mutant{runs}")));
            runs += 1;
        }
        assert!(slowest < Duration::from_secs(20), "{}: an input took {slowest:?}", target.name());
        report.push(format!("{} {runs} runs, slowest {:.0} ms", target.name(), slowest.as_secs_f64() * 1e3));
    }
    eprintln!("fuzz: {}", report.join("; "));
}
