//! A run's `objects/` directory: each mapped object's appearance mosaic (the paper's
//! figure 3, right) and its model, and "find objects that look like this" over them.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use slam::classifier::{AppearanceModel, ModelError, PatchClassifier};
use slam::features::ImageRef;
use slam::object_model::{self, ObjectModel};
use slam::pipeline::Pipeline;

#[derive(Debug, thiserror::Error)]
pub enum ObjectsError {
    #[error("{}: {message}", file.display())]
    File { file: PathBuf, message: String },
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("{0}")]
    Object(String),
}

fn file_err(file: &Path, message: impl ToString) -> ObjectsError {
    ObjectsError::File { file: file.to_path_buf(), message: message.to_string() }
}

/// `objects/models.json`: every mapped object's model, by landmark id.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ObjectModels {
    pub format_version: u32,
    pub objects: Vec<(u32, ObjectModel)>,
}

/// Writes `objects/landmark_<id>.png` (mosaic) for each mapped object with a model, and
/// `objects/models.json`. Returns the number of mosaics written.
pub fn write_objects(dir: &Path, pipeline: &Pipeline) -> Result<usize, ObjectsError> {
    let Some(app) = pipeline.appearance() else { return Ok(0) };
    let out = dir.join("objects");
    std::fs::create_dir_all(&out).map_err(|e| file_err(&out, e))?;
    let mut models = Vec::new();
    let mut written = 0;
    for lm in pipeline.mapped_landmarks() {
        let Some(model) = pipeline.object_model(lm.id) else { continue };
        let (w, h, rgb) = object_model::render_mosaic(&model.mosaic, &app.model.extractor);
        if w > 0 && h > 0 {
            let file = out.join(format!("landmark_{}.png", lm.id));
            image::save_buffer(&file, &rgb, w, h, image::ExtendedColorType::Rgb8).map_err(|e| file_err(&file, e))?;
            written += 1;
        }
        models.push((lm.id, model.clone()));
    }
    let file = out.join("models.json");
    std::fs::write(&file, serde_json::to_string(&ObjectModels { format_version: 1, objects: models }).expect("JSON"))
        .map_err(|e| file_err(&file, e))?;
    // The appearance model too, so `objslam find` works from the run directory alone.
    app.model.save(&out.join("appearance_model.json"))?;
    Ok(written)
}

/// "Find objects that look like this": classifies the example image's patches, fits an
/// appearance density to its object patches, and ranks a run's mapped objects by the
/// appearance-only KL divergence (smallest first).
pub fn find_similar(
    run_dir: &Path,
    model: &AppearanceModel,
    example: &Path,
    appearance_dims: usize,
) -> Result<Vec<(u32, f64)>, ObjectsError> {
    let file = run_dir.join("objects").join("models.json");
    let text = std::fs::read_to_string(&file).map_err(|e| file_err(&file, e))?;
    let models: ObjectModels =
        serde_json::from_str(&text).map_err(|e| file_err(&file, format!("not an objects/models.json: {e}")))?;
    let rgb = image::open(example).map_err(|e| file_err(example, e))?.to_rgb8();
    let (w, h) = rgb.dimensions();
    let image = ImageRef::new(w, h, rgb.as_raw()).map_err(ModelError::from)?;
    let f = model.extractor.features(&image, None).map_err(ModelError::from)?;
    let classifier = PatchClassifier::new(model).map_err(ModelError::from)?;
    let rows: Vec<usize> =
        classifier.classify(&f).into_iter().enumerate().filter(|(_, o)| *o).map(|(i, _)| i).collect();
    if rows.len() < 2 {
        return Err(file_err(
            example,
            format!("only {} patches look like the object class; nothing to compare", rows.len()),
        ));
    }
    let da = appearance_dims.min(f.z.ncols());
    let data = nalgebra::DMatrix::from_fn(rows.len(), da, |i, j| f.z[(rows[i], j)]);
    let vb = slam::gmm::fit(&data, None, &slam::gmm::VbOptions { max_components: 1, ..Default::default() })
        .map_err(|e| ObjectsError::Object(e.to_string()))?;
    let example_model = slam::gmm::StudentTMixture::new(&vb)
        .and_then(|t| t.gaussian_approximation())
        .map_err(|e| ObjectsError::Object(e.to_string()))?;
    let refs: Vec<(u32, &ObjectModel)> = models.objects.iter().map(|(id, m)| (*id, m)).collect();
    object_model::rank_by_appearance(&example_model, &refs).map_err(|e| ObjectsError::Object(e.to_string()))
}
