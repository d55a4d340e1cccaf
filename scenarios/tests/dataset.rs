//! `objslam dataset`: the manifest and the COCO file parse and agree with the masks.

use scenarios::dataset::{DatasetConfig, Manifest, PatchLabels, make_dataset, patch_labels, rle_decode};

#[test]
fn manifest_coco_and_patch_labels_agree_with_the_masks() {
    let dir = std::env::temp_dir().join(format!("objslam-dataset-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let world = worlds::generate::park(&Default::default(), 4).unwrap();
    let mut config = DatasetConfig { images: 8, seed: 2, ..Default::default() };
    config.camera.width = 180;
    config.camera.height = 135;
    let made = make_dataset(&world, "park seed 4", &config, &dir, |_, _| {}).unwrap();
    let manifest: Manifest = serde_json::from_str(&std::fs::read_to_string(dir.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(manifest, made);
    assert_eq!(manifest.images.len(), 8);
    assert!(
        manifest.images.iter().any(|e| e.kind == "object") && manifest.images.iter().any(|e| e.kind == "background")
    );
    let coco: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("annotations.json")).unwrap()).unwrap();
    assert_eq!(coco["images"].as_array().unwrap().len(), 8);
    let (mut trees_seen, mut foliage_parts) = (0, 0);
    for entry in &manifest.images {
        let inst = image::open(dir.join(&entry.instance)).unwrap().to_luma16();
        let class = image::open(dir.join(&entry.class)).unwrap().to_luma8();
        let (w, h) = (inst.width(), inst.height());
        assert_eq!((w, h), (180, 135));
        // Patch labels equal the fraction of tree pixels recomputed from the class mask.
        let stored: PatchLabels =
            serde_json::from_str(&std::fs::read_to_string(dir.join(&entry.patches)).unwrap()).unwrap();
        let again = patch_labels(class.as_raw(), w, h, 9, &[worlds::ObjectClass::Tree.id()]);
        assert_eq!(stored, again);
        assert_eq!((stored.rows, stored.cols), (15, 20));
        // Every visible part of an object instance (its pixels of one class) has exactly
        // one annotation whose RLE decodes to those pixels, with a matching box, area and
        // the class mask's category; together they cover every object pixel once.
        let anns: Vec<&serde_json::Value> =
            coco["annotations"].as_array().unwrap().iter().filter(|a| a["image_id"] == entry.id).collect();
        let is_object = |id: u16| id != 0 && id != worlds::validate::GROUND_INSTANCE_ID;
        let mut parts: Vec<(u16, u8)> =
            inst.pixels().zip(class.pixels()).map(|(i, c)| (i.0[0], c.0[0])).filter(|(id, _)| is_object(*id)).collect();
        parts.sort_unstable();
        parts.dedup();
        assert_eq!(anns.len(), parts.len());
        let mut covered = vec![0u32; (w * h) as usize];
        for a in anns {
            let id = a["instance_id"].as_u64().unwrap() as u16;
            let category = a["category_id"].as_u64().unwrap() as u8;
            let counts: Vec<u32> =
                a["segmentation"]["counts"].as_array().unwrap().iter().map(|c| c.as_u64().unwrap() as u32).collect();
            assert_eq!(a["segmentation"]["size"], serde_json::json!([h, w]));
            let mask = rle_decode(&counts, w, h);
            let truth: Vec<bool> =
                inst.pixels().zip(class.pixels()).map(|(i, c)| i.0[0] == id && c.0[0] == category).collect();
            assert_eq!(mask, truth, "RLE of instance {id}, class {category}");
            let area = truth.iter().filter(|b| **b).count() as u64;
            assert!(area > 0);
            assert_eq!(a["area"].as_u64().unwrap(), area);
            let b = a["bbox"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as u32).collect::<Vec<_>>();
            for (i, &on) in truth.iter().enumerate() {
                if on {
                    let (x, y) = (i as u32 % w, i as u32 / w);
                    assert!(x >= b[0] && x < b[0] + b[2] && y >= b[1] && y < b[1] + b[3]);
                    covered[i] += 1;
                }
            }
            // A part is its object's class, or the foliage of a tree or palm.
            let object_class = world.class_of(id).unwrap();
            if category == worlds::ObjectClass::Foliage.id() {
                assert!(matches!(object_class, worlds::ObjectClass::Tree | worlds::ObjectClass::Palm));
                foliage_parts += 1;
            } else {
                assert_eq!(category, object_class.id());
            }
            if category == worlds::ObjectClass::Tree.id() {
                trees_seen += 1;
            }
        }
        for (i, p) in inst.pixels().enumerate() {
            assert_eq!(covered[i], is_object(p.0[0]) as u32, "pixel {i}");
        }
        // The camera pose is a proper rotation.
        let r = entry.world_from_camera.r;
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        assert!((det - 1.0).abs() < 1e-9);
    }
    assert!(trees_seen >= 4, "object views should show trees");
    assert!(foliage_parts >= 1, "canopies are annotated as foliage");
    // Object views show their target.
    for entry in manifest.images.iter().filter(|e| e.kind == "object") {
        let inst = image::open(dir.join(&entry.instance)).unwrap().to_luma16();
        assert!(inst.pixels().any(|p| Some(p.0[0]) == entry.target_instance), "image {} misses its target", entry.id);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_dataset_settings_are_errors() {
    let world = worlds::generate::park(&Default::default(), 4).unwrap();
    let dir = std::env::temp_dir().join(format!("objslam-dataset-bad-{}", std::process::id()));
    let none = DatasetConfig { images: 0, ..Default::default() };
    assert!(make_dataset(&world, "w", &none, &dir, |_, _| {}).is_err());
    let no_class = DatasetConfig { images: 1, classes: vec![worlds::ObjectClass::Checkerboard], ..Default::default() };
    let e = make_dataset(&world, "w", &no_class, &dir, |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("checkerboard"), "{e}");
}

/// A dataset holds its directory against other commands (two given one directory mixed
/// their files), and replaces an earlier dataset whole, its surplus images too, leaving
/// nothing unfinished behind.
#[test]
fn a_dataset_holds_its_directory_and_replaces_an_earlier_one_whole() {
    let dir = std::env::temp_dir().join(format!("objslam-dataset-held-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (world, config) = (small_world(), small_config());
    make_dataset(&world, "park seed 4", &config, &dir, |_, _| {}).unwrap();
    let earlier = std::fs::read_to_string(dir.join("dataset.json")).unwrap();
    let one = DatasetConfig { images: 1, seed: 3, ..config };
    let held = scenarios::partial_files::lock_output(&dir).unwrap();
    let e = make_dataset(&world, "park seed 4", &one, &dir, |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("another objslam command is writing into this directory"), "{e}");
    assert_eq!(std::fs::read_to_string(dir.join("dataset.json")).unwrap(), earlier, "the earlier dataset is kept");
    drop(held);
    let made = make_dataset(&world, "park seed 4", &one, &dir, |_, _| {}).unwrap();
    let manifest: Manifest = serde_json::from_str(&std::fs::read_to_string(dir.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(manifest, made);
    assert_eq!(manifest.images.len(), 1);
    assert!(dir.join("images/000000.png").is_file() && !dir.join("images/000001.png").exists());
    assert!(!dir.join(".unfinished").exists() && !dir.join(".dataset.json.partial").exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// What training reads of a dataset is checked against what the dataset says: a greyscale
/// image (colour is a feature), a class mask in another pixel format (16-bit ids read as
/// 0, the sky) and patch labels of another image are refused, naming the file.
#[test]
fn training_refuses_images_masks_and_labels_that_are_not_the_datasets() {
    let dir = std::env::temp_dir().join(format!("objslam-dataset-damaged-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (world, config) = (small_world(), small_config());
    make_dataset(&world, "park seed 4", &config, &dir, |_, _| {}).unwrap();
    let manifest = scenarios::train::read_manifest(&dir).unwrap();
    let load = |i| scenarios::train::load_image(&dir, &manifest, i).map(|_| ()).map_err(|e| e.to_string());
    load(0).unwrap();
    load(1).unwrap();
    let options = slam::classifier::TrainingOptions::default();
    let e = scenarios::train::train_from_dataset(&dir, &options, 1, |_, _, _| {}).unwrap_err().to_string();
    assert!(e.contains("--heldout-every 1 holds out every image"), "{e}");
    let (first, second) = (&manifest.images[0], &manifest.images[1]);

    let image = dir.join(&first.image);
    let colour = std::fs::read(&image).unwrap();
    image::open(&image).unwrap().to_luma8().save(&image).unwrap();
    let e = load(0).unwrap_err();
    assert!(e.contains(&first.image) && e.contains("stored as a greyscale image"), "{e}");
    std::fs::write(&image, colour).unwrap();

    let mask = dir.join(&first.class);
    let eight_bit = std::fs::read(&mask).unwrap();
    let wide = image::open(&mask).unwrap().to_luma16();
    image::ImageBuffer::<image::Luma<u16>, _>::from_fn(wide.width(), wide.height(), |x, y| {
        image::Luma([wide.get_pixel(x, y)[0] / 257])
    })
    .save(&mask)
    .unwrap();
    let e = load(0).unwrap_err();
    assert!(e.contains(&first.class) && e.contains("a class mask is an 8-bit greyscale image"), "{e}");
    std::fs::write(&mask, eight_bit).unwrap();

    // The two images' labels swapped (they differ: one is aimed at a tree).
    let (a, b) = (dir.join(&first.patches), dir.join(&second.patches));
    let (text_a, text_b) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert_ne!(text_a, text_b);
    std::fs::write(&a, &text_b).unwrap();
    std::fs::write(&b, &text_a).unwrap();
    let e = load(0).unwrap_err();
    assert!(e.contains(&first.patches) && e.contains("the labels are not this image's"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The park of world seed 4, which the small datasets here show.
fn small_world() -> worlds::World {
    worlds::generate::park(&Default::default(), 4).unwrap()
}

/// A dataset of two 90 x 72 images: enough for what a test reads of one, made in a blink.
fn small_config() -> DatasetConfig {
    let mut config = DatasetConfig { images: 2, seed: 2, ..Default::default() };
    config.camera.width = 90;
    config.camera.height = 72;
    config
}
