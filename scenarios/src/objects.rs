//! A run's `objects/` directory: each mapped object's appearance mosaic (the paper's
//! figure 3, right) and its model, and "find objects that look like this" over them.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
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
    /// Several files of `objects/` could not be written (each was tried).
    #[error("{} files of objects/ could not be written: {}", .0.len(), crate::run::join_errors(.0))]
    Several(Vec<ObjectsError>),
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

/// Writes `objects/landmark_<id>.png` (mosaic) for each mapped object with a model,
/// `objects/models.json` and the appearance model. Returns the number of mosaics written.
/// A file that cannot be written stops no other; every failure is reported.
pub fn write_objects(dir: &Path, pipeline: &Pipeline) -> Result<usize, ObjectsError> {
    let Some(app) = pipeline.appearance() else { return Ok(0) };
    let out = dir.join(crate::files::OBJECTS_DIR);
    std::fs::create_dir_all(&out).map_err(|e| file_err(&out, e))?;
    let landmarks = pipeline.mapped_landmarks();
    let modelled: Vec<_> =
        landmarks.iter().filter_map(|lm| pipeline.object_model(lm.id).map(|model| (lm, model))).collect();
    // Each mosaic is drawn and compressed on its own (a run's end waits for them all).
    let pictures: Vec<Result<bool, ObjectsError>> = modelled
        .par_iter()
        .map(|(lm, model)| {
            let file = out.join(format!("landmark_{}.png", lm.id));
            let picture = mosaic_picture(lm.id, &lm.class, model, &app.model().extractor);
            let Some((w, h, rgb)) = picture.map_err(|e| file_err(&file, e))? else {
                return Ok(false);
            };
            image::save_buffer(&file, &rgb, w, h, image::ExtendedColorType::Rgb8).map_err(|e| file_err(&file, e))?;
            Ok(true)
        })
        .collect();
    let mut written = 0;
    let mut errors = Vec::new();
    for picture in pictures {
        match picture {
            Ok(drawn) => written += drawn as usize,
            Err(e) => errors.push(e),
        }
    }
    let models: Vec<_> = modelled.iter().map(|(lm, model)| (lm.id, (*model).clone())).collect();
    let file = out.join(crate::files::OBJECT_MODELS);
    let json = serde_json::to_string(&ObjectModels { format_version: OBJECT_MODELS_FORMAT_VERSION, objects: models })
        .expect("JSON");
    errors.extend(std::fs::write(&file, json).err().map(|e| file_err(&file, e)));
    // The appearance model too, so `objslam find` works from the run directory alone.
    errors.extend(app.model().save(&out.join(crate::files::APPEARANCE_MODEL)).err().map(ObjectsError::from));
    crate::run::first_or_all(errors, ObjectsError::Several).map(|()| written)
}

/// Height of a mosaic picture's caption, pixels.
const CAPTION_H: u32 = 48;

/// An object's mosaic as a picture to read: its best view's patches as the camera saw
/// them beside their reconstruction through the PCA (the paper's figure 3), each enlarged
/// to a readable size with the patch grid drawn, under a caption with its id and class.
/// The reconstruction keeps only the d leading principal components of colour and texture
/// together, so its colours lean towards the training images' mean (bark comes out olive
/// among grass and leaves); the view as seen shows the true colours. `None` without patches; a model whose mosaic does
/// not fit `extractor`, or a caption that cannot be drawn, is an error.
pub fn mosaic_picture(
    id: u32,
    class: &str,
    model: &ObjectModel,
    extractor: &slam::features::FeatureExtractor,
) -> Result<Option<(u32, u32, Vec<u8>)>, String> {
    let l = extractor.config.patch_size;
    let (mw, mh, modelled) = object_model::render_mosaic(&model.mosaic, extractor).map_err(|e| e.to_string())?;
    if mw == 0 || mh == 0 {
        return Ok(None);
    }
    let seen = object_model::render_mosaic_as_seen(&model.mosaic, l);
    let scale = 160u32.div_ceil(mw).clamp(3, 8);
    let (pw, ph) = (mw * scale, mh * scale);
    let (margin, gap) = (12u32, 24u32);
    let panels: Vec<(&str, &[u8])> = match &seen {
        Some((_, _, rgb)) => vec![("as seen", rgb.as_slice()), ("PCA reconstruction", modelled.as_slice())],
        None => vec![("PCA reconstruction", modelled.as_slice())],
    };
    let width = (2 * margin + panels.len() as u32 * pw + (panels.len() as u32 - 1) * gap).max(320);
    let height = CAPTION_H + ph + margin;
    let mut out = vec![255u8; (width * height * 3) as usize];
    for (k, (_, rgb)) in panels.iter().enumerate() {
        let x0 = margin + k as u32 * (pw + gap);
        for y in 0..ph {
            for x in 0..pw {
                let (sx, sy) = (x / scale, y / scale);
                let on_grid = x % (l * scale) == 0 || y % (l * scale) == 0;
                let src = ((sy * mw + sx) * 3) as usize;
                let dst = (((CAPTION_H + y) * width + x0 + x) * 3) as usize;
                let px = if on_grid { [40, 40, 40] } else { [rgb[src], rgb[src + 1], rgb[src + 2]] };
                out[dst..dst + 3].copy_from_slice(&px);
            }
        }
    }
    // The caption, drawn over the buffer.
    crate::plot::register_fonts();
    {
        use plotters::prelude::*;
        let caption = |e: DrawingAreaErrorKind<_>| format!("drawing the caption: {e}");
        let root = BitMapBackend::with_buffer(&mut out, (width, height)).into_drawing_area();
        let title = format!(
            "landmark {id} ({class}): {} patches of {l} px, {} views",
            model.mosaic.cells.len(),
            model.observations
        );
        root.draw(&Text::new(title, (margin as i32, 6), ("sans-serif", 14).into_font())).map_err(caption)?;
        for (k, (label, _)) in panels.iter().enumerate() {
            let x0 = (margin + k as u32 * (pw + gap)) as i32;
            root.draw(&Text::new(label.to_string(), (x0, 26), ("sans-serif", 13).into_font())).map_err(caption)?;
        }
        root.present().map_err(caption)?;
    }
    Ok(Some((width, height, out)))
}

/// The layout of `objects/models.json` that this build writes and reads.
pub const OBJECT_MODELS_FORMAT_VERSION: u32 = 1;

/// The object models of `objects/models.json` (`file`), checked: this layout, each landmark
/// once, each a sound mixture over the same appearance coordinates and then dx, dy and h.
/// Returns the models and how many appearance coordinates they describe (the run's
/// `object_model.appearance_dims`, whatever it was).
pub fn read_object_models(file: &Path) -> Result<(ObjectModels, usize), ObjectsError> {
    let text = std::fs::read_to_string(file).map_err(|e| file_err(file, e))?;
    let models: ObjectModels =
        slam::settings::from_json(&text).map_err(|e| file_err(file, format!("not an objects/models.json: {e}")))?;
    if models.format_version != OBJECT_MODELS_FORMAT_VERSION {
        return Err(file_err(
            file,
            format!(
                "format_version {}, this objslam reads version {OBJECT_MODELS_FORMAT_VERSION}",
                models.format_version
            ),
        ));
    }
    let mut appearance_dims = None;
    let mut seen = std::collections::BTreeSet::new();
    for (id, m) in &models.objects {
        let bad = |problem: String| file_err(file, format!("landmark {id}: {problem}"));
        if !seen.insert(*id) {
            return Err(bad("listed twice".into()));
        }
        let dims = m.gmm.dims();
        // The appearance coordinates, then dx, dy and h (see `ObjectModel::gmm`).
        if dims < 4 {
            return Err(bad(format!(
                "a mixture of {dims} dimensions; an object model has its appearance coordinates and then dx, dy and h"
            )));
        }
        if *appearance_dims.get_or_insert(dims - 3) != dims - 3 {
            return Err(bad(format!(
                "{} appearance dimensions where the landmarks before it have {}",
                dims - 3,
                appearance_dims.unwrap_or_default()
            )));
        }
        m.gmm.evaluator().map_err(|e| bad(e.to_string()))?;
    }
    Ok((models, appearance_dims.unwrap_or(0)))
}

/// "Find objects that look like this": classifies the example image's patches, fits an
/// appearance density to its object patches, and ranks a run's mapped objects by the
/// appearance-only KL divergence (smallest first), over the appearance coordinates the
/// run's object models describe.
pub fn find_similar(run_dir: &Path, model: &AppearanceModel, example: &Path) -> Result<Vec<(u32, f64)>, ObjectsError> {
    let file = run_dir.join(crate::files::OBJECTS_DIR).join(crate::files::OBJECT_MODELS);
    let (models, appearance_dims) = read_object_models(&file)?;
    if appearance_dims > model.extractor.pca.dims() {
        return Err(file_err(
            &file,
            format!(
                "its object models describe {appearance_dims} appearance coordinates; the appearance model's PCA has {}",
                model.extractor.pca.dims()
            ),
        ));
    }
    let rgb = crate::train::open_image_to_classify(example).map_err(|e| ObjectsError::Object(e.to_string()))?;
    let (w, h) = rgb.dimensions();
    let image = ImageRef::new(w, h, rgb.as_raw()).map_err(|e| file_err(example, e))?;
    let f = model.extractor.features(&image, None).map_err(|e| file_err(example, e))?;
    let classifier = PatchClassifier::new(model).map_err(ModelError::from)?;
    let rows: Vec<usize> = classifier
        .classify(&f)
        .map_err(|e| file_err(example, e))?
        .into_iter()
        .enumerate()
        .filter(|(_, o)| *o)
        .map(|(i, _)| i)
        .collect();
    if rows.len() < 2 {
        return Err(file_err(
            example,
            format!("only {} patches look like the object class; nothing to compare", rows.len()),
        ));
    }
    let da = appearance_dims;
    if da == 0 {
        return Ok(Vec::new());
    }
    let data = nalgebra::DMatrix::from_fn(rows.len(), da, |i, j| f.z[(rows[i], j)]);
    let vb = slam::gmm::fit(&data, None, &slam::gmm::VbOptions { max_components: 1, ..Default::default() })
        .map_err(|e| ObjectsError::Object(e.to_string()))?;
    let example_model = slam::gmm::StudentTMixture::new(&vb)
        .and_then(|t| t.gaussian_approximation())
        .map_err(|e| ObjectsError::Object(e.to_string()))?;
    let refs: Vec<(u32, &ObjectModel)> = models.objects.iter().map(|(id, m)| (*id, m)).collect();
    object_model::rank_by_appearance(&example_model, &refs).map_err(|e| file_err(&file, e))
}
