//! Output files written line by line as a run or a replay goes, so that their size costs
//! no memory. Each is written under a `.partial` name and renamed when the run has
//! finished, so that a run that fails on the way leaves no half-written file (its partial
//! files are removed). A run or replay writes these, and its other outputs, in the output
//! directory's unfinished directory ([`start_unfinished`]) and moves them all into place
//! only when every one was written ([`publish`]): one stopped or failing on the way leaves
//! the directory's earlier outputs whole, and one stopped while moving them in leaves a
//! directory without its marker file (`metadata.json`), never a mix of two outputs that
//! reads as one.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// An I/O error on one of the files.
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", file.display())]
pub struct PartialFileError {
    pub file: PathBuf,
    #[source]
    pub source: std::io::Error,
}

/// Streamed output files, each known by a key `K` (an enum of the output's streams).
pub struct PartialFiles<K> {
    /// Key, final file, the `.partial` file written, and its writer.
    files: Vec<(K, PathBuf, PathBuf, BufWriter<File>)>,
}

fn error(file: &Path) -> impl FnOnce(std::io::Error) -> PartialFileError + '_ {
    move |source| PartialFileError { file: file.to_path_buf(), source }
}

impl<K: Copy + PartialEq> PartialFiles<K> {
    /// Opens `streams` (key, final file name) in `dir`, which is made if need be.
    pub fn create(dir: &Path, streams: &[(K, &str)]) -> Result<Self, PartialFileError> {
        std::fs::create_dir_all(dir).map_err(error(dir))?;
        let mut files = PartialFiles { files: Vec::new() };
        for (key, name) in streams {
            let partial = partial_name(&dir.join(name));
            let f = File::create(&partial).map_err(error(&partial))?;
            files.files.push((*key, dir.join(name), partial, BufWriter::new(f)));
        }
        Ok(files)
    }

    /// Appends `text` (whole lines) to the stream `key`; a stream that was not opened (one
    /// this output does not have) takes nothing.
    pub fn write(&mut self, key: K, text: &str) -> Result<(), PartialFileError> {
        match self.files.iter_mut().find(|(k, _, _, _)| *k == key) {
            Some((_, _, partial, w)) => w.write_all(text.as_bytes()).map_err(error(partial)),
            None => Ok(()),
        }
    }

    /// Flushes every stream to disk, then gives each its final name. Should a flush fail,
    /// no stream is renamed and the partial files are removed.
    pub fn finish(mut self) -> Result<(), PartialFileError> {
        for (_, _, partial, w) in &mut self.files {
            w.flush().map_err(error(partial))?;
            w.get_ref().sync_all().map_err(error(partial))?;
        }
        while let Some((_, done, partial, w)) = self.files.pop() {
            drop(w);
            if let Err(source) = std::fs::rename(&partial, &done) {
                let _ = std::fs::remove_file(&partial);
                return Err(PartialFileError { file: done, source });
            }
        }
        Ok(())
    }
}

impl<K> Drop for PartialFiles<K> {
    /// The streams not renamed (a run that failed): removed.
    fn drop(&mut self) {
        for (_, _, partial, _) in &self.files {
            let _ = std::fs::remove_file(partial);
        }
    }
}

/// An output directory held by this process: while it lives, no other objslam command can
/// hold the same directory, so two commands given one `--out` cannot mix their outputs in
/// its unfinished directory. The operating system releases the hold when the process ends,
/// however it ends, so a killed command leaves nothing to clear away.
#[derive(Debug)]
pub struct OutputLock {
    _held: File,
    /// The directories taking the hold made: the output directory and those of its parents
    /// that were missing, deepest first.
    made: Vec<PathBuf>,
}

impl OutputLock {
    /// Ends the hold of a command that failed: a directory the hold made goes again if the
    /// command left it empty, so that a refused command leaves nothing behind.
    pub fn release_failed(self) {
        // Deepest first; one that is not empty stops the rest.
        for dir in &self.made {
            if std::fs::remove_dir(dir).is_err() {
                break;
            }
        }
    }
}

/// Makes `out` if need be and holds it (see [`OutputLock`]); fails at once, naming `out`,
/// where another command holds it.
pub fn lock_output(out: &Path) -> Result<OutputLock, PartialFileError> {
    let made: Vec<PathBuf> = out
        .ancestors()
        .take_while(|d| !d.as_os_str().is_empty() && d.symlink_metadata().is_err())
        .map(Path::to_path_buf)
        .collect();
    make_output_dir(out)?;
    let held = open_lock(out).map_err(error(out))?;
    match held.try_lock() {
        Ok(()) => Ok(OutputLock { _held: held, made }),
        Err(std::fs::TryLockError::WouldBlock) => Err(PartialFileError {
            file: out.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::ResourceBusy,
                "another objslam command is writing into this directory; wait for it to end or choose another",
            ),
        }),
        Err(std::fs::TryLockError::Error(e)) => Err(error(out)(e)),
    }
}

/// Makes the output directory `out` (and its parents) if need be; where it cannot, says
/// what stands in the way (see [`not_a_directory`]).
pub fn make_output_dir(out: &Path) -> Result<(), PartialFileError> {
    std::fs::create_dir_all(out).map_err(|e| not_a_directory(out, e))
}

/// Why `out` could not be made a directory, in the user's terms: what stands in its way
/// (a file, a link to nothing, a file among its parents), else the system's reason.
fn not_a_directory(out: &Path, source: std::io::Error) -> PartialFileError {
    let said = |message: String| PartialFileError {
        file: out.to_path_buf(),
        source: std::io::Error::new(source.kind(), message),
    };
    if let Ok(target) = std::fs::read_link(out)
        && !out.exists()
    {
        return said(format!(
            "is a link to {}, which does not exist; give a directory for the outputs",
            target.display()
        ));
    }
    if out.is_file() {
        return said("is a file, not a directory; give a directory for the outputs".into());
    }
    // A device, a pipe or a socket (`/dev/null`).
    if std::fs::metadata(out).is_ok_and(|m| !m.is_dir()) {
        return said("is not a directory (a device or a pipe); give a directory for the outputs".into());
    }
    if let Some(file) = out.ancestors().skip(1).find(|a| a.is_file()) {
        return said(format!("{} is a file, so no directory can be made inside it", file.display()));
    }
    said(format!("cannot make the output directory: {source}"))
}

/// The file whose lock stands for `out`'s: the directory itself where the system can lock
/// one (nothing is added to it), a hidden file in it elsewhere.
#[cfg(unix)]
fn open_lock(out: &Path) -> std::io::Result<File> {
    File::open(out)
}

#[cfg(not(unix))]
fn open_lock(out: &Path) -> std::io::Result<File> {
    std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(out.join(".objslam.lock"))
}

/// Whether two paths name the same place, however each is spelled (made absolute, links,
/// `.` and `..` resolved where they exist): an output that is an input, a bag that is the
/// run's output directory.
pub fn same_path(a: &Path, b: &Path) -> bool {
    resolved(a) == resolved(b)
}

/// Whether `inner` lies inside the directory `outer` (not at it), however each is spelled
/// and whether or not they exist yet (see [`same_path`]).
pub fn lies_inside(inner: &Path, outer: &Path) -> bool {
    let (inner, outer) = (resolved(inner), resolved(outer));
    inner != outer && inner.starts_with(&outer)
}

/// `p` made absolute, with links, `.` and `..` resolved in the part that exists and `.`
/// and `..` in the rest.
fn resolved(p: &Path) -> PathBuf {
    use std::path::Component;
    let Ok(absolute) = std::path::absolute(p) else { return p.to_path_buf() };
    // The longest existing ancestor, resolved; then the rest, one name at a time.
    let mut existing = absolute.as_path();
    let mut rest = Vec::new();
    while existing.canonicalize().is_err() {
        match (existing.parent(), existing.components().next_back()) {
            (Some(parent), Some(last)) => {
                rest.push(last);
                existing = parent;
            }
            _ => return absolute.clone(),
        }
    }
    let mut out = existing.canonicalize().unwrap_or_else(|_| existing.to_path_buf());
    for c in rest.into_iter().rev() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other.as_os_str()),
        }
    }
    out
}

/// Where outputs into `out` wait until all of them are written.
pub fn unfinished_dir(out: &Path) -> PathBuf {
    out.join(".unfinished")
}

/// The kinds of outputs whose move into a directory can be stopped with their marker still
/// waiting in its unfinished directory, each named by the command that writes them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoppedMove {
    /// `dataset.json`: `objslam dataset`.
    Dataset,
    /// `metadata.json` of `objslam record`, or a robot log's `manifest.toml`.
    Recording,
    /// `metadata.yaml`: a ROS 2 bag (`objslam record --format ros2`, `objslam run --bag`).
    Bag,
    /// `metadata.json` of `objslam run`.
    Run,
}

impl StoppedMove {
    /// The command to run into the directory again to finish it.
    pub fn command(self) -> &'static str {
        match self {
            StoppedMove::Dataset => "objslam dataset",
            StoppedMove::Recording => "objslam record",
            StoppedMove::Bag => "objslam record --format ros2",
            StoppedMove::Run => "objslam run",
        }
    }
}

/// Which command's outputs wait, finished, in `out`'s unfinished directory (their marker,
/// moved last, is there): a move into `out` stopped midway. `None` where none do (nothing
/// there, or a command stopped while still writing, whose files are only a draft).
pub fn stopped_move(out: &Path) -> Option<StoppedMove> {
    let dir = unfinished_dir(out);
    let json =
        |name: &str| -> Option<serde_json::Value> { serde_json::from_slice(&std::fs::read(dir.join(name)).ok()?).ok() };
    if json("dataset.json").is_some() {
        return Some(StoppedMove::Dataset);
    }
    if dir.join("metadata.yaml").is_file() {
        return Some(StoppedMove::Bag);
    }
    match json(crate::files::METADATA).as_ref().and_then(|m| m["tool"].as_str().map(str::to_owned)).as_deref() {
        Some("objslam record") => return Some(StoppedMove::Recording),
        // A run writes its marker among its other files, so only the list a move writes
        // before it moves anything tells finished outputs from a draft.
        Some("objslam run") => return read_moving(&dir).is_some().then_some(StoppedMove::Run),
        _ => {}
    }
    let manifest = std::fs::read_to_string(dir.join(robotlog::format::MANIFEST)).ok()?;
    toml::from_str::<robotlog::Manifest>(&manifest).is_ok().then_some(StoppedMove::Recording)
}

/// Refuses to start `out`'s unfinished directory anew where another command's finished
/// outputs wait there to be moved in (`own`: the kinds the caller finishes itself): they
/// would be lost.
pub fn check_no_other_stopped_move(out: &Path, own: &[StoppedMove]) -> Result<(), PartialFileError> {
    let dir = unfinished_dir(out);
    let remedy = |kind: StoppedMove| match kind {
        // A bag is never written over, so no command finishes one: the user does.
        StoppedMove::Bag => format!(
            "move its metadata.yaml into {} to finish that bag (a bag is not replaced: record into another directory)",
            out.display()
        ),
        _ => format!("run `{}` into {} again to finish the move", kind.command(), out.display()),
    };
    match stopped_move(out) {
        Some(kind) if !own.contains(&kind) => Err(PartialFileError {
            file: dir.clone(),
            source: std::io::Error::other(format!(
                "holds finished outputs stopped while they were moved into {}: {}, or remove {} to drop them",
                out.display(),
                remedy(kind),
                dir.display()
            )),
        }),
        _ => Ok(()),
    }
}

/// Makes `out`'s unfinished directory anew (one stopped on the way may have left one) and
/// returns it. The caller holds `out` ([`lock_output`]) until it has published or abandoned
/// what it wrote there.
pub fn start_unfinished(out: &Path) -> Result<PathBuf, PartialFileError> {
    let dir = unfinished_dir(out);
    // Named by the directory the user gave: the unfinished one is ours.
    let cannot = |e: std::io::Error| PartialFileError {
        file: out.to_path_buf(),
        source: std::io::Error::new(e.kind(), format!("cannot write into the directory: {e}")),
    };
    // A file where the unfinished directory goes is named: nothing else would say what is
    // in the way.
    if dir.symlink_metadata().is_ok_and(|m| !m.is_dir()) {
        return Err(PartialFileError {
            file: dir.clone(),
            source: std::io::Error::other("a file or link stands where unfinished outputs are written: remove it"),
        });
    }
    match std::fs::remove_dir_all(&dir) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(cannot(e)),
        _ => {}
    }
    std::fs::create_dir_all(&dir).map_err(cannot)?;
    Ok(dir)
}

/// Holds `out`, runs `check` (under the hold, before the unfinished directory is started
/// anew: a command refused there, an `out` that is not its own, leaves another command's
/// unfinished outputs as they were), then `write` on its fresh unfinished directory. On
/// success the hold is returned with what `write` gave, for the caller to publish under; on
/// failure what was written is removed and the hold released (a directory the hold made
/// goes again).
pub fn write_unfinished<T, E: From<PartialFileError>>(
    out: &Path,
    check: impl FnOnce() -> Result<(), E>,
    write: impl FnOnce(&Path) -> Result<T, E>,
) -> Result<(T, OutputLock), E> {
    let lock = lock_output(out)?;
    if let Err(e) = check() {
        lock.release_failed();
        return Err(e);
    }
    match start_unfinished(out).map_err(E::from).and_then(|dir| write(&dir)) {
        Ok(value) => Ok((value, lock)),
        Err(e) => {
            let _ = std::fs::remove_dir_all(unfinished_dir(out));
            lock.release_failed();
            Err(e)
        }
    }
}

/// Passes `result` on, ending the hold `lock` on `out`; where it is a failure, removes
/// `out`'s unfinished directory if the failure left it empty (one holding outputs is kept),
/// and `out` itself where the hold made it and it is empty, so a failed command leaves no
/// empty directory behind.
pub fn abandon_if_failed<T, E>(lock: Option<OutputLock>, out: Option<&Path>, result: Result<T, E>) -> Result<T, E> {
    if let (Err(_), Some(out)) = (&result, out) {
        let _ = std::fs::remove_dir(unfinished_dir(out));
        if let Some(lock) = lock {
            lock.release_failed();
        }
    }
    result
}

/// Writes `bytes` to `file` whole or not at all: into `file` + ".partial" beside it, then
/// renamed over it, so that a command stopped while writing leaves the earlier file as it
/// was, never an empty or cut one. A link is followed (the file it names is replaced, the
/// link kept), and a device or pipe (`/dev/null`) is written into as it is, not replaced.
pub fn write_whole(file: &Path, bytes: &[u8]) -> Result<(), PartialFileError> {
    let target = std::fs::canonicalize(file).unwrap_or_else(|_| file.to_path_buf());
    if std::fs::metadata(&target).is_ok_and(|m| !m.is_file()) {
        return std::fs::write(file, bytes).map_err(error(file));
    }
    let partial = partial_name(&target);
    let written = File::create(&partial).and_then(|mut f| {
        f.write_all(bytes)?;
        f.sync_all()
    });
    written.and_then(|()| std::fs::rename(&partial, &target)).map_err(|source| {
        let _ = std::fs::remove_file(&partial);
        PartialFileError { file: file.to_path_buf(), source }
    })
}

/// Whether [`write_whole`] could write `file`: the file it would write beside it can be
/// made (checked before a long job rather than found when its result is saved).
pub fn check_writable(file: &Path) -> Result<(), PartialFileError> {
    let target = std::fs::canonicalize(file).unwrap_or_else(|_| file.to_path_buf());
    if std::fs::metadata(&target).is_ok_and(|m| !m.is_file()) {
        return Ok(());
    }
    let probe = partial_name(&target);
    File::create(&probe).map_err(error(file))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// `file` + ".partial": where a file is written before it takes its name.
fn partial_name(file: &Path) -> PathBuf {
    let mut name = file.as_os_str().to_owned();
    name.push(".partial");
    name.into()
}

/// The file in an unfinished directory naming what a move into the output directory brings
/// in, while it runs.
const MOVING: &str = ".moving.json";
/// Where [`write_whole`] writes [`MOVING`] before it takes its name.
const MOVING_PARTIAL: &str = ".moving.json.partial";

/// The names a stopped move was bringing in (its [`MOVING`] file), if it began.
fn read_moving(unfinished: &Path) -> Option<Vec<String>> {
    serde_json::from_slice(&std::fs::read(unfinished.join(MOVING)).ok()?).ok()
}

/// Finishes a move into `out` that was stopped (its marker still in `unfinished`), as
/// [`publish`] would have: where it had begun, the earlier outputs' `stale` names it does
/// not bring in are removed (a stop while they were being removed left some), and nothing
/// it moved in already; where it had not, it is published whole.
pub fn finish_publish(
    unfinished: &Path,
    out: &Path,
    stale: &[&str],
    marker: &str,
) -> Result<(), Vec<PartialFileError>> {
    let Some(bringing) = read_moving(unfinished) else { return publish(unfinished, out, stale, marker) };
    let left: Vec<&str> = stale.iter().copied().filter(|s| !bringing.iter().any(|b| b == s)).collect();
    publish(unfinished, out, &left, marker)
}

/// Moves finished outputs from `unfinished` into `out`, each replacing the file (or
/// directory) of the same name, after removing the `stale` names (outputs an earlier one
/// may hold that this one does not write). `marker` is the file that makes `out` read as
/// a finished output (a run's `metadata.json`, a bag's `metadata.yaml`): the earlier one
/// is removed before anything else and the new one moved in last, so that a publish
/// stopped midway (a kill) leaves a directory without it, never a mix of two outputs
/// that reads as one. A directory standing where a file goes is refused before anything
/// is moved or removed; past that, a file that cannot be moved stops no other (but the
/// marker, which then stays out). Every failure is returned, and what was not moved
/// stays in `unfinished`.
pub fn publish(unfinished: &Path, out: &Path, stale: &[&str], marker: &str) -> Result<(), Vec<PartialFileError>> {
    fn one(file: &Path) -> impl FnOnce(std::io::Error) -> Vec<PartialFileError> + '_ {
        move |source| vec![PartialFileError { file: file.to_path_buf(), source }]
    }
    let mut entries = Vec::new();
    for entry in std::fs::read_dir(unfinished).map_err(one(unfinished))? {
        let entry = entry.map_err(one(unfinished))?;
        // The list of names, and a copy of it cut short by a stop while it was written.
        let name = entry.file_name();
        if name != MOVING && name != MOVING_PARTIAL {
            entries.push((entry.path(), out.join(name)));
        }
    }
    // The marker last.
    entries.sort_by_key(|(from, _)| from.file_name().is_some_and(|n| n == marker));
    // A directory where a file goes is found before anything moves, so that the outputs
    // stay all old rather than half new.
    let blocked: Vec<PartialFileError> = entries
        .iter()
        .filter_map(|(from, to)| {
            let what = match (from.is_dir(), to.is_dir()) {
                (false, true) => "a directory stands where the file goes",
                (true, false) if std::fs::symlink_metadata(to).is_ok() => "a file stands where the directory goes",
                _ => return None,
            };
            Some(PartialFileError {
                file: to.clone(),
                source: std::io::Error::other(format!(
                    "{what} (the new outputs are kept in {}, and none was moved)",
                    unfinished.display()
                )),
            })
        })
        .collect();
    if !blocked.is_empty() {
        return Err(blocked);
    }
    // Which names this move brings in, kept beside them until it ends: a move stopped
    // while the earlier outputs were removed is finished from it (see [`finish_publish`]).
    // A move that is itself a finish writes it again with the names still to move; the
    // names moved already stay in the first list.
    let journal = unfinished.join(MOVING);
    let mut names: Vec<String> = read_moving(unfinished).unwrap_or_default();
    for (from, _) in &entries {
        let name = from.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if !names.contains(&name) {
            names.push(name);
        }
    }
    // Whole or not at all: a list cut short would read as no list.
    write_whole(&journal, serde_json::to_string(&names).expect("names are JSON").as_bytes()).map_err(|e| vec![e])?;
    // What this removes of the earlier outputs, for the words of a failure below.
    let mut removed_names = Vec::new();
    for name in std::iter::once(&marker).chain(stale) {
        let path = out.join(name);
        let removed = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        match removed {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(one(&path)(e)),
            Err(_) => {}
            Ok(()) => removed_names.push(*name),
        }
    }
    let mut errors: Vec<PartialFileError> = Vec::new();
    let mut moved_count = 0;
    for (from, to) in entries {
        if !errors.is_empty() && from.file_name().is_some_and(|n| n == marker) {
            break;
        }
        let moved = if to.is_dir() {
            std::fs::remove_dir_all(&to).and_then(|()| std::fs::rename(&from, &to))
        } else {
            std::fs::rename(&from, &to)
        };
        match moved {
            Ok(()) => moved_count += 1,
            Err(source) => errors.push(PartialFileError { file: to, source }),
        }
    }
    // Said once, on the first failure: what of the earlier outputs is gone, what of the new
    // is in, and where the rest waits.
    if let Some(first) = errors.first_mut() {
        let gone = if removed_names.is_empty() {
            String::new()
        } else {
            format!("the earlier outputs' {} removed; ", removed_names.join(", "))
        };
        first.source = std::io::Error::new(
            first.source.kind(),
            format!(
                "{} (while moving the new outputs in: {gone}{moved_count} new moved in; the rest, {marker} among them, wait in {}: move them into {} to finish)",
                first.source,
                unfinished.display(),
                out.display()
            ),
        );
    }
    if errors.is_empty() {
        std::fs::remove_file(&journal).map_err(one(&journal))?;
        let _ = std::fs::remove_file(unfinished.join(MOVING_PARTIAL));
        std::fs::remove_dir(unfinished).map_err(one(unfinished))?;
        return Ok(());
    }
    Err(errors)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A move stopped while the earlier outputs were removed leaves some of them; one
    /// stopped while moving has moved some new files in. Finishing either removes the
    /// earlier outputs' leftovers the move does not bring in, and keeps what it moved.
    #[test]
    fn a_stopped_move_is_finished_from_its_list_of_names() {
        let out = std::env::temp_dir().join(format!("objslam-finish-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let dir = unfinished_dir(&out);
        std::fs::create_dir_all(&dir).unwrap();
        let stale = ["marker", "old_only", "shared", "new_only"];
        // Stopped while removing: the earlier marker gone, its other files still there.
        for name in ["old_only", "shared"] {
            std::fs::write(out.join(name), "old").unwrap();
        }
        for name in ["marker", "shared", "new_only"] {
            std::fs::write(dir.join(name), "new").unwrap();
        }
        std::fs::write(dir.join(MOVING), r#"["shared","new_only","marker"]"#).unwrap();
        finish_publish(&dir, &out, &stale, "marker").unwrap();
        assert!(!out.join("old_only").exists(), "the earlier output's leftover is removed");
        for name in ["marker", "shared", "new_only"] {
            assert_eq!(std::fs::read_to_string(out.join(name)).unwrap(), "new", "{name}");
        }
        assert!(!dir.exists());
        // Stopped while moving: what it moved stays.
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::remove_file(out.join("marker")).unwrap();
        std::fs::write(dir.join("marker"), "newer").unwrap();
        std::fs::write(dir.join(MOVING), r#"["shared","new_only","marker"]"#).unwrap();
        finish_publish(&dir, &out, &stale, "marker").unwrap();
        assert_eq!(std::fs::read_to_string(out.join("new_only")).unwrap(), "new", "moved already, kept");
        assert_eq!(std::fs::read_to_string(out.join("marker")).unwrap(), "newer");
        // Stopped before it began: published whole, the stale names removed.
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::remove_file(out.join("marker")).unwrap();
        std::fs::write(out.join("old_only"), "old").unwrap();
        std::fs::write(dir.join("marker"), "m").unwrap();
        // A list cut short while written (a stop then) is no list, and is not moved in.
        std::fs::write(dir.join(MOVING_PARTIAL), "[\"sha").unwrap();
        finish_publish(&dir, &out, &stale, "marker").unwrap();
        assert!(!out.join("old_only").exists() && !out.join("new_only").exists() && out.join("marker").is_file());
        assert!(!out.join(MOVING_PARTIAL).exists() && !dir.exists());
        let _ = std::fs::remove_dir_all(&out);
    }

    /// Each command's marker waiting in the unfinished directory names its stopped move; a
    /// draft (a marker cut short) names none; a command refuses another's, not its own.
    #[test]
    fn stopped_moves_are_told_apart_and_kept_from_other_commands() {
        let out = std::env::temp_dir().join(format!("objslam-stopped-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let dir = unfinished_dir(&out);
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(stopped_move(&out), None);
        for (name, text, kind) in [
            ("dataset.json", "{}", Some(StoppedMove::Dataset)),
            ("metadata.yaml", "rosbag2_bagfile_information: {}", Some(StoppedMove::Bag)),
            ("metadata.json", r#"{"tool": "objslam record"}"#, Some(StoppedMove::Recording)),
            // A run's marker is finished outputs only once a move has begun (its list there).
            ("metadata.json", r#"{"tool": "objslam run"}"#, None),
            (MOVING, r#"["metadata.json"]"#, None),
            ("metadata.json", r#"{"tool": "objslam rec"#, None),
            ("manifest.toml", "", None),
        ] {
            std::fs::write(dir.join(name), text).unwrap();
            assert_eq!(stopped_move(&out), kind, "{name}: {text}");
            if let Some(kind) = kind {
                check_no_other_stopped_move(&out, &[kind]).unwrap();
                let e = check_no_other_stopped_move(&out, &[]).unwrap_err().to_string();
                assert!(e.contains("stopped while they were moved"), "{e}");
                assert_eq!(kind == StoppedMove::Bag, e.contains("move its metadata.yaml"), "{e}");
            }
            std::fs::remove_file(dir.join(name)).unwrap();
        }
        std::fs::write(dir.join("metadata.json"), r#"{"tool": "objslam run"}"#).unwrap();
        std::fs::write(dir.join(MOVING), r#"["metadata.json"]"#).unwrap();
        assert_eq!(stopped_move(&out), Some(StoppedMove::Run));
        let _ = std::fs::remove_dir_all(&out);
    }

    /// A device given as the output directory is named for what it is (it had read "File
    /// exists").
    #[test]
    fn a_device_is_no_output_directory() {
        let e = make_output_dir(Path::new("/dev/null")).unwrap_err().to_string();
        assert!(e.contains("/dev/null") && e.contains("is not a directory (a device or a pipe)"), "{e}");
    }

    #[test]
    fn an_output_directory_is_held_by_one_command_at_a_time() {
        let dir = std::env::temp_dir().join(format!("objslam-lock-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let held = lock_output(&dir).unwrap();
        assert!(dir.is_dir(), "made if need be");
        let e = lock_output(&dir).unwrap_err();
        assert_eq!(e.file, dir);
        assert!(e.to_string().contains("another objslam command"), "{e}");
        drop(held);
        let again = lock_output(&dir).unwrap();
        drop(again);
        // What stands where the directory would go is named, not the system's "File exists".
        let file = dir.join("a-file");
        std::fs::write(&file, "").unwrap();
        let e = lock_output(&file).unwrap_err().to_string();
        assert!(e.contains("a-file: is a file, not a directory"), "{e}");
        let e = lock_output(&file.join("sub")).unwrap_err().to_string();
        assert!(e.contains("a-file is a file, so no directory can be made inside it"), "{e}");
        #[cfg(unix)]
        {
            let link = dir.join("link");
            std::os::unix::fs::symlink(dir.join("nowhere"), &link).unwrap();
            let e = lock_output(&link).unwrap_err().to_string();
            assert!(e.contains("is a link to") && e.contains("nowhere, which does not exist"), "{e}");
        }
        // A failed command removes the directories its hold made, parents too, and no more.
        let nested = dir.join("new").join("deeper").join("out");
        lock_output(&nested).unwrap().release_failed();
        assert!(!dir.join("new").exists() && dir.is_dir());
        std::fs::create_dir_all(dir.join("new")).unwrap();
        std::fs::write(dir.join("new").join("kept"), "").unwrap();
        let held = lock_output(&nested).unwrap();
        std::fs::write(nested.join("written"), "").unwrap();
        held.release_failed();
        assert!(nested.join("written").exists(), "a directory that is not empty stays");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn paths_inside_others_are_found_however_spelled() {
        let dir = std::env::temp_dir().join(format!("objslam-inside-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("bag")).unwrap();
        assert!(lies_inside(&dir.join("bag/run"), &dir.join("bag")), "not there yet");
        assert!(lies_inside(&dir.join("x/../bag/./run/more"), &dir.join("bag/")));
        assert!(!lies_inside(&dir.join("bag"), &dir.join("bag")));
        assert!(!lies_inside(&dir.join("bagged"), &dir.join("bag")));
        assert!(!lies_inside(&dir.join("bag"), &dir.join("bag/run")));
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(dir.join("bag"), dir.join("link")).unwrap();
            assert!(lies_inside(&dir.join("link/run"), &dir.join("bag")));
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A file where the unfinished directory goes is named, not the output directory.
    #[test]
    fn a_file_in_the_unfinished_directorys_place_is_named() {
        let dir = std::env::temp_dir().join(format!("objslam-unfinished-file-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(unfinished_dir(&dir), "mine").unwrap();
        let e = start_unfinished(&dir).unwrap_err().to_string();
        assert!(e.contains(".unfinished") && e.contains("a file or link stands where"), "{e}");
        assert_eq!(std::fs::read_to_string(unfinished_dir(&dir)).unwrap(), "mine", "left as it was");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Regression: a run killed while its outputs were moved in left some files of each
    /// run under an earlier run's `metadata.json`. The marker now goes first and comes
    /// last: a publish that stops midway leaves none.
    #[test]
    fn the_marker_goes_first_and_comes_last() {
        let dir = std::env::temp_dir().join(format!("objslam-publish-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let unfinished = unfinished_dir(&dir);
        std::fs::create_dir_all(&unfinished).unwrap();
        for (name, text) in
            [("metadata.json", "old"), ("a.json", "old"), ("b", "a file, where the new b is a directory")]
        {
            std::fs::write(dir.join(name), text).unwrap();
        }
        std::fs::write(unfinished.join("metadata.json"), "new").unwrap();
        std::fs::write(unfinished.join("a.json"), "new").unwrap();
        std::fs::create_dir(unfinished.join("b")).unwrap();
        // b cannot replace the file: found before anything moves, so the earlier output
        // stays whole, its marker with it (an output dataset's folder where the user keeps
        // a file had published half the new dataset over the old).
        let errors = publish(&unfinished, &dir, &[], "metadata.json").unwrap_err();
        assert_eq!(errors.len(), 1);
        assert_eq!(errors[0].file, dir.join("b"));
        assert!(
            errors[0].source.to_string().starts_with("a file stands where the directory goes"),
            "{}",
            errors[0].source
        );
        assert_eq!(std::fs::read_to_string(dir.join("a.json")).unwrap(), "old");
        assert_eq!(std::fs::read_to_string(dir.join("metadata.json")).unwrap(), "old");
        assert!(unfinished.join("metadata.json").exists(), "the new outputs wait, whole");
        // Once nothing blocks it, the whole output moves in, the marker with it.
        std::fs::remove_file(dir.join("b")).unwrap();
        publish(&unfinished, &dir, &[], "metadata.json").unwrap();
        assert_eq!(std::fs::read_to_string(dir.join("metadata.json")).unwrap(), "new");
        assert!(dir.join("b").is_dir() && !unfinished.exists());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn partial_files_take_their_names_when_finished_and_vanish_when_the_output_fails() {
        let dir = std::env::temp_dir().join(format!("objslam-partial-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        // An earlier output stays whole while a new one streams, and after it fails.
        std::fs::write(dir.join("laser.jsonl"), "earlier\n").unwrap();
        let mut failed = PartialFiles::create(&dir, &[(1, "laser.jsonl")]).unwrap();
        failed.write(1, "new\n").unwrap();
        assert!(dir.join("laser.jsonl.partial").exists());
        drop(failed);
        assert!(!dir.join("laser.jsonl.partial").exists(), "a failed output's partial files are removed");
        assert_eq!(std::fs::read_to_string(dir.join("laser.jsonl")).unwrap(), "earlier\n");

        let mut done = PartialFiles::create(&dir, &[(1, "laser.jsonl"), (2, "trees_shown.jsonl")]).unwrap();
        done.write(1, "new\n").unwrap();
        done.write(3, "a stream not opened takes nothing\n").unwrap();
        done.finish().unwrap();
        assert_eq!(std::fs::read_to_string(dir.join("laser.jsonl")).unwrap(), "new\n");
        assert!(dir.join("trees_shown.jsonl").exists());
        let names: Vec<String> =
            std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        assert!(names.iter().all(|n| !n.ends_with(".partial")), "{names:?}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
