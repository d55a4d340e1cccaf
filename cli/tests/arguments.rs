//! Bad command-line values get an error naming the flag and the value, never clap's
//! "unexpected argument" for a negative number or a run that starts anyway.

use std::process::Command;

fn stderr_of(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_objslam")).args(args).output().expect("objslam runs");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn negative_numbers_are_values_checked_like_any_other() {
    let out = std::env::temp_dir().join(format!("objslam-negative-{}", std::process::id()));
    let out = out.to_str().expect("a UTF-8 temporary path");
    for (args, expect) in [
        (
            vec!["record", "park", "--duration", "-5", "--out", out],
            "--duration must be a positive number of seconds, not -5",
        ),
        (vec!["train", "--dataset", out, "--out", out, "--threshold", "-1"], "--threshold must lie in [0, 1], got -1"),
        (vec!["run", "--seed", "-1"], "invalid value '-1' for '--seed <SEED>'"),
        (vec!["montecarlo", "laser_only", "--runs", "-3"], "invalid value '-3' for '--runs <RUNS>'"),
        (vec!["run", "--method", "bogus"], "invalid value 'bogus' for '--method <METHOD>'"),
        (vec!["montecarlo", "laser_only", "--methods", "nn, bogus", "--out", out], "unknown method \"bogus\""),
    ] {
        let (ok, err) = stderr_of(&args);
        assert!(!ok, "{args:?} succeeded");
        assert!(err.contains(expect), "{args:?}: {err}");
        assert!(!err.contains("unexpected argument"), "{args:?}: {err}");
    }
    assert!(!std::path::Path::new(out).exists(), "nothing was written");
}
