//! Checks on output paths before anything is written.

use std::path::Path;

use anyhow::Result;

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
        _ => Ok(()),
    }
}
