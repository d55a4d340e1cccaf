//! Every progress bar's style, in one place. Bars draw on stderr, so stdout holds only
//! results that scripts may read.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use scenarios::montecarlo::StudyProgress;
use scenarios::run::RunProgress;

fn bar(len: u64, template: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(ProgressStyle::with_template(template).expect("a valid template").progress_chars("=> "));
    // Redrawing faster than a person reads only costs time.
    bar.set_draw_target(ProgressDrawTarget::stderr_with_hz(4));
    bar
}

/// Simulated seconds of a run or a recording, labelled `what`.
pub(crate) fn simulated(what: &str) -> ProgressBar {
    let b = bar(0, "{msg} [{bar:40}] {pos}/{len} s simulated, {elapsed} elapsed, ETA {eta}");
    b.set_message(what.to_string());
    b
}

/// Moves a bar of simulated seconds to `t` of `total`.
pub(crate) fn set_simulated(bar: &ProgressBar, t: f64, total: f64) {
    bar.set_length(total.ceil() as u64);
    bar.set_position((t.floor() as u64).min(total.ceil() as u64));
}

/// The stages of a training (`what`: whose).
pub(crate) fn training(what: &str) -> ProgressBar {
    bar(1, &format!("{what} {{msg:>18}} [{{bar:40}}] {{pos}}/{{len}}, {{elapsed}} elapsed"))
}

/// Moves a training bar to `done` of `total` in `stage`.
pub(crate) fn set_training(bar: &ProgressBar, stage: &str, done: usize, total: usize) {
    bar.set_message(stage.to_string());
    bar.set_length(total as u64);
    bar.set_position(done as u64);
}

/// Images of a dataset.
pub(crate) fn images(count: usize) -> ProgressBar {
    bar(count as u64, "dataset [{bar:40}] {pos}/{len} images, {elapsed} elapsed, ETA {eta}")
}

/// A run: a training bar while its appearance model trains, then simulated seconds;
/// warnings are printed above the bar.
pub(crate) struct RunBar {
    name: String,
    training: Option<ProgressBar>,
    simulated: Option<ProgressBar>,
}

impl RunBar {
    pub(crate) fn new(name: &str) -> Self {
        RunBar { name: name.to_string(), training: None, simulated: None }
    }

    pub(crate) fn show(&mut self, p: RunProgress) {
        match p {
            RunProgress::Training { stage, done, total } => {
                let b = self.training.get_or_insert_with(|| training("appearance model"));
                set_training(b, stage, done, total);
            }
            RunProgress::Simulated { t, total } => {
                if let Some(b) = self.training.take() {
                    b.finish_and_clear();
                }
                let name = &self.name;
                let b = self.simulated.get_or_insert_with(|| simulated(&format!("running {name}")));
                set_simulated(b, t, total);
            }
            RunProgress::Warning(w) => match self.simulated.as_ref().or(self.training.as_ref()) {
                Some(b) => b.suspend(|| eprintln!("warning: {w}")),
                None => eprintln!("warning: {w}"),
            },
        }
    }

    pub(crate) fn finish(self) {
        for b in [self.training, self.simulated].into_iter().flatten() {
            b.finish_and_clear();
        }
    }
}

/// A study: a training bar while an appearance model trains, then finished runs with
/// their rate (runs done before this start are not counted in it).
pub(crate) struct StudyBar {
    training: std::sync::Mutex<Option<ProgressBar>>,
    runs: ProgressBar,
    started: std::time::Instant,
    first_done: std::sync::Mutex<Option<usize>>,
}

impl StudyBar {
    pub(crate) fn new() -> Self {
        StudyBar {
            training: std::sync::Mutex::new(None),
            runs: bar(0, "study [{bar:40}] {pos}/{len} runs, {msg}, {elapsed} elapsed, ETA {eta}"),
            started: std::time::Instant::now(),
            first_done: std::sync::Mutex::new(None),
        }
    }

    pub(crate) fn show(&self, p: StudyProgress) {
        match p {
            StudyProgress::Training { stage, done, total } => {
                let mut t = self.training.lock().unwrap_or_else(|p| p.into_inner());
                set_training(t.get_or_insert_with(|| training("appearance model")), stage, done, total);
            }
            StudyProgress::Runs { done, total } => {
                if let Some(b) = self.training.lock().unwrap_or_else(|p| p.into_inner()).take() {
                    b.finish_and_clear();
                }
                self.runs.set_length(total as u64);
                self.runs.set_position(done as u64);
                let mut first = self.first_done.lock().unwrap_or_else(|p| p.into_inner());
                let base = *first.get_or_insert(done);
                let minutes = self.started.elapsed().as_secs_f64() / 60.0;
                if minutes > 0.0 {
                    self.runs.set_message(format!("{:.1} runs/min", (done - base) as f64 / minutes));
                }
            }
        }
    }

    pub(crate) fn finish(&self) {
        if let Some(b) = self.training.lock().unwrap_or_else(|p| p.into_inner()).take() {
            b.finish_and_clear();
        }
        self.runs.finish_and_clear();
    }

    /// Runs that were on file before this command ran any (a resumed study's).
    pub(crate) fn done_before(&self) -> usize {
        self.first_done.lock().unwrap_or_else(|p| p.into_inner()).unwrap_or(0)
    }

    /// Seconds since the study started.
    pub(crate) fn elapsed_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}
