//! Scenario files: which world, which sensors, which calibration and pipeline settings,
//! and the pass criteria. A library of scenarios ships in `scenarios/*.toml` and is
//! embedded in the binary, so `objslam run` needs nothing on disk.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

mod keys;

/// Errors from loading or checking a scenario.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("{}: cannot read: {source}", file.display())]
    Read { file: PathBuf, source: std::io::Error },
    #[error("{}: {message}", file.display())]
    Parse { file: PathBuf, message: String },
    #[error("{}: {}{field}: {message}", file.display(), line.map(|l| format!("line {l}: ")).unwrap_or_default())]
    Invalid { file: PathBuf, line: Option<usize>, field: String, message: String },
    #[error("unknown scenario {name:?}: not a file and not one of the built-in scenarios ({})", available.join(", "))]
    Unknown { name: String, available: Vec<String> },
    /// The world could not be made: a world file's own error names that file.
    #[error("{scenario}: world: {source}")]
    World { scenario: String, source: worlds::WorldError },
}

/// Where the world comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSource {
    /// A generator preset (`park`)...
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// ... or a world file, relative to the scenario file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// Seed of the generated world; absent: the world seed follows the run seed, so a
    /// Monte Carlo study also varies the world.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Generator parameters overriding the preset's defaults.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub params: Option<worlds::generate::ParkParams>,
}

/// The calibration (laser <- camera extrinsics) the pipeline is given: a `[calibration]`
/// table, or just its mode (`calibration = "estimated"`, `calibration = "cal.json"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(from = "CalibrationSpelling")]
pub struct CalibrationChoice {
    /// `true`: the simulator's exact extrinsics; `perturbed`: the true ones with seeded
    /// errors of the sigmas below; `estimated`: run the Zhang & Pless calibration first;
    /// anything else: a `calibration.json` file path.
    pub mode: String,
    #[serde(default)]
    pub rotation_sigma_deg: f64,
    #[serde(default)]
    pub translation_sigma_m: f64,
    /// The calibration session run for `estimated` (`[calibration.session]`): board
    /// poses, sizes, distances, tilts (see `crate::calibrate::SessionConfig`).
    #[serde(default)]
    pub session: crate::calibrate::SessionConfig,
}

/// How a scenario file may write its calibration: a string (the mode) or a table. A
/// hand-written visitor rather than an untagged enum, so errors inside the table (an
/// unknown key, a bad session value) keep their field and line.
struct CalibrationSpelling(CalibrationChoice);

impl<'de> Deserialize<'de> for CalibrationSpelling {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = CalibrationChoice;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a mode (\"true\", \"perturbed\", \"estimated\" or a calibration.json path) or a [calibration] table")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<CalibrationChoice, E> {
                Ok(CalibrationChoice { mode: v.into(), ..Default::default() })
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<CalibrationChoice, A::Error> {
                CalibrationTable::deserialize(serde::de::value::MapAccessDeserializer::new(map)).map(|t| {
                    CalibrationChoice {
                        mode: t.mode,
                        rotation_sigma_deg: t.rotation_sigma_deg,
                        translation_sigma_m: t.translation_sigma_m,
                        session: t.session,
                    }
                })
            }
        }
        d.deserialize_any(V).map(CalibrationSpelling)
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibrationTable {
    /// Absent: "true", as the table's other keys default to the true extrinsics' zeros.
    #[serde(default = "true_mode")]
    mode: String,
    #[serde(default)]
    rotation_sigma_deg: f64,
    #[serde(default)]
    translation_sigma_m: f64,
    #[serde(default)]
    session: crate::calibrate::SessionConfig,
}

fn true_mode() -> String {
    "true".into()
}

impl From<CalibrationSpelling> for CalibrationChoice {
    fn from(c: CalibrationSpelling) -> Self {
        c.0
    }
}

impl Default for CalibrationChoice {
    fn default() -> Self {
        CalibrationChoice {
            mode: "true".into(),
            rotation_sigma_deg: 0.0,
            translation_sigma_m: 0.0,
            session: Default::default(),
        }
    }
}

/// Criteria a run must meet to pass; absent criteria are not checked.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PassCriteria {
    pub max_wrong_associations: Option<usize>,
    /// Landmarks on posts, palms, people, walls or nothing.
    pub max_false_landmarks: Option<usize>,
    /// For baseline scenarios that must reproduce a failure: at least this many landmarks
    /// on things that are not trees.
    pub min_false_landmarks: Option<usize>,
    pub max_duplicate_landmarks: Option<usize>,
    /// Least `map.tree_recall` (mapped share of the trees there were to map, by ground
    /// truth); a run with no tree to map fails it.
    pub min_tree_recall: Option<f64>,
    pub max_ate_rmse_m: Option<f64>,
    pub max_landmark_rmse_m: Option<f64>,
    pub max_collisions: Option<usize>,
    /// Largest error of the run's laser-camera extrinsics against the simulator's.
    pub max_calibration_rotation_error_deg: Option<f64>,
    pub max_calibration_translation_error_m: Option<f64>,
}

impl PassCriteria {
    /// What a system's estimate without the map and the associations (a trajectory, with
    /// or without `landmarks`) can be judged on, and whether criteria needing the map and
    /// the associations were left out. Every field is named, so a new criterion must be
    /// placed here.
    pub fn for_trajectory(&self, landmarks: bool) -> (PassCriteria, bool) {
        let PassCriteria {
            max_wrong_associations,
            max_false_landmarks,
            min_false_landmarks,
            max_duplicate_landmarks,
            min_tree_recall,
            max_ate_rmse_m,
            max_landmark_rmse_m,
            max_collisions,
            max_calibration_rotation_error_deg,
            max_calibration_translation_error_m,
        } = *self;
        let needs_map = max_wrong_associations.is_some()
            || max_false_landmarks.is_some()
            || min_false_landmarks.is_some()
            || max_duplicate_landmarks.is_some()
            || min_tree_recall.is_some();
        let judged = PassCriteria {
            max_ate_rmse_m,
            max_collisions,
            max_landmark_rmse_m: max_landmark_rmse_m.filter(|_| landmarks),
            max_calibration_rotation_error_deg,
            max_calibration_translation_error_m,
            ..PassCriteria::default()
        };
        (judged, needs_map)
    }
}

/// What [`Scenario::input_files`] calls the calibration file: a calibration session writes
/// that file rather than reading it.
pub const CALIBRATION_INPUT: &str = "calibration file";

/// The `calibration.mode` keywords; any other value names a calibration file (.json).
pub const CALIBRATION_MODES: [&str; 3] = ["true", "perturbed", "estimated"];

/// Where a scenario was read from (`<built-in>/<name>.toml` for the library's; empty for
/// one built in code): named in errors found after reading, and not part of what the
/// scenario says, so two scenarios with the same settings are equal wherever they came from.
#[derive(Debug, Clone, Default)]
pub struct SourceFile(pub PathBuf);

impl PartialEq for SourceFile {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// What names a built-in scenario as such (`<built-in>/paper_park`): errors give built-ins
/// this place, a study pins them by it, and [`Scenario::load`] reads it as the built-in
/// alone, whatever files the working directory holds.
pub const BUILT_IN_PREFIX: &str = "<built-in>/";

/// A scenario file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// The file the scenario was read from, for errors found after reading.
    #[serde(skip)]
    pub source: SourceFile,
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Default run seed (`--seed` overrides).
    #[serde(default = "default_seed")]
    pub seed: u64,
    pub world: WorldSource,
    /// Simulator settings: robot, laser, odometry noise, duration.
    #[serde(default)]
    pub sim: sim::SimConfig,
    #[serde(default)]
    pub calibration: CalibrationChoice,
    /// Pipeline settings (association method, thresholds, model), typed and checked when
    /// the file is read.
    #[serde(default)]
    pub pipeline: slam::pipeline::PipelineConfig,
    /// The appearance model of the camera methods: a file, or trained and cached.
    #[serde(default)]
    pub appearance: crate::appearance::AppearanceSource,
    #[serde(default)]
    pub pass: PassCriteria,
}

fn default_seed() -> u64 {
    1
}

/// Most false landmarks `pass.min_false_landmarks` may ask for: more than any run maps (a
/// park ten times the paper's maps a few hundred).
const MAX_LANDMARKS_CRITERION: usize = 10_000;

/// The built-in scenario library, embedded at compile time.
pub const LIBRARY: &[(&str, &str)] = &[
    ("paper_park", include_str!("../paper_park.toml")),
    ("posts_near_trees", include_str!("../posts_near_trees.toml")),
    ("crowd", include_str!("../crowd.toml")),
    ("long_loop", include_str!("../long_loop.toml")),
    ("laser_only", include_str!("../laser_only.toml")),
    ("calibration", include_str!("../calibration.toml")),
    ("city_park", include_str!("../city_park.toml")),
];

/// The default scenario of `objslam run`.
pub const DEFAULT_SCENARIO: &str = "paper_park";

impl Scenario {
    /// Parses and checks scenario text; `file` names it in errors.
    pub fn parse(text: &str, file: &Path) -> Result<Scenario, ScenarioError> {
        let mut s: Scenario = toml_strict::from_str(text).map_err(|e| {
            // A scenario's tables are single: `[[sim.laser]]` would otherwise be reported
            // as a type error inside it ("expected f64").
            let array_of_tables = text.lines().enumerate().find_map(|(i, line)| {
                let name = line.trim().strip_prefix("[[")?.split("]]").next()?.trim().to_string();
                Some((i + 1, name))
            });
            let message = match array_of_tables {
                Some((line, name)) => format!(
                    "line {line}: `[[{name}]]` starts an array of tables, and a scenario has none: write `[{name}]`"
                ),
                None => e.to_string().trim_end().to_string(),
            };
            ScenarioError::Parse { file: file.to_path_buf(), message }
        })?;
        s.source = SourceFile(file.to_path_buf());
        s.check(file).map_err(|e| match e {
            ScenarioError::Invalid { file, line: None, field, message } => {
                ScenarioError::Invalid { line: line_of(text, &field), file, field, message }
            }
            other => other,
        })?;
        Ok(s)
    }

    /// Loads a scenario by file path or built-in name. Returns it with its base directory.
    pub fn load(name_or_path: &str) -> Result<(Scenario, PathBuf), ScenarioError> {
        let path = Path::new(name_or_path);
        // `<built-in>/NAME` (as a study pins a built-in scenario) is the built-in alone,
        // whatever files the working directory holds.
        let explicit = name_or_path.strip_prefix(BUILT_IN_PREFIX);
        // A directory is no scenario file: one named as a built-in (a run's output
        // directory, `objslam run laser_only --out laser_only`) does not hide it.
        let builtin_name = LIBRARY.iter().any(|(n, _)| *n == name_or_path.trim_end_matches(".toml"));
        if explicit.is_none() && path.exists() && !(path.is_dir() && builtin_name) {
            let text = read_settings_text(path)?;
            let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
            return Ok((Scenario::parse(&text, path)?, base));
        }
        let key = explicit.unwrap_or(name_or_path).trim_end_matches(".toml");
        match LIBRARY.iter().find(|(n, _)| *n == key) {
            Some((n, text)) => {
                Ok((Scenario::parse(text, Path::new(&format!("{BUILT_IN_PREFIX}{n}.toml")))?, PathBuf::from(".")))
            }
            None => Err(ScenarioError::Unknown {
                name: name_or_path.into(),
                available: LIBRARY.iter().map(|(n, _)| n.to_string()).collect(),
            }),
        }
    }

    /// The name of the built-in scenario this is, where [`Scenario::load`] read it from the
    /// library rather than from a file.
    pub fn built_in(&self) -> Option<&str> {
        self.source.0.to_str()?.strip_prefix(BUILT_IN_PREFIX)?.strip_suffix(".toml")
    }

    fn check(&self, file: &Path) -> Result<(), ScenarioError> {
        let bad = |field: &str, message: String| {
            Err(ScenarioError::Invalid { file: file.to_path_buf(), line: None, field: field.into(), message })
        };
        // The name makes the default output directory (runs/<name>-<seed>): a path in it
        // would write elsewhere.
        let name_ok = !self.name.is_empty()
            && !self.name.starts_with('.')
            && self.name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
        if !name_ok {
            return bad("name", format!("must be letters, digits, '_', '-' and '.' (not first), got {:?}", self.name));
        }
        // Within a file name's 255 bytes with the seed and what studies add to it.
        if self.name.len() > MAX_NAME_CHARS {
            return bad("name", format!("must be at most {MAX_NAME_CHARS} characters, got {}", self.name.len()));
        }
        match (&self.world.preset, &self.world.file) {
            (Some(_), Some(_)) => return bad("world", "give either `preset` or `file`, not both".into()),
            (None, None) => return bad("world", "needs `preset` (e.g. \"park\") or `file`".into()),
            (Some(p), None) if !worlds::generate::PRESETS.contains(&p.as_str()) => {
                return bad(
                    "world.preset",
                    format!("unknown preset {p:?}; available: {}", worlds::generate::PRESETS.join(", ")),
                );
            }
            (None, Some(_)) if self.world.params.is_some() => {
                return bad("world.params", "generator parameters only apply to a preset".into());
            }
            (None, Some(_)) if self.world.seed.is_some() => {
                return bad("world.seed", "a world seed only applies to a preset (a world file is one world)".into());
            }
            _ => {}
        }
        if let Some(p) = &self.world.params {
            match p.check() {
                Ok(()) => {}
                Err(worlds::WorldError::Parameter { field, message }) => {
                    return bad(&format!("world.params.{field}"), message);
                }
                Err(e) => return bad("world.params", e.to_string()),
            }
        }
        match self.sim.check() {
            Ok(()) => {}
            Err(sim::SimError::Config { field, message }) => return bad(&format!("sim.{field}"), message),
            Err(e) => return bad("sim", e.to_string()),
        }
        let c = &self.calibration;
        // A file is named by its extension, so that a misspelt mode ("ture") is not taken
        // for a file that does not exist.
        let keyword = CALIBRATION_MODES.contains(&c.mode.as_str());
        if !keyword && !c.mode.to_ascii_lowercase().ends_with(".json") {
            return bad(
                "calibration.mode",
                format!(
                    "unknown mode {:?}: \"true\", \"perturbed\", \"estimated\", or a calibration file (.json)",
                    c.mode
                ),
            );
        }
        for (field, v) in [
            ("calibration.rotation_sigma_deg", c.rotation_sigma_deg),
            ("calibration.translation_sigma_m", c.translation_sigma_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(field, format!("perturbation sigmas must be finite and not negative, got {v}"));
            }
            // A calibration off by more is no calibration of this robot: a file is refused
            // beyond the same offset, and a rotation's error is at most a half turn.
            let most = if field.ends_with("_deg") { 180.0 } else { crate::calibrate::MAX_MOUNT_OFFSET_M };
            if v > most {
                return bad(field, format!("must be at most {most}, got {v}"));
            }
            if v != 0.0 && c.mode != "perturbed" {
                return bad(field, format!("only applies to mode \"perturbed\", not {:?}", c.mode));
            }
        }
        // The session is checked against the sensors only where a run runs it.
        let session =
            if c.mode == "estimated" { c.session.check(file, &self.sim) } else { c.session.check_settings(file) };
        if let Err(e) = session {
            let message = match e {
                crate::calibrate::CalibrateError::Session { field, message, .. } => {
                    return bad(&format!("calibration.session.{field}"), message);
                }
                other => other.to_string(),
            };
            return bad("calibration.session", message);
        }
        if let Err(e) = self.pipeline.validate() {
            return bad(&format!("pipeline.{}", e.path), e.problem);
        }
        // The simulated robot's odometry is body-frame increments, which the car-like
        // model cannot use: every run would stop at its first odometry message.
        if let slam::ekf::MotionConfig::Ackermann(_) = self.pipeline.motion {
            return bad(
                "pipeline.motion.model",
                "\"ackermann\" reads a car's speed and steering, and the simulated robot's odometry gives \
                 body-frame increments: use \"odometry\" (the car-like model is for robot logs, `objslam replay`)"
                    .into(),
            );
        }
        // A run sets the filter's laser mounting from the simulator's (see
        // run::pipeline_config): another value here would be silently replaced.
        let sensor = &self.pipeline.sensor;
        let default = slam::ekf::RangeBearingModel::default();
        let [mx, my, _] = self.sim.laser.mount_xyz_m;
        for (field, given, sim, fallback) in [
            ("pipeline.sensor.mount_x", sensor.mount_x, mx, default.mount_x),
            ("pipeline.sensor.mount_y", sensor.mount_y, my, default.mount_y),
        ] {
            if given != sim && given != fallback {
                return bad(
                    field,
                    format!(
                        "a run takes the laser's mounting from sim.laser.mount_xyz_m ({sim} m here); leave it out, not {given}"
                    ),
                );
            }
        }
        if let Err((field, message)) = self.appearance.check() {
            return bad(&format!("appearance.{field}"), message);
        }
        if let Some((field, message)) = self.camera_too_small_for(self.pipeline.method) {
            return bad(field, message);
        }
        if let Some((field, message)) = self.object_models_too_wide_for(self.pipeline.method) {
            return bad(field, message);
        }
        if let Some(r) = self.pass.min_tree_recall
            && !(0.0..=1.0).contains(&r)
        {
            return bad("pass.min_tree_recall", format!("must be in [0, 1], got {r}"));
        }
        // Criteria that no run could pass.
        let p = &self.pass;
        if let Some(min) = p.min_false_landmarks
            && min > MAX_LANDMARKS_CRITERION
        {
            return bad(
                "pass.min_false_landmarks",
                format!("must be at most {MAX_LANDMARKS_CRITERION}, got {min}: no run maps that many landmarks"),
            );
        }
        if let (Some(min), Some(max)) = (p.min_false_landmarks, p.max_false_landmarks)
            && min > max
        {
            return bad(
                "pass.min_false_landmarks",
                format!("{min} is above pass.max_false_landmarks = {max}: no run could pass both"),
            );
        }
        for (field, max) in
            [("pass.max_ate_rmse_m", p.max_ate_rmse_m), ("pass.max_landmark_rmse_m", p.max_landmark_rmse_m)]
        {
            if let Some(max) = max
                && !(max > 0.0 && max.is_finite())
            {
                // Infinite: no limit, which leaving the criterion out says.
                let why =
                    if max == f64::INFINITY { "leave the criterion out for no limit" } else { "no run could pass" };
                return bad(field, format!("must be a positive number of metres, got {max}: {why}"));
            }
        }
        for (field, max) in [
            ("pass.max_calibration_rotation_error_deg", p.max_calibration_rotation_error_deg),
            ("pass.max_calibration_translation_error_m", p.max_calibration_translation_error_m),
        ] {
            if let Some(max) = max
                && !(max >= 0.0 && max.is_finite())
            {
                let why =
                    if max == f64::INFINITY { "leave the criterion out for no limit" } else { "no run could pass" };
                return bad(field, format!("must be 0 or more, got {max}: {why}"));
            }
        }
        Ok(())
    }

    /// The scenario as errors name it: its file, or `scenario <name>` when built in code.
    pub fn describe(&self) -> String {
        if self.source.0.as_os_str().is_empty() {
            format!("scenario {}", self.name)
        } else {
            self.source.0.display().to_string()
        }
    }

    /// Where `method` fits object models of more appearance dimensions than the model it
    /// trains has: the key and the problem. (A model given as a file is checked against
    /// this when it is loaded.)
    pub fn object_models_too_wide_for(
        &self,
        method: slam::association::AssociationMethod,
    ) -> Option<(&'static str, String)> {
        let dims = self.pipeline.object_model.appearance_dims;
        (method.uses_appearance() && self.appearance.model.is_none() && dims > self.appearance.pca_dims).then(|| {
            (
                "pipeline.object_model.appearance_dims",
                format!(
                    "{dims} is more than the trained appearance model's appearance.pca_dims = {}",
                    self.appearance.pca_dims
                ),
            )
        })
    }

    /// Where `method` trains its appearance model on this scenario's camera images and they
    /// hold no patch: the camera key and the problem.
    pub fn camera_too_small_for(&self, method: slam::association::AssociationMethod) -> Option<(&'static str, String)> {
        let patch = crate::dataset::DatasetConfig::default().patch_size;
        let camera = &self.sim.camera;
        (method.uses_appearance() && self.appearance.model.is_none() && camera.width.min(camera.height) < patch).then(
            || {
                (
                    if camera.width < patch { "sim.camera.width" } else { "sim.camera.height" },
                    format!(
                        "a {}x{} image holds no {patch}x{patch}-pixel patch for the appearance model the method {} trains",
                        camera.width,
                        camera.height,
                        method.name()
                    ),
                )
            },
        )
    }

    /// The scenario with the files it names relative to itself (`world.file`, a
    /// calibration file, `appearance.model`) made absolute against `base_dir`, its file's
    /// directory: written into a run's `metadata.json`, it runs the run again from
    /// wherever it is saved.
    pub fn with_absolute_paths(&self, base_dir: &Path) -> Scenario {
        let absolute = |relative: &str| {
            crate::files::recorded_path(&base_dir.join(relative))
                .to_str()
                .map(str::to_owned)
                .unwrap_or_else(|| relative.to_owned())
        };
        let mut s = self.clone();
        if let Some(file) = &s.world.file {
            s.world.file = Some(absolute(file));
        }
        if let Some(file) = self.calibration_file() {
            s.calibration.mode = absolute(file);
        }
        if let Some(model) = &s.appearance.model {
            s.appearance.model = Some(absolute(model));
        }
        s
    }

    /// The calibration file `calibration.mode` names, if it names one rather than a mode.
    pub fn calibration_file(&self) -> Option<&str> {
        (!CALIBRATION_MODES.contains(&self.calibration.mode.as_str())).then_some(self.calibration.mode.as_str())
    }

    /// The files a run of this scenario reads, each with what it is: the scenario file
    /// itself (when it is one on disk), the world file, the calibration file and the
    /// appearance model, resolved against `base_dir`.
    pub fn input_files(&self, base_dir: &Path) -> Vec<(&'static str, std::path::PathBuf)> {
        let mut inputs = Vec::new();
        if self.source.0.is_file() {
            inputs.push(("scenario file", self.source.0.clone()));
        }
        if let Some(file) = &self.world.file {
            inputs.push(("world file", base_dir.join(file)));
        }
        if let Some(file) = self.calibration_file() {
            inputs.push((CALIBRATION_INPUT, base_dir.join(file)));
        }
        if let Some(file) = &self.appearance.model {
            inputs.push(("appearance model", base_dir.join(file)));
        }
        inputs
    }

    /// Builds the world for a run seed.
    pub fn world(&self, base_dir: &Path, run_seed: u64) -> Result<worlds::World, ScenarioError> {
        let scenario = self.describe();
        if let Some(preset) = &self.world.preset {
            worlds::generate::preset(preset, self.world.params.as_ref(), self.world.seed.unwrap_or(run_seed))
                .map_err(|source| ScenarioError::World { scenario, source })
        } else {
            let path = base_dir.join(self.world.file.as_deref().unwrap_or_default());
            let mut world = worlds::load(&path).map_err(|source| ScenarioError::World { scenario, source })?;
            world.resolve_mesh_paths(&path);
            Ok(world)
        }
    }
}

impl Scenario {
    /// A scenario with every setting at the code's default: the park preset and its
    /// generator parameters, the simulator, calibration, pipeline and appearance model; no
    /// pass criterion.
    pub fn with_defaults(name: &str) -> Scenario {
        Scenario {
            source: SourceFile::default(),
            name: name.into(),
            description: String::new(),
            seed: default_seed(),
            world: WorldSource {
                preset: Some("park".into()),
                file: None,
                seed: None,
                params: Some(Default::default()),
            },
            sim: Default::default(),
            calibration: Default::default(),
            pipeline: Default::default(),
            appearance: Default::default(),
            pass: Default::default(),
        }
    }

    /// Whether `path` (dotted, `sim.odometry.a_dd`) is a setting a scenario file can hold.
    pub fn is_setting(path: &str) -> bool {
        keys::KEYS.iter().any(|(p, _)| *p == path)
    }

    /// [`Scenario::with_defaults`] as TOML (what `objslam config defaults` prints), each
    /// table and key after a comment saying what it means, and the keys that have no
    /// default (the pass criteria among them) commented out with an example value; or only
    /// the table at the dotted path `table` (`pipeline.evidence`) and the tables below it.
    pub fn defaults_toml(table: Option<&str>) -> Result<String, ScenarioError> {
        keys::commented(table).map_err(|message| ScenarioError::Parse { file: PathBuf::from("<defaults>"), message })
    }
}

/// Reads a TOML file of settings of one kind (a `--sim-config`, a `--params`): parsed, then
/// checked by `check`, which names the first bad field as `(field, problem)`; errors name
/// the file, the line and the field.
fn read_settings<T: serde::de::DeserializeOwned>(
    file: &Path,
    check: impl Fn(&T) -> Result<(), (String, String)>,
) -> Result<T, ScenarioError> {
    let text = read_settings_text(file)?;
    let settings: T = toml_strict::from_str(&text).map_err(|e| ScenarioError::Parse {
        file: file.to_path_buf(),
        message: e.to_string().trim_end().to_string(),
    })?;
    check(&settings).map_err(|(field, message)| match field.is_empty() {
        true => ScenarioError::Parse { file: file.to_path_buf(), message },
        false => ScenarioError::Invalid { file: file.to_path_buf(), line: line_of(&text, &field), field, message },
    })?;
    Ok(settings)
}

/// Reads simulator settings (a scenario's `[sim]` table on its own, `objslam record
/// --sim-config`), checked.
pub fn read_sim_config(file: &Path) -> Result<sim::SimConfig, ScenarioError> {
    read_settings(file, |c: &sim::SimConfig| match c.check() {
        Ok(()) => Ok(()),
        Err(sim::SimError::Config { field, message }) => Err((field, message)),
        Err(e) => Err((String::new(), e.to_string())),
    })
}

/// Reads park generator parameters (a scenario's `[world.params]` on its own, `objslam
/// world generate --params`), checked.
pub fn read_park_params(file: &Path) -> Result<worlds::generate::ParkParams, ScenarioError> {
    read_settings(file, |p: &worlds::generate::ParkParams| match p.check() {
        Ok(()) => Ok(()),
        Err(worlds::WorldError::Parameter { field, message }) => Err((field, message)),
        Err(e) => Err((String::new(), e.to_string())),
    })
}

/// Longest scenario name: it names output directories (`runs/<name>-<seed>`).
const MAX_NAME_CHARS: usize = 100;

/// Largest settings file read: a hand-written scenario is a few kilobytes, and a path to a
/// device or a log given by mistake (`/dev/zero`) would otherwise be read without end.
const MAX_SETTINGS_BYTES: u64 = 16 << 20;

/// The text of a scenario or settings file, refusing one larger than [`MAX_SETTINGS_BYTES`].
fn read_settings_text(file: &Path) -> Result<String, ScenarioError> {
    use std::io::Read;
    let read = |source| ScenarioError::Read { file: file.to_path_buf(), source };
    let mut bytes = Vec::new();
    std::fs::File::open(file).map_err(read)?.take(MAX_SETTINGS_BYTES + 1).read_to_end(&mut bytes).map_err(read)?;
    if bytes.len() as u64 > MAX_SETTINGS_BYTES {
        return Err(ScenarioError::Parse {
            file: file.to_path_buf(),
            message: format!("larger than {} MiB: not a settings file", MAX_SETTINGS_BYTES >> 20),
        });
    }
    String::from_utf8(bytes)
        .map_err(|_| read(std::io::Error::new(std::io::ErrorKind::InvalidData, "stream did not contain valid UTF-8")))
}

/// The line (1-based) of the dotted key `path` in TOML `text`, where it is written as
/// `key = ...` under its table's header (`[a.b]` then `c = ...` for `a.b.c`); `None` when
/// it is spelled another way or not written (a default).
pub fn line_of(text: &str, path: &str) -> Option<usize> {
    // Array indices (`initial_pose_sigma[2]`) point at the array's own line.
    let path = path.split('[').next().unwrap_or(path);
    let mut table = String::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if let Some(header) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            table = header.trim_matches(['[', ']', ' ']).to_string();
            continue;
        }
        let Some((key, _)) = line.split_once('=') else { continue };
        let key = key.trim().trim_matches('"');
        let full = if table.is_empty() { key.to_string() } else { format!("{table}.{key}") };
        if full == path {
            return Some(i + 1);
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file far larger than any scenario (a device, a log given by mistake) is refused
    /// after a bounded read, not read without end.
    #[test]
    fn a_huge_file_is_not_read_as_a_scenario() {
        let e = Scenario::load("/dev/zero").unwrap_err().to_string();
        assert!(e.contains("/dev/zero") && e.contains("larger than 16 MiB"), "{e}");
    }

    #[test]
    fn an_array_of_tables_is_named_as_such() {
        let text = "name = \"t\"\n[world]\npreset = \"park\"\n[[sim.laser]]\nrate_hz = 5.0\n";
        let e = Scenario::parse(text, Path::new("arr.toml")).unwrap_err().to_string();
        assert!(
            e.contains("arr.toml: line 4: `[[sim.laser]]` starts an array of tables")
                && e.contains("write `[sim.laser]`"),
            "{e}"
        );
    }

    #[test]
    fn a_name_too_long_for_its_output_directory_is_refused() {
        let text = format!("name = \"{}\"\n[world]\npreset = \"park\"\n", "a".repeat(300));
        let e = Scenario::parse(&text, Path::new("long.toml")).unwrap_err().to_string();
        assert!(e.contains("long.toml: line 1: name: must be at most 100 characters, got 300"), "{e}");
    }

    #[test]
    fn every_library_scenario_parses_and_builds_its_world() {
        for (name, _) in LIBRARY {
            let (s, base) = Scenario::load(name).unwrap();
            assert_eq!(&s.name, name);
            let world = s.world(&base, s.seed).unwrap();
            let problems = worlds::validate::validate(&world, &base);
            assert!(problems.is_empty(), "{name}: {problems:?}");
            // `<built-in>/NAME`, as a study pins it, is the same scenario.
            assert_eq!(Scenario::load(&format!("<built-in>/{name}")).unwrap().0, s);
            assert_eq!(s.built_in(), Some(*name));
        }
        let file = std::env::temp_dir().join(format!("objslam-built-in-{}.toml", std::process::id()));
        std::fs::write(&file, LIBRARY[0].1).unwrap();
        let from_file = Scenario::load(file.to_str().unwrap()).unwrap().0;
        std::fs::remove_file(&file).unwrap();
        assert_eq!(from_file.built_in(), None, "read from a file, though its text is a built-in's");
        assert!(matches!(Scenario::load("<built-in>/no_such"), Err(ScenarioError::Unknown { .. })));
    }

    /// A world seed beside a world file is refused (a file is one world), and a
    /// `[calibration]` table may leave out its mode, which is then "true".
    #[test]
    fn a_seed_for_a_world_file_is_refused_and_a_calibration_table_defaults_its_mode() {
        let e = Scenario::parse("name = \"s\"\n[world]\nfile = \"w.toml\"\nseed = 3\n", Path::new("s.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("world.seed") && e.contains("only applies to a preset"), "{e}");
        let s = Scenario::parse(
            "name = \"s\"\n[world]\npreset = \"park\"\n[calibration]\nrotation_sigma_deg = 0.0\n",
            Path::new("s.toml"),
        )
        .unwrap();
        assert_eq!(s.calibration.mode, "true");
    }

    /// The calibration session is checked against the laser only where a run runs it
    /// (a low laser had been refused for a session it never ran), and a session of fewer
    /// poses than a calibration needs is refused when the file is read, not by the run.
    #[test]
    fn the_calibration_session_is_checked_against_the_sensors_only_where_it_runs() {
        let text = |mode: &str, poses: usize| {
            format!(
                "name = \"s\"\n[world]\npreset = \"park\"\n[sim.laser]\nmount_xyz_m = [0.16, 0.0, 0.2]\n\
                 [calibration]\nmode = \"{mode}\"\n[calibration.session]\nposes = {poses}\n"
            )
        };
        Scenario::parse(&text("true", 20), Path::new("s.toml")).unwrap();
        // A camera too small for a patch, for a method that trains its model on it.
        let tiny = "name = \"s\"\n[world]\npreset = \"park\"\n[sim.camera]\nwidth = 8\nheight = 8\n";
        let e = Scenario::parse(tiny, Path::new("s.toml")).unwrap_err().to_string();
        assert!(e.contains("s.toml") && e.contains("sim.camera.width") && e.contains("9x9"), "{e}");
        let tiny_nn = format!("{tiny}[pipeline]\nmethod = \"nn\"\n");
        let s = Scenario::parse(&tiny_nn, Path::new("s.toml")).unwrap();
        // A camera method asked for the run is checked before anything trains.
        let combined = Some(slam::association::AssociationMethod::Combined);
        let e = crate::run::preflight(&s, Path::new("."), combined, None).map(|_| ()).expect_err("refused").to_string();
        assert!(e.contains("s.toml") && e.contains("sim.camera.width") && e.contains("combined"), "{e}");
        let e = Scenario::parse(&text("estimated", 20), Path::new("s.toml")).unwrap_err().to_string();
        assert!(e.contains("calibration.session.centre_height_m") && e.contains("laser's plane"), "{e}");
        for mode in ["true", "estimated"] {
            let e = Scenario::parse(&text(mode, 2), Path::new("s.toml")).unwrap_err().to_string();
            assert!(e.contains("calibration.session.poses") && e.contains("at least 5"), "{e}");
        }
    }

    /// city_park is the size it says: ten times paper_park's ground, with its objects.
    #[test]
    fn city_park_is_a_park_ten_times_the_papers() {
        let (s, base) = Scenario::load("city_park").unwrap();
        let world = s.world(&base, s.seed).unwrap();
        let count = |class| world.objects.iter().filter(|o| o.class == class).count();
        use worlds::ObjectClass::*;
        assert_eq!((count(Tree), count(Post), count(Palm), count(Wall)), (120, 40, 10, 1));
        assert_eq!(world.people.len(), 30);
        let [w, h] = [world.ground.max_m[0] - world.ground.min_m[0], world.ground.max_m[1] - world.ground.min_m[1]];
        assert!((w * h - 6000.0).abs() < 1.0, "{} m²", w * h);
    }

    /// The default scenario parses back to itself, and docs/reference/scenario.md shows
    /// exactly what `objslam config defaults` prints (regenerate it with
    /// `OBJSLAM_WRITE_REFERENCE=1 cargo test -p scenarios defaults`).
    #[test]
    fn defaults_parse_back_and_the_reference_page_agrees() {
        let text = Scenario::defaults_toml(None).unwrap();
        let parsed = Scenario::parse(&text, Path::new("defaults.toml")).unwrap();
        assert_eq!(parsed, Scenario::with_defaults("my_scenario"));
        // The pass criteria, all commented out, come last.
        let pass = text.split_once("\n[pass]\n").map(|(_, rest)| rest).unwrap_or_default();
        assert!(pass.contains("# min_tree_recall = ") && !pass.contains("\n[") && !pass.contains("\n# ["), "{text}");
        let evidence = Scenario::defaults_toml(Some("pipeline.evidence")).unwrap();
        assert!(evidence.contains("radius_m = 0.3"), "{evidence}");
        assert!(Scenario::defaults_toml(Some("pipeline.nothing")).is_err());
        assert!(Scenario::defaults_toml(Some("seed")).is_err());
        let page = format!(
            "# Scenario reference\n\nEvery setting of a scenario file at its default, as `objslam config defaults` prints it,\neach after a comment saying what it means, in what unit and, where it is checked, its valid\nrange. Settings without a default (the pass criteria, optional files, seeds and tables, the\ncar-like motion model) are commented out with an example value. Generated from the code\n(`scenarios/src/scenario/keys.rs`); a test checks this page agrees. How scenarios are\nwritten and run: [scenarios](../guide/scenarios.md) and [runs and metrics](../guide/runs-and-metrics.md).\n\n```toml\n{text}```\n"
        );
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/reference/scenario.md");
        if std::env::var_os("OBJSLAM_WRITE_REFERENCE").is_some() {
            std::fs::write(&file, &page).unwrap();
        }
        let on_disk = std::fs::read_to_string(&file).unwrap_or_default();
        assert!(
            on_disk == page,
            "{} is out of date: OBJSLAM_WRITE_REFERENCE=1 cargo test -p scenarios defaults",
            file.display()
        );
    }

    #[test]
    fn malformed_scenarios_get_clear_errors() {
        let f = Path::new("bad.toml");
        let e = Scenario::parse("name = \"x\"\n[world]\npreset = \"jungle\"\n", f).unwrap_err().to_string();
        assert!(e.contains("bad.toml") && e.contains("world.preset") && e.contains("jungle"), "{e}");
        let e = Scenario::parse("name = \"x\"\n[world]\n", f).unwrap_err().to_string();
        assert!(e.contains("needs `preset`"), "{e}");
        let e = Scenario::parse("name = \"x\"\n[world]\npreset = \"park\"\n[sim.laser]\nrate_hz = -1.0\n", f)
            .unwrap_err()
            .to_string();
        assert!(e.contains("laser.rate_hz"), "{e}");
        let e = Scenario::parse("name = \"x\"\n[world]\npreset = \"park\"\n[pass]\nmin_tree_recall = 2.0\n", f)
            .unwrap_err()
            .to_string();
        assert!(e.contains("min_tree_recall"), "{e}");
        let e = Scenario::parse("name = \"x\"\nwrld = 3\n", f).unwrap_err().to_string();
        assert!(e.contains("wrld") && e.contains("line"), "{e}");
        let e = Scenario::parse(
            "name = \"x\"\n[world]\npreset = \"park\"\n\n[pipeline.evidence]\n# a comment\nradius_m = -1.0\n",
            f,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("bad.toml: line 7: pipeline.evidence.radius_m"), "{e}");
        for name in ["../../x", "a/b", "", ".hidden"] {
            let e =
                Scenario::parse(&format!("name = {name:?}\n[world]\npreset = \"park\"\n"), f).unwrap_err().to_string();
            assert!(e.contains("line 1: name"), "{name}: {e}");
        }
        // Settings that a run would replace or reject later are refused when read.
        let base = "name = \"x\"\n[world]\npreset = \"park\"\n";
        for (table, expect) in [
            (
                "[calibration]\nmode = \"perturbed\"\ntranslation_sigma_m = 1e12\n",
                "line 6: calibration.translation_sigma_m: must be at most 10",
            ),
            (
                "[calibration]\nmode = \"perturbed\"\nrotation_sigma_deg = 1e9\n",
                "line 6: calibration.rotation_sigma_deg: must be at most 180",
            ),
            ("[appearance]\ntraining_images = 0\n", "line 5: appearance.training_images"),
            ("[appearance]\ntraining_preset = \"jungle\"\n", "line 5: appearance.training_preset"),
            ("[appearance]\nmax_patches_per_class = 0\n", "line 5: appearance.max_patches_per_class"),
            ("[appearance]\ntraining_worlds = 0\n", "line 5: appearance.training_worlds: must be 1 to 1000"),
            (
                "[appearance]\ntraining_images = 4\ntraining_worlds = 5\n",
                "line 6: appearance.training_worlds: 5 worlds for 4 training images",
            ),
            (
                "[appearance]\nmodel = \"m.json\"\ntraining_seed = 3\n",
                "line 6: appearance.training_seed: only applies to a model trained by the run",
            ),
            ("[pipeline.sensor]\nmount_x = 1.0\n", "line 5: pipeline.sensor.mount_x"),
            ("[pipeline.object_model]\nmosaic_patches = 400\n", "line 5: pipeline.object_model.mosaic_patches"),
            ("[pipeline.motion]\nmodl = \"ackermann\"\n", "unknown field `modl`"),
            (
                "[pipeline.motion]\nmodel = \"ackermann\"\nwheelbase_m = 0.4\n",
                "line 5: pipeline.motion.model: \"ackermann\" reads a car's speed and steering",
            ),
            ("[calibration]\nmode = \"ture\"\n", "line 5: calibration.mode: unknown mode \"ture\""),
            // An array longer than its field, which toml alone would cut short.
            (
                "[sim.laser]\nmount_xyz_m = [0.16, 0.0, 0.4, 9.0]\n",
                "line 5: sim.laser.mount_xyz_m: 4 elements, more than",
            ),
            ("[world.params]\ntree_radius_m = [0.1, 0.2, 0.3]\n", "line 5: world.params.tree_radius_m: 3 elements"),
            (
                "[pipeline]\ninitial_pose_sigma = [0.1, 0.1, 0.1, 0.1]\n",
                "line 5: pipeline.initial_pose_sigma: 4 elements",
            ),
        ] {
            let e = Scenario::parse(&format!("{base}{table}"), f).unwrap_err().to_string();
            assert!(e.contains(expect), "{table}: {e}");
        }
        // The filter's mounting may repeat the laser's.
        Scenario::parse(
            &format!("{base}[sim.laser]\nmount_xyz_m = [0.3, 0.0, 0.4]\n[pipeline.sensor]\nmount_x = 0.3\n"),
            f,
        )
        .unwrap();
        let yawed = Scenario::parse(&format!("{base}[sim.laser]\nmount_yaw_deg = 10.0\n"), f).unwrap();
        crate::run::pipeline_config(&yawed, None).expect("recording a yawed laser is fine");
        let e = crate::run::run_config(&yawed, None).unwrap_err().to_string();
        assert!(e.contains(&format!("{}: sim.laser.mount_yaw_deg = 10", f.display())), "{e}");
        let e = Scenario::load("no_such_scenario").unwrap_err().to_string();
        assert!(e.contains("paper_park"), "{e}");
    }
}
