//! Running the built `vkinverse` binary from a test: with the validation layer on (and on
//! the test device, where `VKINVERSE_TEST_DEVICE` names one), within a deadline, and failing
//! the test on a panic or any validation message.

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Longest any one invocation may take before the test fails instead of hanging.
pub const DEADLINE: Duration = Duration::from_secs(120);

/// What the validation layer's messages start with on stderr.
pub const VALIDATION: &str = "vulkan validation:";

pub struct Output {
    pub code: Option<i32>,
    pub stdout: String,
    pub stderr: String,
    pub wall: Duration,
}

impl Output {
    pub fn ok(&self) -> bool {
        self.code == Some(0)
    }
}

/// Runs the binary with the validation layer on (and on the test device, where one is named)
/// and fails the test if it outlives [`DEADLINE`], panics, or the layer reports anything.
pub fn vkinverse<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    vkinverse_env(args, &[])
}

/// [`vkinverse`] with extra environment variables (the debug build's stopping points).
pub fn vkinverse_env<S: AsRef<std::ffi::OsStr>>(args: &[S], envs: &[(&str, &str)]) -> Output {
    vkinverse_during(args, envs, |_, _| {})
}

/// [`vkinverse_env`], calling `during` with the child's process id and its stderr so far
/// while it runs (every 20 ms).
pub fn vkinverse_during<S: AsRef<std::ffi::OsStr>>(args: &[S], envs: &[(&str, &str)], mut during: impl FnMut(u32, &str)) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_vkinverse"));
    cmd.args(args).env("VKINVERSE_VALIDATION", "1").envs(envs.iter().copied());
    if let Ok(device) = std::env::var("VKINVERSE_TEST_DEVICE") {
        cmd.args(["--device", &device]);
    }
    let start = Instant::now();
    let mut child = cmd.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("run vkinverse");
    // Drained on threads, as it comes, so that a chatty child never blocks on a full pipe.
    let drain = |mut r: Box<dyn Read + Send>| {
        let text = Arc::new(Mutex::new(String::new()));
        let into = Arc::clone(&text);
        let thread = std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            loop {
                match r.read(&mut buf).expect("read child output") {
                    0 => break,
                    n => into.lock().unwrap().push_str(&String::from_utf8_lossy(&buf[..n])),
                }
            }
        });
        (text, thread)
    };
    let (out, out_thread) = drain(Box::new(child.stdout.take().unwrap()));
    let (err, err_thread) = drain(Box::new(child.stderr.take().unwrap()));
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > DEADLINE {
            let _ = child.kill();
            let _ = child.wait();
            panic!("vkinverse {:?} still running after {DEADLINE:?}", cmd.get_args().collect::<Vec<_>>());
        }
        let so_far = err.lock().unwrap().clone();
        during(child.id(), &so_far);
        std::thread::sleep(Duration::from_millis(20));
    };
    out_thread.join().unwrap();
    err_thread.join().unwrap();
    let text = |t: Arc<Mutex<String>>| std::mem::take(&mut *t.lock().unwrap());
    let output = Output { code: status.code(), stdout: text(out), stderr: text(err), wall: start.elapsed() };
    let args: Vec<_> = cmd.get_args().collect();
    assert!(!output.stderr.contains(VALIDATION), "{args:?}: validation messages:\n{}", output.stderr);
    assert!(!output.stderr.contains("panicked"), "{args:?}: panic:\n{}", output.stderr);
    output
}

/// Runs and requires exit status 0.
pub fn vkinverse_ok<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    let out = vkinverse(args);
    let shown: Vec<_> = args.iter().map(|a| a.as_ref().to_string_lossy().into_owned()).collect();
    assert!(out.ok(), "vkinverse {shown:?} failed ({:?}):\n{}", out.code, out.stderr);
    out
}

/// Runs, requires a non-zero exit and stderr of exactly one `vkinverse: error:` line that
/// contains every needle; returns that line.
pub fn vkinverse_err<S: AsRef<std::ffi::OsStr>>(args: &[S], needles: &[&str]) -> String {
    vkinverse_err_env(args, &[], needles)
}

/// [`vkinverse_err`] with extra environment variables.
pub fn vkinverse_err_env<S: AsRef<std::ffi::OsStr>>(args: &[S], envs: &[(&str, &str)], needles: &[&str]) -> String {
    let out = vkinverse_env(args, envs);
    let shown: Vec<_> = args.iter().map(|a| a.as_ref().to_string_lossy().into_owned()).collect();
    assert!(!out.ok() && out.code.is_some(), "vkinverse {shown:?} should fail, exited {:?}", out.code);
    let lines: Vec<&str> = out.stderr.lines().collect();
    assert!(lines.len() == 1 && lines[0].starts_with("vkinverse: error: "), "{shown:?}: stderr is not one error line:\n{}", out.stderr);
    for needle in needles {
        assert!(lines[0].contains(needle), "{shown:?}: {:?} lacks {needle:?}", lines[0]);
    }
    lines[0].to_string()
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// A JSON file's value.
pub fn json(path: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}
