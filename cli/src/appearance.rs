//! `objslam train`, `segment`, `find` and `gmm`: the appearance model, its mixtures and
//! what it finds.

use anyhow::{Context, Result};
use scenarios::files;
use slam::classifier::score_text;

use crate::progress;

/// `objslam train`.
pub(crate) fn train(args: &crate::args::TrainArgs) -> Result<()> {
    let crate::args::TrainArgs { dataset, out, pca_dims, max_components, heldout_every, threshold, seed, .. } = args;
    let (dataset, out, heldout_every) = (dataset.as_path(), out.as_path(), *heldout_every);
    anyhow::ensure!((0.0..=1.0).contains(threshold), "--threshold must lie in [0, 1], got {threshold}");
    crate::paths::writable_file("--out", out)?;
    for (flag, file) in [("--export-features", &args.export_features), ("--heldout-report", &args.heldout_report)] {
        if let Some(file) = file {
            crate::paths::writable_file(flag, file)?;
        }
    }
    // No output replaces a dataset's file or another output.
    let outputs: Vec<(&str, &std::path::Path)> = [
        ("--out", Some(out)),
        ("--export-features", args.export_features.as_deref()),
        ("--heldout-report", args.heldout_report.as_deref()),
    ]
    .into_iter()
    .filter_map(|(flag, file)| Some((flag, file?)))
    .collect();
    for (i, (flag, file)) in outputs.iter().enumerate() {
        if let Some(d) = std::iter::once(dataset)
            .chain(args.heldout_dataset.iter().map(|p| p.as_path()))
            .find(|d| scenarios::dataset::owns(d, file))
        {
            anyhow::bail!(
                "{flag} {}: a file of the dataset {}, which it would replace; write it elsewhere",
                file.display(),
                d.display()
            );
        }
        if let Some((other, _)) = outputs[..i].iter().find(|(_, o)| scenarios::partial_files::same_path(o, file)) {
            anyhow::bail!("{flag} {}: {other} writes there too; give each its own file", file.display());
        }
    }
    let options = slam::classifier::TrainingOptions {
        pca_dims: *pca_dims,
        seed: *seed,
        threshold: *threshold,
        distractors: args.distractors,
        context: args.context,
        vb: slam::gmm::VbOptions { max_components: *max_components, ..Default::default() },
        ..Default::default()
    };
    // The other worlds' datasets are read and checked before the training, not after it
    // (see `read_heldout_manifest`): not the training's own world, its classes, the
    // model's patches, and some images.
    let trained_on = scenarios::train::read_manifest(dataset)?;
    // Scored twice, one world would count twice in the held-out figures.
    for (i, other) in args.heldout_dataset.iter().enumerate() {
        if let Some(earlier) = args.heldout_dataset[..i].iter().find(|e| scenarios::partial_files::same_path(e, other))
        {
            anyhow::bail!(
                "--heldout-dataset {}: given twice (also as {}); each world is scored once",
                other.display(),
                earlier.display()
            );
        }
    }
    for other in &args.heldout_dataset {
        scenarios::train::read_heldout_manifest(other, dataset, &trained_on, trained_on.patch_size)
            .map_err(|e| anyhow::anyhow!("--heldout-dataset {e}"))?;
    }
    let bar = progress::training("train");
    let started = std::time::Instant::now();
    let (model, classes) =
        scenarios::train::train_from_dataset(dataset, &options, heldout_every, |stage, done, total| {
            progress::set_training(&bar, stage, done, total)
        })?;
    bar.finish_and_clear();
    crate::paths::write_whole(out, model.to_json())?;
    let t = &model.training;
    println!("trained on {} images in {:.1} s -> {}", t.images, started.elapsed().as_secs_f64(), out.display());
    println!(
        "  PCA: {} -> {} dimensions, {:.1}% of the variance",
        model.extractor.config.raw_dims(),
        model.extractor.pca.dims(),
        100.0 * t.pca_explained_variance
    );
    println!(
        "  object: {} patches ({} fitted), {} components; background: {} patches ({} fitted), {} components; w_obj = {:.3}",
        t.object_patches,
        t.fitted_object_patches,
        model.object.effective_components(1e-3),
        t.background_patches,
        t.fitted_background_patches,
        model.background.effective_components(1e-3),
        model.object_weight
    );
    match &t.heldout {
        Some(s) => println!(
            "  held-out patches: precision {}, recall {}, F1 {} ({} object patches of {})",
            score_text(s.defined_precision()),
            score_text(s.defined_recall()),
            score_text(s.defined_f1()),
            s.true_positives + s.false_negatives,
            s.true_positives + s.false_negatives + s.false_positives + s.true_negatives
        ),
        None if heldout_every == 0 => println!("  no held-out images (--heldout-every 0)"),
        None => println!(
            "  no held-out images: every {heldout_every}th image is held out, and the dataset has too few (--heldout-every)"
        ),
    }
    if t.heldout.is_some() {
        println!("  held-out patches called object, by true class: {}", class_shares(&classes));
    }
    if let Some(s) = &t.foliage_heldout {
        println!(
            "  foliage ({} patches, {} components), held out: precision {}, recall {}, F1 {}",
            t.foliage_patches,
            model.foliage.as_ref().map_or(0, |f| f.gmm.effective_components(1e-3)),
            score_text(s.defined_precision()),
            score_text(s.defined_recall()),
            score_text(s.defined_f1())
        );
    }
    if let Some(d) = &model.distractors {
        println!(
            "  distractors: {} patches ({:.1}% of the background), {} components",
            t.distractor_patches,
            100.0 * d.weight,
            d.gmm.effective_components(1e-3)
        );
    }
    if let Some(c) = &model.context {
        let w = c.weights;
        println!(
            "  column context ({} images, {} patches): {:.3} x own log-odds {:+.3}, above {:.3}, below {:.3}, \
             mean of 2-{} above {:.3}, below {:.3}",
            c.images, c.patches, w[0], w[1], w[2], w[3], c.reach, w[4], w[5]
        );
    }
    let mut worlds = Vec::new();
    for other in &args.heldout_dataset {
        let w = scenarios::train::score_on_dataset(other, &model, options.label_fraction)?;
        println!(
            "  held-out world {} ({} images, {}): precision {}, recall {}, F1 {}; called object: {}",
            w.world,
            w.images,
            other.display(),
            score_text(w.precision),
            score_text(w.recall),
            score_text(w.f1),
            class_shares(&w.by_class)
        );
        worlds.push(w);
    }
    if let Some(file) = &args.heldout_report {
        crate::paths::write_whole(file, serde_json::to_string_pretty(&worlds)? + "\n")
            .with_context(|| format!("{}: cannot write", file.display()))?;
    }
    if let Some(csv) = &args.export_features {
        let rows = scenarios::train::export_features(dataset, &model, options.label_fraction, csv)?;
        println!("  {rows} feature rows -> {}", csv.display());
    }
    Ok(())
}

/// "tree 80/100 (80.0%), post 3/50 (6.0%)": per true class, the patches called object.
fn class_shares(by_class: &scenarios::train::ClassTable) -> String {
    let parts: Vec<String> = by_class
        .iter()
        .map(|(name, (n, obj))| format!("{name} {obj}/{n} ({:.1}%)", 100.0 * *obj as f64 / (*n).max(1) as f64))
        .collect();
    parts.join(", ")
}

/// `objslam segment`.
pub(crate) fn segment(model: &std::path::Path, image: &std::path::Path, out: &std::path::Path) -> Result<()> {
    crate::paths::not_an_input("--out", out, &[("image", image), ("model", model)])?;
    let model = slam::classifier::AppearanceModel::load(model)?;
    let (objects, total) = scenarios::train::segment_image(&model, image, out)?;
    println!("{objects} of {total} patches classified as object -> {}", out.display());
    Ok(())
}

/// `objslam gmm fit`.
pub(crate) fn gmm_fit(data: &std::path::Path, options: &slam::gmm::VbOptions, out: &std::path::Path) -> Result<()> {
    crate::paths::not_an_input("--out", out, &[("data", data)])?;
    crate::paths::writable_file("--out", out)?;
    let started = std::time::Instant::now();
    let (model, digest) = scenarios::train::gmm_fit_csv(data, options)?;
    let secs = started.elapsed().as_secs_f64();
    // The mixture, and how it was fitted (`gmm score` scores the mixture and checks `fit`
    // is whole): the same data and `fit.options` fit the same model again.
    let record = scenarios::train::GmmFitRecord::new(data, digest, options);
    crate::paths::write_whole(out, scenarios::train::gmm_model_file(&model, &record))?;
    println!("{} points x {} dimensions, fitted in {secs:.2} s", model.points, model.dims());
    println!(
        "  lower bound: {:.6} nats (full PRML 10.70 bound on ln p(X), all constant terms included; {:.6} per point)",
        model.lower_bound,
        model.lower_bound / model.points as f64
    );
    println!(
        "  components: {} with weight above 1e-3 ({} kept)",
        model.effective_components(1e-3),
        model.components.len()
    );
    println!("  VBEM iterations: {}", model.iterations);
    println!("  -> {}", out.display());
    Ok(())
}

/// `objslam gmm score`.
pub(crate) fn gmm_score(model: &std::path::Path, data: &std::path::Path) -> Result<()> {
    let (mean, points) = scenarios::train::gmm_score_csv(model, data)?;
    println!("{points} points of {} under {}", data.display(), model.display());
    println!("mean held-out log-likelihood: {mean:.6} nats per point (posterior predictive, PRML 10.81)");
    Ok(())
}

/// `objslam find`.
pub(crate) fn find(
    run: &std::path::Path,
    image: &std::path::Path,
    model: Option<&std::path::Path>,
    top: usize,
) -> Result<()> {
    anyhow::ensure!(top >= 1, "--top must be at least 1, got 0");
    let runs_model = run.join(files::OBJECTS_DIR).join(files::APPEARANCE_MODEL);
    if !run.is_dir() {
        anyhow::bail!(
            "--run {}: {}; give the directory of an `objslam run` of a camera method",
            run.display(),
            if run.exists() { "not a directory" } else { "no such directory" }
        );
    }
    if !run.join(files::OBJECTS_DIR).join(files::OBJECT_MODELS).is_file() {
        anyhow::bail!(
            "{}: no objects/models.json: give the directory of an `objslam run` of a camera method (position-only methods describe no object's appearance)",
            run.display()
        );
    }
    let model_path = model.map(std::path::Path::to_path_buf).unwrap_or_else(|| runs_model.clone());
    let model = slam::classifier::AppearanceModel::load(&model_path)?;
    // The run's object models live in its model's feature space (its PCA): another
    // model's features would be compared with them as if they were the same numbers.
    if model_path != runs_model && runs_model.is_file() {
        let own = slam::classifier::AppearanceModel::load(&runs_model)?;
        if own.extractor != model.extractor {
            anyhow::bail!(
                "--model {}: not the model whose features describe the run's objects ({}): the KL divergences would compare numbers of two feature spaces; leave --model out",
                model_path.display(),
                runs_model.display()
            );
        }
    }
    let ranked = scenarios::objects::find_similar(run, &model, image)?;
    if ranked.is_empty() {
        println!("{}: the run mapped no object with a model; nothing to rank", run.display());
        return Ok(());
    }
    println!("mapped objects most like {} (appearance KL, nats):", image.display());
    for (id, kl) in ranked.iter().take(top) {
        // A model too small for a picture has none (and a picture may have been removed).
        let picture = run.join(files::OBJECTS_DIR).join(format!("landmark_{id}.png"));
        let picture = if picture.is_file() { picture.display().to_string() } else { "(no picture)".into() };
        println!("  landmark {id:>4}  KL {kl:>10.2}  {picture}");
    }
    Ok(())
}
