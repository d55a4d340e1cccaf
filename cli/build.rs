//! Tells the binary which commit it is built from (`OBJSLAM_COMMIT`, and
//! `OBJSLAM_MODIFIED` when the workspace's sources differ from it), for the metadata of
//! every output. Outside a git checkout (a source archive) neither is set.

use std::path::Path;
use std::process::Command;

/// What the binary is built from: a change in any of these makes another binary.
const SOURCES: &[&str] = &[
    "Cargo.toml",
    "Cargo.lock",
    "toml_strict",
    "worlds",
    "render",
    "sim",
    "slam",
    "ros2bag",
    "robotlog",
    "scenarios",
    "cli",
];

fn git(root: &Path, args: &[&str]) -> Option<String> {
    // Without optional locks, `git status` does not rewrite the index it watches below.
    let out = Command::new("git").arg("--no-optional-locks").arg("-C").arg(root).args(args).output().ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    let Ok(manifest_dir) = std::env::var("CARGO_MANIFEST_DIR") else { return };
    let root = Path::new(&manifest_dir).join("..");
    // Run again when a source changes (directories are scanned whole) or HEAD moves.
    for s in SOURCES {
        println!("cargo:rerun-if-changed={}", root.join(s).display());
    }
    let Some(git_dir) = git(&root, &["rev-parse", "--absolute-git-dir"]) else { return };
    for f in ["HEAD", "index", "packed-refs"] {
        println!("cargo:rerun-if-changed={}", Path::new(&git_dir).join(f).display());
    }
    if let Some(head) = git(&root, &["symbolic-ref", "-q", "HEAD"]) {
        println!("cargo:rerun-if-changed={}", Path::new(&git_dir).join(head).display());
    }
    let Some(commit) = git(&root, &["rev-parse", "HEAD"]) else { return };
    println!("cargo:rustc-env=OBJSLAM_COMMIT={commit}");
    let mut status = vec!["status", "--porcelain", "--untracked-files=no", "--"];
    status.extend(SOURCES);
    let modified = git(&root, &status).is_none_or(|s| !s.is_empty());
    println!("cargo:rustc-env=OBJSLAM_MODIFIED={modified}");
}
