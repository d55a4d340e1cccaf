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
    let probe = partial_name(out);
    std::fs::File::create(&probe).with_context(|| format!("{flag} {}: cannot write there", out.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Writes `bytes` to `out` whole or not at all: into `out` + ".partial" beside it, then
/// renamed over `out`, so that a command stopped while writing leaves the earlier file
/// (a trained model, a fitted mixture) as it was, never an empty or cut one.
pub(crate) fn write_whole(out: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    let partial = partial_name(out);
    let written = std::fs::File::create(&partial).and_then(|mut f| {
        std::io::Write::write_all(&mut f, bytes.as_ref())?;
        f.sync_all()
    });
    if let Err(e) = written.and_then(|()| std::fs::rename(&partial, out)) {
        let _ = std::fs::remove_file(&partial);
        return Err(e).with_context(|| format!("{}: cannot write", out.display()));
    }
    Ok(())
}

fn partial_name(out: &Path) -> std::path::PathBuf {
    let mut name = out.as_os_str().to_owned();
    name.push(".partial");
    name.into()
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
        assert!(!partial_name(&file).exists(), "the probe and the partial file are gone");
        // Where it cannot be written, before and after a long job: named, nothing left.
        let nowhere = dir.join("missing").join("m.json");
        let e = writable_file("--out", &nowhere).unwrap_err().to_string();
        assert!(e.contains("--out") && e.contains("does not exist"), "{e}");
        let e = format!("{:#}", write_whole(&nowhere, "x").unwrap_err());
        assert!(e.contains("m.json: cannot write"), "{e}");
        assert!(!partial_name(&nowhere).exists());
        std::fs::remove_dir_all(&dir).ok();
    }
}
