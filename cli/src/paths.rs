//! Checks on output paths before anything is written.

use std::path::Path;

use anyhow::{Context, Result};

/// Refuses an output `out` (given as `flag`) that is one of the command's `inputs` (what
/// each is, and its path): writing it would replace what the command reads with something
/// else, and the input would be lost.
pub(crate) fn not_an_input(flag: &str, out: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    match inputs.iter().find(|(_, input)| scenarios::partial_files::same_path(out, input)) {
        Some((what, input)) => anyhow::bail!(
            "{flag} {}: it is the {what} given ({}); writing it would replace the input: choose another path",
            out.display(),
            input.display()
        ),
        None => Ok(()),
    }
}

/// Refuses an output file `out` (given as `flag`) that is, or links to, a file in the
/// input directory `dir` (`what` it is): writing it would change the input.
pub(crate) fn not_inside(flag: &str, out: &Path, what: &str, dir: &Path) -> Result<()> {
    let (Ok(target), Ok(dir_abs)) = (out.canonicalize(), dir.canonicalize()) else { return Ok(()) };
    if target.starts_with(&dir_abs) {
        anyhow::bail!(
            "{flag} {}: {} is a file of the {what} given ({}); writing it would change the input: choose another path",
            out.display(),
            target.display(),
            dir.display()
        );
    }
    Ok(())
}

/// Refuses an output file `out` (given as `flag`) that cannot be written where it is: a
/// directory standing there, or a parent directory that does not exist. Checked before a
/// long job (training) rather than found when its result is saved.
pub(crate) fn writable_file(flag: &str, out: &Path) -> Result<()> {
    if out.is_dir() {
        anyhow::bail!("{flag} {}: is a directory; give the path of a file to write", out.display());
    }
    match out.parent().filter(|p| !p.as_os_str().is_empty()) {
        Some(parent) if !parent.is_dir() => {
            anyhow::bail!("{flag} {}: the directory {} does not exist", out.display(), parent.display())
        }
        _ => {}
    }
    // The file is written beside itself first (see `write_whole`): that must be possible.
    scenarios::partial_files::check_writable(out)
        .with_context(|| format!("{flag} {}: cannot write there", out.display()))
}

/// Writes `bytes` to `out` whole or not at all (see
/// [`scenarios::partial_files::write_whole`]): a command stopped while writing leaves the
/// earlier file (a trained model, a fitted mixture) as it was.
pub(crate) fn write_whole(out: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    scenarios::partial_files::write_whole(out, bytes.as_ref())
        .with_context(|| format!("{}: cannot write", out.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_is_written_whole_beside_itself_and_nothing_is_left_on_failure() {
        let dir = std::env::temp_dir().join(format!("objslam-write-whole-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("model.json");
        std::fs::write(&file, "earlier").unwrap();
        writable_file("--out", &file).unwrap();
        write_whole(&file, "new").unwrap();
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "new");
        assert!(!dir.join("model.json.partial").exists(), "the probe and the partial file are gone");
        // Where it cannot be written, before and after a long job: named, nothing left.
        let nowhere = dir.join("missing").join("m.json");
        let e = writable_file("--out", &nowhere).unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("does not exist"), "{e}");
        let e = format!("{:#}", write_whole(&nowhere, "x").unwrap_err());
        assert!(e.contains("m.json: cannot write"), "{e}");
        assert!(!dir.join("missing").exists());
        // A link keeps linking, to the file written; a device is written into, not replaced.
        #[cfg(unix)]
        {
            let link = dir.join("link.json");
            std::os::unix::fs::symlink(&file, &link).unwrap();
            writable_file("--out", &link).unwrap();
            write_whole(&link, "through the link").unwrap();
            assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
            assert_eq!(std::fs::read_to_string(&file).unwrap(), "through the link");
            let null = Path::new("/dev/null");
            writable_file("--out", null).unwrap();
            write_whole(null, "discarded").unwrap();
            assert!(!std::fs::metadata(null).unwrap().is_file(), "/dev/null is still a device");
        }
        std::fs::remove_dir_all(&dir).ok();
    }
}
