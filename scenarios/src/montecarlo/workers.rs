//! Monte Carlo runs in child processes ([`super::Workers::Processes`]).
//!
//! The protocol is JSON lines. Parent to child: the study plan, then one [`Job`] per line,
//! each sent when the child has answered the one before (so fast children take more jobs).
//! Child to parent: one [`RunRecord`] per job. The parent closes the child's stdin when no
//! job is left and the child exits. A child that dies or answers nonsense costs the run it
//! had, recorded as an error with the end of its stderr; a new child takes the next job.
//! So does a child that takes longer than the run timeout over one run: it is killed.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use super::{Job, RunRecord, StudyError, StudyFile, StudyModels, run_job};

/// Lines of a failed child's stderr kept for its run's error.
const STDERR_TAIL_LINES: usize = 12;

/// The child side: reads the plan and then jobs from `input`, answers each with its record
/// on `output`, until `input` ends. This is `objslam montecarlo-worker`.
pub fn serve_worker(input: impl BufRead, mut output: impl Write) -> Result<(), StudyError> {
    let protocol = |message: String| StudyError::Worker(format!("worker: {message}"));
    exit_when_orphaned();
    let mut lines = input.lines();
    let Some(first) = lines.next() else { return Ok(()) };
    let start: StudyFile = serde_json::from_str(&first.map_err(|e| protocol(e.to_string()))?)
        .map_err(|e| protocol(format!("the first line is not a study plan: {e}")))?;
    let (pin, base, base_dir) = super::pin_scenario(&start.plan.scenario)?;
    // The scenario file edited while the study runs would give this worker's runs another
    // scenario than the study's.
    if let Some(changed) = start.scenario_pin.as_ref().and_then(|began| began.changed_to(&start.plan.scenario, &pin)) {
        return Err(protocol(format!("{changed}: restore it, or start a new study")));
    }
    // The parent resolved every model first, so these load cached ones.
    let models = StudyModels::new(&base_dir);
    // Runs go on a rayon thread, so they simulate inline rather than on a thread of their
    // own beside the pipeline: with one worker per core the cores are already full.
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().map_err(|e| protocol(e.to_string()))?;
    for line in lines {
        let line = line.map_err(|e| protocol(e.to_string()))?;
        let job: Job = serde_json::from_str(&line).map_err(|e| protocol(format!("not a job: {e}")))?;
        let record = pool.install(|| run_job(&base, &base_dir, &job, &models));
        writeln!(output, "{}", serde_json::to_string(&record).expect("JSON"))
            .and_then(|_| output.flush())
            .map_err(|e| protocol(format!("cannot answer: {e}")))?;
    }
    Ok(())
}

/// A killed study's workers would finish the run in hand for nobody (their answer has no
/// reader): a watchdog ends the process once its parent is gone (re-parented).
fn exit_when_orphaned() {
    #[cfg(unix)]
    {
        let parent = std::os::unix::process::parent_id();
        std::thread::spawn(move || {
            loop {
                std::thread::sleep(std::time::Duration::from_millis(500));
                if std::os::unix::process::parent_id() != parent {
                    std::process::exit(3);
                }
            }
        });
    }
}

/// One child process and its pipes. Its answers are read on a thread of their own, so
/// that waiting for one can time out.
struct WorkerProcess {
    child: Child,
    stdin: ChildStdin,
    answers: Receiver<std::io::Result<String>>,
    stdout_reader: JoinHandle<()>,
    stderr_tail: Arc<Mutex<VecDeque<String>>>,
    stderr_reader: JoinHandle<()>,
}

impl WorkerProcess {
    fn spawn(exe: &Path, start: &StudyFile) -> std::io::Result<Self> {
        let mut command = Command::new(exe);
        command.arg("montecarlo-worker").stdin(Stdio::piped()).stdout(Stdio::piped()).stderr(Stdio::piped());
        // Each child is one of the workers sharing the cores: one thread of its own, and
        // llvmpipe (the software renderer) rasterising on the calling thread rather than
        // handing tiles to threads of its own, unless the user chose otherwise.
        command.env("RAYON_NUM_THREADS", "1");
        if std::env::var_os("LP_NUM_THREADS").is_none() {
            command.env("LP_NUM_THREADS", "0");
        }
        let mut child = command.spawn()?;
        let mut stdin = child.stdin.take().expect("piped");
        let stdout = BufReader::new(child.stdout.take().expect("piped"));
        let (sender, answers) = std::sync::mpsc::channel();
        let stdout_reader = std::thread::spawn(move || {
            for line in stdout.lines() {
                let failed = line.is_err();
                if sender.send(line).is_err() || failed {
                    break;
                }
            }
        });
        let stderr = child.stderr.take().expect("piped");
        let stderr_tail = Arc::new(Mutex::new(VecDeque::new()));
        let tail = stderr_tail.clone();
        let stderr_reader = std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                let mut t = tail.lock().unwrap_or_else(|p| p.into_inner());
                if t.len() == STDERR_TAIL_LINES {
                    t.pop_front();
                }
                t.push_back(line);
            }
        });
        writeln!(stdin, "{}", serde_json::to_string(start).expect("JSON"))?;
        Ok(WorkerProcess { child, stdin, answers, stdout_reader, stderr_tail, stderr_reader })
    }

    /// Runs one job, waiting at most `timeout` (`None`: for ever); what went wrong when the
    /// child did not answer with its record in time.
    fn run(&mut self, job: &Job, timeout: Option<Duration>) -> Result<RunRecord, String> {
        writeln!(self.stdin, "{}", serde_json::to_string(job).expect("JSON"))
            .and_then(|_| self.stdin.flush())
            .map_err(|e| format!("cannot send the job: {e}"))?;
        let answer = match timeout {
            Some(limit) => self.answers.recv_timeout(limit).map_err(|e| match e {
                RecvTimeoutError::Timeout => {
                    format!("the run took longer than {} s (--run-timeout)", limit.as_secs_f64())
                }
                RecvTimeoutError::Disconnected => "it stopped without answering".to_string(),
            })?,
            None => self.answers.recv().map_err(|_| "it stopped without answering".to_string())?,
        };
        match answer {
            Ok(line) => {
                let record: RunRecord = serde_json::from_str(&line).map_err(|e| format!("unreadable answer: {e}"))?;
                if record.key == job.key() {
                    Ok(record)
                } else {
                    Err(format!("it answered for {} instead", record.key))
                }
            }
            Err(e) => Err(format!("cannot read its answer: {e}")),
        }
    }

    /// Ends the child (killed if it still runs) and says how it ended, with its stderr's end.
    fn end(self, kill: bool) -> String {
        let WorkerProcess { mut child, stdin, answers, stdout_reader, stderr_tail, stderr_reader } = self;
        drop(stdin);
        if kill {
            let _ = child.kill();
        }
        let status = child.wait().map(|s| s.to_string()).unwrap_or_else(|e| e.to_string());
        drop(answers);
        let _ = stdout_reader.join();
        let _ = stderr_reader.join();
        let tail: Vec<String> = stderr_tail.lock().unwrap_or_else(|p| p.into_inner()).drain(..).collect();
        if tail.is_empty() { status } else { format!("{status}; its stderr ended with: {}", tail.join(" | ")) }
    }
}

/// The record of a run its worker process could not finish: retried when the study resumes.
fn error_record(job: &Job, error: String) -> RunRecord {
    RunRecord { key: job.key(), job: job.clone(), metrics: None, error: Some(error), retryable: true, build: None }
}

/// Runs `todo` on `count` child processes of `exe`, calling `finished` for each record as
/// it arrives; a child that takes longer than `run_timeout` over a run is killed and the
/// run recorded as retryable. Fails when no child can be started at all, or when
/// `finished` refuses a record (the scenario changed under the study): no job more is
/// given out, and the refused record is not returned.
pub(super) fn run_in_processes(
    start: &StudyFile,
    todo: &[&Job],
    exe: &Path,
    count: usize,
    run_timeout: Option<Duration>,
    finished: &(dyn Fn(&RunRecord) -> Result<(), StudyError> + Sync),
) -> Result<Vec<RunRecord>, StudyError> {
    if todo.is_empty() {
        return Ok(Vec::new());
    }
    let mut workers = Vec::new();
    for _ in 0..count.clamp(1, todo.len()) {
        workers.push(
            WorkerProcess::spawn(exe, start)
                .map_err(|e| StudyError::Worker(format!("cannot start {} montecarlo-worker: {e}", exe.display())))?,
        );
    }
    let queue = Mutex::new(todo.iter().copied().collect::<VecDeque<&Job>>());
    let records = Mutex::new(Vec::new());
    // Set when the scenario no longer is the study's: no job more is given out.
    let changed: Mutex<Option<StudyError>> = Mutex::new(None);
    std::thread::scope(|scope| {
        for first in workers {
            let (queue, records, changed) = (&queue, &records, &changed);
            scope.spawn(move || {
                let mut worker = Some(first);
                loop {
                    if changed.lock().unwrap_or_else(|p| p.into_inner()).is_some() {
                        break;
                    }
                    let Some(job) = queue.lock().unwrap_or_else(|p| p.into_inner()).pop_front() else { break };
                    if worker.is_none() {
                        // A worker died: before another starts, the scenario is checked here
                        // once, so that a changed one stops the study instead of failing
                        // every job in a new worker.
                        if let Err(e) = check_pin(start) {
                            queue.lock().unwrap_or_else(|p| p.into_inner()).push_front(job);
                            changed.lock().unwrap_or_else(|p| p.into_inner()).get_or_insert(e);
                            break;
                        }
                        worker = WorkerProcess::spawn(exe, start).ok();
                    }
                    let record = match worker.as_mut().map(|w| w.run(job, run_timeout)) {
                        Some(Ok(record)) => record,
                        Some(Err(what)) => {
                            let how = worker.take().expect("it ran").end(true);
                            error_record(job, format!("the worker process failed: {what} (exit: {how})"))
                        }
                        None => error_record(job, format!("cannot start {} montecarlo-worker", exe.display())),
                    };
                    if let Err(e) = finished(&record) {
                        changed.lock().unwrap_or_else(|p| p.into_inner()).get_or_insert(e);
                        break;
                    }
                    records.lock().unwrap_or_else(|p| p.into_inner()).push(record);
                }
                if let Some(w) = worker {
                    w.end(false);
                }
            });
        }
    });
    let records = records.into_inner().unwrap_or_else(|p| p.into_inner());
    match changed.into_inner().unwrap_or_else(|p| p.into_inner()) {
        // The finished runs are on file already; the error says why the rest did not run.
        Some(e) => Err(e),
        None => Ok(records),
    }
}

/// Whether the scenario the study names still is the one it pinned when it began.
fn check_pin(start: &StudyFile) -> Result<(), StudyError> {
    // A study begun before scenarios were pinned has nothing to check against.
    let Some(began) = &start.scenario_pin else { return Ok(()) };
    super::still_pinned(
        &start.plan,
        began,
        " (a worker that had died was not restarted); the finished runs are kept: restore the scenario and run the \
         same command again, or start a new study",
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::montecarlo::{ScenarioPin, StudyPlan};

    /// A worker whose scenario no longer is the one the study pinned (the file edited
    /// while the study runs) refuses to run, rather than run another scenario's jobs.
    #[test]
    fn a_worker_refuses_a_scenario_changed_since_the_study_began() {
        let plan = StudyPlan {
            scenario: "laser_only".into(),
            base_seed: 1,
            runs: 1,
            methods: vec!["nn".into()],
            vary: vec![],
        };
        let (pin, _, _) = super::super::pin_scenario("laser_only").unwrap();
        let start = |sha256: &str| {
            let pin = ScenarioPin { file: pin.file.clone(), sha256: sha256.into() };
            serde_json::to_string(&StudyFile { plan: plan.clone(), scenario_pin: Some(pin), build: None }).unwrap()
                + "\n"
        };
        let mut answers = Vec::new();
        let e = serve_worker(start("0000").as_bytes(), &mut answers).unwrap_err().to_string();
        assert!(e.contains("files or settings differ"), "{e}");
        // The pinned scenario itself: the worker starts and, given no job, ends.
        serve_worker(start(&pin.sha256).as_bytes(), &mut answers).unwrap();
        assert!(answers.is_empty());
        // The parent's check before it replaces a worker that died says the same.
        let study = |sha256: &str| serde_json::from_str::<StudyFile>(&start(sha256)).unwrap();
        let e = check_pin(&study("0000")).unwrap_err().to_string();
        assert!(e.contains("files or settings differ") && e.contains("finished runs are kept"), "{e}");
        assert_eq!(e.matches(&pin.file).count(), 1, "the scenario named once: {e}");
        check_pin(&study(&pin.sha256)).unwrap();
    }
}
