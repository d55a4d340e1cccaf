//! The offline phase on rendered images: trees (trunks) against everything else in the
//! park, posts, palms, walls, grass and people included.

use scenarios::dataset::{DatasetConfig, make_dataset};
use slam::classifier::TrainingOptions;

/// A CI-sized run (40 images, 6,000 patches per class) measured held-out patch F1 0.82
/// (precision 0.72, recall 0.95); the guard is 0.8. Its foliage model: F1 0.84 (precision
/// 0.85, recall 0.83), guarded at 0.75. At full size (100 images, 20,000
/// patches per class: `objslam train` defaults, see docs/results.md) F1 is 0.89, above the
/// 0.85 goal.
#[test]
fn tree_patches_are_found_on_held_out_rendered_images() {
    let dir = std::env::temp_dir().join(format!("objslam-appearance-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let world = worlds::generate::preset("park", None, 1001).unwrap();
    make_dataset(&world, "park 1001", &DatasetConfig { images: 40, seed: 4, ..Default::default() }, &dir, |_, _| {})
        .unwrap();
    let options = TrainingOptions { max_patches_per_class: 6000, ..Default::default() };
    let (model, classes) = scenarios::train::train_from_dataset(&dir, &options, 4, |_, _, _| {}).unwrap();
    assert!(classes["tree"].0 > 0, "held-out tree patches counted by class: {classes:?}");
    // The model says which renderer made its training images (the dataset's).
    assert_eq!(model.training.renderer, Some(scenarios::train::read_manifest(&dir).unwrap().renderer));
    let s = model.training.heldout.expect("held-out images");
    eprintln!("held-out patches: precision {:.3}, recall {:.3}, F1 {:.3}", s.precision(), s.recall(), s.f1());
    assert!(s.f1() >= 0.8, "F1 {:.3} (precision {:.3}, recall {:.3})", s.f1(), s.precision(), s.recall());
    let f = model.training.foliage_heldout.expect("a foliage model, scored on the held-out images");
    eprintln!("held-out foliage: precision {:.3}, recall {:.3}, F1 {:.3}", f.precision(), f.recall(), f.f1());
    // Measured: foliage precision 0.85, recall 0.83 (F1 0.84) on the held-out images.
    assert!(f.f1() >= 0.75, "foliage F1 {:.3} (precision {:.3}, recall {:.3})", f.f1(), f.precision(), f.recall());

    // Scored on every image of another world, as `objslam train --heldout-dataset` does.
    let other = dir.join("other");
    let world_b = worlds::generate::preset("park", None, 2002).unwrap();
    make_dataset(&world_b, "park 2002", &DatasetConfig { images: 6, seed: 5, ..Default::default() }, &other, |_, _| {})
        .unwrap();
    let w = scenarios::train::score_on_dataset(&other, &model, options.label_fraction).unwrap();
    eprintln!("world {}: precision {:?}, recall {:?}, by class {:?}", w.world, w.precision, w.recall, w.by_class);
    assert_eq!((w.world.as_str(), w.images), ("park 2002", 6));
    let (trees, called) = w.by_class["tree"];
    assert!(trees > 0 && called <= trees, "{:?}", w.by_class);
    // Measured on this pair: precision 0.84, recall 0.95 (posts 154 of 185 patches called
    // object); the guard only says the model still finds trees in a world it never saw.
    let f1 = w.f1.expect("the other world has tree patches, and some are called object");
    assert!(f1 >= 0.5, "another world's F1 {f1:.3} (precision {:?}, recall {:?})", w.precision, w.recall);

    // The patches the exports write: image by image, the labels of load_image and the
    // class mask's majority at each patch's cell, in the feature rows' order.
    let manifest = scenarios::train::read_manifest(&other).unwrap();
    let exported = other.join("features.csv");
    let rows = scenarios::train::export_features(&other, &model, options.label_fraction, &exported).unwrap();
    let patches: Vec<_> = scenarios::train::image_patches(&other, &manifest, &model.extractor, [4, 1])
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(patches.iter().map(|p| p.index).collect::<Vec<_>>(), [4, 1]);
    let l = model.extractor.config.patch_size;
    for p in &patches {
        let img = scenarios::train::load_image(&other, &manifest, p.index).unwrap();
        let class = image::open(other.join(&manifest.images[p.index].class)).unwrap().to_luma8();
        let cols = img.width / l;
        assert_eq!(p.cells.len(), p.features.z.nrows());
        for (k, &(c, r)) in p.cells.iter().enumerate() {
            assert_eq!(p.features.index(c, r), Some(k), "cell ({c}, {r}) is feature row {k}'s");
            assert_eq!(p.fractions[k], img.fractions[(r * cols + c) as usize]);
            assert_eq!(p.classes[k], scenarios::train::majority_class(&class, c, r, l));
        }
    }
    let text = std::fs::read_to_string(&exported).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let per_image = patches[0].cells.len();
    assert_eq!((rows, lines.len()), (6 * per_image, rows + 1), "one row a patch of each image, and a header");
    // Image 1's rows: its cells and fractions, in the feature rows' order.
    let p = &patches[1];
    for (k, line) in lines[1 + per_image..1 + 2 * per_image].iter().enumerate() {
        let fields: Vec<&str> = line.split(',').collect();
        let (c, r) = p.cells[k];
        assert_eq!(fields[..3], [p.index.to_string(), c.to_string(), r.to_string()], "row {k}");
        assert_eq!(fields[fields.len() - 2].parse::<f32>().unwrap(), p.fractions[k], "row {k}");
    }

    // The distractors (posts, palms, walls, people) fitted apart from the rest of the
    // background (`distractors`, off by default): without that, the other world's posts
    // are mostly called object.
    assert!(model.distractors.is_none());
    let apart = TrainingOptions { distractors: true, ..options.clone() };
    let (split, _) = scenarios::train::train_from_dataset(&dir, &apart, 4, |_, _, _| {}).unwrap();
    assert!(split.distractors.is_some() && split.training.distractor_patches > 0);
    let (p, w) = (w, scenarios::train::score_on_dataset(&other, &split, options.label_fraction).unwrap());
    let precision = |w: &scenarios::train::HeldoutWorld| w.precision.expect("some patches are called object");
    let recall = |w: &scenarios::train::HeldoutWorld| w.recall.expect("the world has tree patches");
    let share = |w: &scenarios::train::HeldoutWorld, class: &str| {
        let (n, called) = w.by_class[class];
        called as f64 / n as f64
    };
    eprintln!(
        "posts called object: {:.3} with the distractors apart, {:.3} without; precision {:.3} against {:.3}",
        share(&w, "post"),
        share(&p, "post"),
        precision(&w),
        precision(&p)
    );
    // Measured on this pair: 0.70 of the posts' patches against 0.80, precision 0.88
    // against 0.85. (At the run's model size, 10 components where this has 20, the
    // posts fall from 0.83 to 0.32 on 40 images of this world: docs/results.md.)
    assert!(share(&w, "post") < 0.9 * share(&p, "post"), "posts {:?} against {:?}", w.by_class, p.by_class);
    assert!(precision(&w) > precision(&p), "precision {:.3} against {:.3}", precision(&w), precision(&p));

    // The column context (`context`, off by default), fitted on every 5th of the training
    // images: the other world's patches are called object with more precision.
    let with_context = TrainingOptions { context: true, ..options.clone() };
    let (ctx, _) = scenarios::train::train_from_dataset(&dir, &with_context, 4, |_, _, _| {}).unwrap();
    let c = ctx.context.as_ref().expect("a column context");
    let cw = scenarios::train::score_on_dataset(&other, &ctx, options.label_fraction).unwrap();
    eprintln!(
        "column context ({} images, weights {:?}): precision {:.3} recall {:.3}, posts {:.3}; without {:.3} {:.3}",
        c.images,
        c.weights,
        precision(&cw),
        recall(&cw),
        share(&cw, "post"),
        precision(&p),
        recall(&p)
    );
    // Measured on this pair: precision 0.930 and recall 0.934 against 0.848 and 0.952,
    // posts 0.64 of their patches against 0.80 (6 context images, 24 for the mixtures).
    assert_eq!(c.images, 6);
    assert!(precision(&cw) > precision(&p) + 0.03, "precision {:.3} against {:.3}", precision(&cw), precision(&p));
    assert!(recall(&cw) >= 0.85, "recall {:.3} with the context", recall(&cw));
    assert!(share(&cw, "post") < share(&p, "post"), "posts {:?} against {:?}", cw.by_class, p.by_class);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A run's model source small enough to train in seconds: `images` images, 300 patches a
/// class, 3 components, 4 PCA dimensions.
fn small_source(images: usize) -> scenarios::appearance::AppearanceSource {
    scenarios::appearance::AppearanceSource {
        training_images: images,
        max_patches_per_class: 300,
        max_components: 3,
        pca_dims: 4,
        ..Default::default()
    }
}

/// Regression: two runs of one test process asked for the same uncached model at once;
/// both trained it into one scratch folder and the second rename found its temporary file
/// gone ("No such file or directory" on the cached model), failing CI. Now the model is
/// trained once and both get it.
#[test]
fn concurrent_requests_for_an_uncached_model_train_it_once() {
    let cache = std::env::temp_dir().join(format!("objslam-cache-race-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let source = small_source(3);
    let camera = sim::camera::CameraConfig::default();
    let trained = std::sync::atomic::AtomicUsize::new(0);
    let models: Vec<_> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..3)
            .map(|_| {
                scope.spawn(|| {
                    source.resolve_in(&cache, std::path::Path::new("."), &camera, |stage, done, total| {
                        if stage == "rendering" && done == total {
                            trained.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                        }
                    })
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap().unwrap()).collect()
    });
    assert_eq!(trained.into_inner(), 1, "the model is trained once");
    assert!(models.iter().all(|m| *m == models[0]), "every caller gets the same model");
    let files: Vec<String> =
        std::fs::read_dir(&cache).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(files, vec![source.cache_key(&camera)], "only the model is left in the cache");
    let _ = std::fs::remove_dir_all(&cache);
}

/// A model trained over several worlds: the images are shared out among parks drawn from
/// the generalisation benchmark's distribution (none of them a benchmark world), all of
/// them trained on, and the model is another than the one-world model of the same settings.
#[test]
fn training_images_spread_over_several_worlds_are_all_trained_on() {
    use scenarios::montecarlo::generalisation::{Split, training_world, world_seed};
    let cache = std::env::temp_dir().join(format!("objslam-cache-worlds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache);
    let one = small_source(5);
    let three = scenarios::appearance::AppearanceSource { training_worlds: 3, ..one.clone() };
    let camera = sim::camera::CameraConfig::default();
    assert_ne!(one.cache_key(&camera), three.cache_key(&camera));
    let rendered = std::sync::Mutex::new(Vec::new());
    let spread = three
        .resolve_in(&cache, std::path::Path::new("."), &camera, |stage, done, total| {
            if stage == "rendering" {
                rendered.lock().unwrap().push((done, total));
            }
        })
        .unwrap();
    assert_eq!(spread.training.images, 5, "every image of the three worlds");
    // Images 2, 2 and 1 to the three worlds, counted as one training's progress.
    let rendered = rendered.into_inner().unwrap();
    assert_eq!(rendered.last(), Some(&(5, 5)), "{rendered:?}");
    assert!(rendered.windows(2).all(|w| w[0].0 <= w[1].0), "progress only goes forward: {rendered:?}");
    let single = one.resolve_in(&cache, std::path::Path::new("."), &camera, |_, _, _| {}).unwrap();
    assert_eq!(single.training.images, 5);
    assert_ne!(spread, single, "other worlds, another model");
    // The training worlds are the benchmark's kind of park, yet none of its worlds.
    let benchmark: Vec<u64> = (0..64).flat_map(|i| [world_seed(Split::Tune, i), world_seed(Split::Test, i)]).collect();
    let (seed0, params0) = training_world(one.training_world_seed, 0).unwrap();
    assert!(!benchmark.contains(&seed0));
    assert!((0..3).all(|k| training_world(one.training_world_seed, k).is_some_and(|(s, _)| !benchmark.contains(&s))));
    assert_ne!(params0, worlds::generate::ParkParams::default(), "drawn, not the preset's");
    assert_ne!(training_world(one.training_world_seed, 1).unwrap().0, seed0);
    let _ = std::fs::remove_dir_all(&cache);
}
