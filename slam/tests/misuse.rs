//! The library's misuse: bad data, and a caller's slip (a slice of the wrong length, an
//! index past the map, a probability out of range), is a typed error that says what was
//! wrong: never a panic, a quiet NaN or a wrong answer.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector2, Vector3};
use slam::association::{chi2_quantile, jcbb::jcbb_with};
use slam::classifier::{ModelError, TrainingOptions, train};
use slam::column_context::{ColumnContext, ContextError, LabelledGrid};
use slam::ekf::{Ekf, OdometryMotionModel, RangeBearingModel};
use slam::features::pca::Pca;
use slam::gmm::{Component, Gmm, GmmError};
use slam::kl::{KlError, PreparedGmm};
use slam::object_model::{ObjectModelConfig, ObjectModelError, ObjectObservation, fit_observation};

fn gaussian(weight: f64, mean: &[f64]) -> Component {
    Component { weight, mean: DVector::from_column_slice(mean), covariance: DMatrix::identity(mean.len(), mean.len()) }
}

#[test]
fn mixtures_with_weights_or_means_not_finite_are_refused() {
    for bad in [
        Gmm { components: vec![gaussian(f64::NAN, &[0.0, 0.0]), gaussian(0.5, &[1.0, 0.0])] },
        Gmm { components: vec![gaussian(-3.0, &[0.0, 0.0]), gaussian(4.0, &[1.0, 0.0])] },
        Gmm { components: vec![gaussian(1.0, &[f64::NAN, 0.0])] },
    ] {
        assert!(matches!(bad.evaluator(), Err(GmmError::BadModel(_))), "{bad:?}");
        assert!(matches!(PreparedGmm::new(&bad), Err(KlError::Component { .. })), "{bad:?}");
    }
    let zero = Gmm { components: vec![gaussian(0.0, &[0.0, 0.0])] };
    assert!(matches!(PreparedGmm::new(&zero), Err(KlError::Component { component: 0, .. })));
    // Every weight zero: no mixture at all, where every density would be the same floor.
    let all_zero = Gmm { components: vec![gaussian(0.0, &[0.0, 0.0]), gaussian(0.0, &[1.0, 0.0])] };
    assert!(matches!(all_zero.evaluator(), Err(GmmError::BadModel(m)) if m.contains("zero")));
    assert!(matches!(zero.evaluator(), Err(GmmError::BadModel(_))));
    // A component emptied to weight 0 beside others is sound (VBEM leaves them).
    let emptied = Gmm { components: vec![gaussian(0.0, &[5.0, 5.0]), gaussian(1.0, &[0.0, 0.0])] };
    assert!(emptied.evaluator().is_ok() && PreparedGmm::new(&emptied).is_ok());
    let sound = Gmm { components: vec![gaussian(1.0, &[0.0, 0.0])] };
    let ln_p = sound.evaluator().unwrap().log_density(&[0.0, 0.0]).unwrap();
    assert!((ln_p + (2.0 * std::f64::consts::PI).ln()).abs() < 1e-12, "{ln_p}");
}

#[test]
fn a_point_of_another_dimension_is_not_scored() {
    let g = Gmm { components: vec![gaussian(1.0, &[0.0, 0.0]), gaussian(1.0, &[1.0, 0.0])] };
    let e = g.evaluator().unwrap();
    let wrong = GmmError::Dimension { expected: 2, found: 3 };
    assert_eq!(e.log_density(&[0.0, 0.0, 9.0]), Err(wrong.clone()));
    assert_eq!(e.log_terms(&[0.0, 0.0, 9.0], &mut [0.0; 2]), Err(wrong.clone()));
    assert_eq!(e.log_terms_lanes(&[[0.0; 4]; 3], &mut [[0.0; 4]; 2]), Err(wrong));
    // Fewer slots than components would leave a component out of the sum.
    let short = GmmError::TermSlots { slots: 1, components: 2 };
    assert_eq!(e.log_terms(&[0.0, 0.0], &mut [0.0; 1]), Err(short.clone()));
    assert_eq!(e.log_terms_lanes(&[[0.0; 4]; 2], &mut [[0.0; 4]; 1]), Err(short));
    let mut terms = [0.0; 2];
    e.log_terms(&[0.0, 0.0], &mut terms).unwrap();
    assert!(terms.iter().all(|t| t.is_finite()));
    let fitted =
        slam::gmm::fit(&DMatrix::from_fn(40, 2, |i, j| ((i * 7 + j * 3) % 11) as f64), None, &Default::default());
    let student = slam::gmm::StudentTMixture::new(&fitted.unwrap()).unwrap();
    assert_eq!(student.log_density(&DVector::zeros(3)), Err(GmmError::Dimension { expected: 2, found: 3 }));
    assert!(student.log_density(&DVector::zeros(2)).unwrap().is_finite());
}

#[test]
fn pca_of_vectors_of_another_length_is_refused() {
    use slam::features::FeatureError;
    let data = DMatrix::from_fn(10, 3, |i, j| ((i * 5 + j * 2) % 7) as f64);
    let pca = Pca::fit(&data, 2).unwrap();
    assert!(pca.project(&data).is_ok());
    let e = pca.project(&DMatrix::zeros(4, 5)).unwrap_err();
    assert!(matches!(e, FeatureError::PcaMismatch { expected: 3, found: 5 }), "{e}");
    let e = pca.back_project(&[1.0]).unwrap_err();
    assert!(matches!(e, FeatureError::AppearanceLength { expected: 2, found: 1 }), "{e}");
    // A feature row (appearance, then its neighbours' norms) back-projects by its head.
    assert_eq!(pca.back_project(&[1.0, 2.0, 9.0, 9.0]).unwrap(), pca.back_project(&[1.0, 2.0]).unwrap());
    // Put together field by field: a basis of another length than the mean.
    let lopsided = Pca { mean: DVector::zeros(4), ..pca.clone() };
    assert!(matches!(
        lopsided.project(&DMatrix::zeros(2, 4)),
        Err(FeatureError::PcaMismatch { expected: 4, found: 3 })
    ));
    assert!(matches!(lopsided.back_project(&[1.0, 2.0]), Err(FeatureError::PcaMismatch { expected: 4, found: 3 })));
}

#[test]
fn image_regions_and_patch_rectangles_outside_the_image_are_refused() {
    use slam::features::gabor::{GaborBank, Plane};
    use slam::features::{FeatureConfig, FeatureError, ImageRef, PatchRect, raw_patches};
    let plane = Plane { width: 8, height: 6, data: vec![0.5; 48] };
    let bank = GaborBank::default();
    assert_eq!(bank.apply_within(&plane, (2, 1, 6, 5)).unwrap().len(), bank.len());
    for region in [(3, 0, 6, 1), (0, 2, 1, 5), (usize::MAX, 0, 2, 1)] {
        let e = bank.apply_within(&plane, region).unwrap_err();
        assert!(matches!(e, FeatureError::Region { width: 8, height: 6, .. }), "{e}");
    }
    let rgb = vec![100u8; 20 * 20 * 3];
    let image = ImageRef::new(20, 20, &rgb).unwrap();
    let config = FeatureConfig { patch_size: 4, ..FeatureConfig::default() };
    let whole = PatchRect::whole(&image, 4);
    assert_eq!(raw_patches(&image, &config, &whole).unwrap().shape(), (25, config.raw_dims()));
    let past = PatchRect { col1: 6, ..whole };
    assert!(matches!(raw_patches(&image, &config, &past), Err(FeatureError::Rect { cols: 5, rows: 5, .. })));
    let zero = FeatureConfig { patch_size: 0, ..FeatureConfig::default() };
    assert!(matches!(raw_patches(&image, &zero, &whole), Err(FeatureError::Settings(_))));
}

#[test]
fn a_mosaic_whose_cells_and_vectors_do_not_pair_is_refused() {
    use slam::features::gabor::GaborBank;
    use slam::features::{FeatureConfig, FeatureError, FeatureExtractor};
    use slam::object_model::{MosaicView, render_mosaic};
    let config = FeatureConfig { patch_size: 2, bank: GaborBank { filters: vec![] }, channel_gain: vec![] };
    let data = DMatrix::from_fn(30, config.raw_dims(), |i, j| ((i * 7 + j * 5) % 13) as f64 / 13.0);
    let extractor = FeatureExtractor::new(config, Pca::fit(&data, 3).unwrap()).unwrap();
    let view = |appearance: Vec<Vec<f64>>| MosaicView { cells: vec![(0, 0), (1, 0)], appearance, pixels: vec![] };
    let (w, h, rgb) = render_mosaic(&view(vec![vec![0.0; 3], vec![0.1; 3]]), &extractor).unwrap();
    assert_eq!((w, h, rgb.len()), (4, 2, 24));
    let e = render_mosaic(&view(vec![vec![0.0; 3]]), &extractor).unwrap_err();
    assert!(matches!(e, FeatureError::Mosaic { cells: 2, appearance: 1 }), "{e}");
    let e = render_mosaic(&view(vec![vec![0.0; 3], vec![0.0; 2]]), &extractor).unwrap_err();
    assert!(matches!(e, FeatureError::AppearanceLength { expected: 3, found: 2 }), "{e}");
    // An extractor put together field by field, its PCA not of its settings' patches.
    let mut mismatched = extractor.clone();
    mismatched.config.patch_size = 3;
    let e = render_mosaic(&view(vec![vec![0.0; 3], vec![0.1; 3]]), &mismatched).unwrap_err();
    assert!(matches!(e, FeatureError::PcaMismatch { expected: 12, found: 27 }), "{e}");
}

#[test]
fn a_column_context_applies_only_to_whole_grids() {
    let grid = LabelledGrid {
        log_odds: (0..12).map(|k| if k % 3 == 0 { 2.0 } else { -2.0 }).collect(),
        object: (0..12).map(|k| k % 3 == 0).collect(),
        cols: 3,
        rows: 4,
    };
    let context = ColumnContext::fit(std::slice::from_ref(&grid), 2).unwrap();
    assert_eq!(context.apply(&grid.log_odds, 3, 4).unwrap().len(), 12);
    for (cols, rows) in [(4, 4), (usize::MAX, 2)] {
        let e = context.apply(&grid.log_odds, cols, rows).unwrap_err();
        assert!(matches!(&e, ContextError::Input(m) if m.contains("12 log-odds")), "{e}");
    }
}

#[test]
fn pca_of_data_not_finite_is_refused() {
    let mut data = DMatrix::from_fn(10, 3, |i, j| (i * 3 + j) as f64);
    data[(4, 2)] = f64::NAN;
    let e = Pca::fit(&data, 2).unwrap_err().to_string();
    assert!(e.contains("row 4, column 2"), "{e}");
}

#[test]
fn pca_of_data_that_do_not_vary_enough_is_refused() {
    // Blank images: every sample the same.
    let e = Pca::fit(&DMatrix::from_element(10, 3, 0.5), 2).unwrap_err().to_string();
    assert!(e.contains("do not vary"), "{e}");
    // Points on a line in 3-D vary in one direction: a second PCA coordinate is nothing.
    let line = DMatrix::from_fn(10, 3, |i, j| i as f64 * [1.0, 2.0, -1.0][j]);
    assert!(Pca::fit(&line, 1).is_ok());
    let e = Pca::fit(&line, 2).unwrap_err().to_string();
    assert!(e.contains("vary in only 1 direction;") && e.contains("give 1 or fewer"), "{e}");
}

#[test]
fn training_checks_its_feature_settings_first() {
    let mut options = TrainingOptions::default();
    options.features.patch_size = 0;
    let e = train(3, |_| Err(ModelError::Training("no image should be read".into())), &options, |_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("features.patch_size"), "{e}");
}

#[test]
fn a_column_context_is_fitted_only_on_whole_grids() {
    let grid = LabelledGrid { log_odds: vec![1.0, -1.0, 1.0, -1.0], object: vec![true, false], cols: 2, rows: 2 };
    let e = ColumnContext::fit(std::slice::from_ref(&grid), 3).unwrap_err();
    assert!(matches!(&e, ContextError::Input(m) if m.contains("grid 0: 4 log-odds and 2 labels for 2x2")), "{e}");
    let whole = LabelledGrid { object: vec![true, false, true, false], ..grid };
    assert!(matches!(ColumnContext::fit(&[whole], 0), Err(ContextError::Input(m)) if m.contains("reach")));
}

#[test]
fn an_object_model_needs_appearance_columns() {
    let obs = ObjectObservation {
        centre: [0.0, 0.0],
        rows: DMatrix::from_fn(5, 2, |i, j| (i + j) as f64),
        appearance: vec![],
        cells: vec![],
        pixels: vec![],
        centre_covariance: Matrix2::identity(),
    };
    let e = fit_observation(&obs, None, &ObjectModelConfig::default()).unwrap_err();
    assert!(matches!(e, ObjectModelError::TooFewColumns(2)), "{e}");
}

#[test]
fn a_control_of_the_wrong_length_is_named() {
    use slam::ekf::EkfError;
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity());
    let before = ekf.clone();
    let e = ekf.predict(&OdometryMotionModel::default(), &[0.1]).unwrap_err();
    assert_eq!(e, EkfError::ControlLength { control: 1, model: 3 });
    assert!(e.to_string().contains("a control of 1 values for a motion model of 3"), "{e}");
    assert_eq!(ekf, before);
}

#[test]
fn a_motion_model_refuses_a_control_or_calibration_of_another_length() {
    use slam::ekf::{AckermannMotionModel, EkfError, MotionConfig, MotionModel};
    let pose = Vector3::new(1.0, 2.0, 0.3);
    let odometry = OdometryMotionModel::default();
    let models: [&dyn MotionModel; 3] =
        [&odometry, &AckermannMotionModel::default(), &MotionConfig::Ackermann(AckermannMotionModel::default())];
    for model in models {
        for control in [&[1.0, 0.1][..], &[1.0, 0.1, 0.2, 0.0]] {
            let wrong = EkfError::ControlLength { control: control.len(), model: 3 };
            assert_eq!(model.predict(&pose, control).map(|p| p.0), Err(wrong.clone()));
            assert_eq!(model.predict_calibrated(&pose, &[], control).map(|p| p.pose), Err(wrong));
        }
        assert!(model.predict(&pose, &[1.0, 0.1, 0.2]).is_ok());
    }
    // A model that estimates no calibration takes none; the odometry model three or none.
    let car = AckermannMotionModel::default();
    let e = car.predict_calibrated(&pose, &[0.0; 3], &[1.0, 0.1, 0.2]).unwrap_err();
    assert_eq!(e, EkfError::CalibrationLength { calibration: 3, model: 0 });
    let e = odometry.predict_calibrated(&pose, &[0.0, 0.0], &[0.5, 0.0, 0.1]).unwrap_err();
    assert_eq!(e, EkfError::CalibrationLength { calibration: 2, model: 3 });
    let (plain, calibrated) = (
        odometry.predict(&pose, &[0.5, 0.0, 0.1]).unwrap(),
        odometry.predict_calibrated(&pose, &[0.0; 3], &[0.5, 0.0, 0.1]).unwrap(),
    );
    assert!((plain.0 - calibrated.pose).norm() < 1e-12);
}

#[test]
fn gaussians_and_mixtures_of_other_shapes_are_refused() {
    use slam::kl::{PreparedGaussian, kl_gaussian};
    use slam::object_model::marginal;
    let a = PreparedGaussian::new(&DVector::zeros(2), &DMatrix::identity(2, 2), 0).unwrap();
    let b = PreparedGaussian::new(&DVector::zeros(3), &DMatrix::identity(3, 3), 0).unwrap();
    assert_eq!(kl_gaussian(&a, &b).unwrap_err(), KlError::Dimension(2, 3));
    // Put together field by field: a covariance of another size than the mean.
    let lopsided = PreparedGaussian { mean: DVector::zeros(3), ..a.clone() };
    assert!(matches!(
        kl_gaussian(&lopsided, &b),
        Err(KlError::CovarianceShape { component: 0, dims: 3, rows: 2, cols: 2 })
    ));
    let mixture =
        PreparedGmm::new(&Gmm { components: vec![gaussian(0.5, &[0.0, 0.0]), gaussian(0.5, &[1.0, 0.0])] }).unwrap();
    assert!(slam::kl::kl_variational(&mixture, &mixture).unwrap().abs() < 1e-12);
    let mut unweighted = mixture.clone();
    unweighted.log_weights.pop();
    let mut mixed = mixture.clone();
    mixed.components[1] = b.clone();
    let empty = PreparedGmm { log_weights: vec![], components: vec![] };
    for bad in [&unweighted, &mixed, &empty] {
        assert!(slam::kl::kl_variational(bad, &mixture).is_err() && slam::kl::kl_matched_bound(&mixture, bad).is_err());
    }
    assert_eq!(empty.dims(), 0);
    assert!(kl_gaussian(&a, &a).unwrap().abs() < 1e-12);
    let two = Gmm { components: vec![gaussian(1.0, &[0.0, 1.0])] };
    assert_eq!(marginal(&two, 3).unwrap_err(), GmmError::Dimension { expected: 3, found: 2 });
    assert_eq!(marginal(&two, 1).unwrap().dims(), 1);
    // A mixture whose components disagree in shape has no moments.
    let mixed = Gmm { components: vec![gaussian(0.5, &[0.0, 1.0]), gaussian(0.5, &[0.0, 1.0, 2.0])] };
    assert_eq!(mixed.moments().unwrap_err(), GmmError::Dimension { expected: 2, found: 3 });
    let mut wide = two.clone();
    wide.components[0].covariance = DMatrix::identity(3, 3);
    assert!(matches!(wide.moments(), Err(GmmError::CovarianceShape { component: 0, dims: 2, rows: 3, cols: 3 })));
    assert!(matches!(slam::gmm::VbPrior::from_gmm(&mixed, 5.0), Err(GmmError::Dimension { .. })));
    // A variational model whose W^-1 disagrees with its mean has no predictive density.
    let mut fitted =
        slam::gmm::fit(&DMatrix::from_fn(40, 2, |i, j| ((i * 7 + j * 3) % 11) as f64), None, &Default::default())
            .unwrap();
    fitted.components[0].w_inv = DMatrix::identity(3, 3);
    assert!(matches!(slam::gmm::StudentTMixture::new(&fitted), Err(GmmError::CovarianceShape { component: 0, .. })));
}

#[test]
fn beams_past_the_scan_and_patches_of_no_size_are_named_or_none() {
    use slam::calibration::{BoardSegmentation, SegmentationError, segment_board};
    use slam::features::{ImageRef, PatchRect};
    use slam::messages::LaserScan;
    let scan = LaserScan {
        t: 0.0,
        angle_min: -0.5,
        angle_increment: 0.01,
        range_min: 0.1,
        range_max: 30.0,
        ranges: vec![2.0; 101],
    };
    assert!(scan.valid(100) && !scan.valid(101));
    assert!(scan.point(100).is_some() && scan.point(101).is_none());
    let bad = BoardSegmentation { range_m: [5.0, 1.0], ..Default::default() };
    assert!(matches!(segment_board(&scan, &bad, None), Err(SegmentationError::Setting { field: "range_m", .. })));
    let rgb = vec![0u8; 30 * 20 * 3];
    let image = ImageRef::new(30, 20, &rgb).unwrap();
    assert_eq!(image.grid(0), (0, 0));
    assert!(PatchRect::whole(&image, 0).is_empty());
    let inverted = PatchRect { col0: 4, col1: 2, row0: 3, row1: 1 };
    assert_eq!((inverted.cols(), inverted.rows(), inverted.len(), inverted.patch(0)), (0, 0, 0, None));
    let two_by_three = PatchRect { col0: 1, col1: 3, row0: 5, row1: 8 };
    assert_eq!(
        (two_by_three.patch(0), two_by_three.patch(5), two_by_three.patch(6)),
        (Some((1, 5)), Some((2, 7)), None)
    );
    let config = slam::features::FeatureConfig::default();
    let far = PatchRect { col0: u32::MAX - 1, col1: u32::MAX, row0: 0, row1: 1 };
    let region = config.pixels_read(&far, 30, 20);
    assert!(region.columns.0 <= region.columns.1 && region.columns.1 <= 30, "{region:?}");
    let no_patches = slam::features::FeatureConfig { patch_size: 0, ..config.clone() };
    assert!(no_patches.pixels_read(&two_by_three, 30, 20).columns.1 <= 30);
    // An image built field by field, its buffer short: named, not read past its end.
    let short = ImageRef { width: 30, height: 20, rgb: &rgb[..100] };
    let config = slam::features::FeatureConfig::default();
    let e = slam::features::raw_patches(&short, &config, &PatchRect::whole(&image, 9)).unwrap_err();
    assert!(matches!(e, slam::features::FeatureError::ImageSize { found: 100, .. }), "{e}");
    let huge = ImageRef { width: u32::MAX, height: u32::MAX, rgb: &rgb };
    assert!(slam::features::raw_patches(&huge, &config, &PatchRect::whole(&image, 9)).is_err());
}

#[test]
fn a_plane_whose_data_is_not_its_size_is_refused() {
    use slam::features::FeatureError;
    use slam::features::gabor::{GaborBank, Plane};
    let bank = GaborBank::default();
    for plane in [Plane { width: 4, height: 3, data: vec![0.0; 11] }, Plane { width: 0, height: 3, data: vec![0.0; 1] }]
    {
        assert!(matches!(bank.apply(&plane), Err(FeatureError::PlaneSize { .. })), "{plane:?}");
        assert!(matches!(bank.apply_within(&plane, (0, 0, 0, 0)), Err(FeatureError::PlaneSize { .. })));
    }
    // A bank with a filter that is not separable (45 degrees) filters in 2-D.
    let mut diagonal = GaborBank::default();
    diagonal.filters[0].theta_deg = 45.0;
    assert!(diagonal.filters[0].separable().is_none());
    for empty in [Plane { width: 0, height: 3, data: vec![] }, Plane { width: 5, height: 0, data: vec![] }] {
        for bank in [&bank, &diagonal] {
            let out = bank.apply(&empty).unwrap();
            assert!(out.len() == bank.len() && out.iter().all(|p| p.data.is_empty()));
            let within = bank.apply_within(&empty, (0, 0, 0, 0)).unwrap();
            assert!(within.len() == bank.len() && within.iter().all(|p| p.data.is_empty()));
        }
    }
    assert_eq!(bank.apply(&Plane { width: 4, height: 3, data: vec![0.5; 12] }).unwrap().len(), bank.len());
}

#[test]
fn jcbb_needs_a_row_of_allowed_pairs_per_observation_and_a_probability() {
    use slam::association::jcbb::{JcbbError, jcbb};
    let ekf = Ekf::new(Vector3::zeros(), Matrix3::identity());
    let z = [Vector2::new(5.0, 0.0), Vector2::new(6.0, 0.5)];
    let e = jcbb_with(&ekf, &RangeBearingModel::default(), &z, &[vec![]], 0.99).unwrap_err();
    assert_eq!(e, JcbbError::AllowedRows { rows: 1, observations: 2 });
    for percentage in [99.0, 1.0, 0.0, f64::NAN] {
        let e = jcbb(&ekf, &RangeBearingModel::default(), &z, 9.21, percentage).unwrap_err();
        assert!(matches!(e, JcbbError::Confidence(_)), "{e}");
    }
    assert_eq!(jcbb(&ekf, &RangeBearingModel::default(), &z, 9.21, 0.99).unwrap(), vec![None, None]);
}

#[test]
fn a_chi_square_quantile_outside_its_domain_is_named() {
    use slam::association::Chi2DomainError;
    for (dof, p) in [(2, 1.5), (2, 1.0), (3, -0.1), (0, 0.5), (4, f64::NAN)] {
        let e = chi2_quantile(dof, p).unwrap_err();
        assert_eq!(e.dof, dof);
        assert!(e.to_string().contains("need dof >= 1 and 0 <= p < 1"), "{e}");
    }
    assert_eq!(chi2_quantile(2, 0.0), Ok(0.0));
    assert!((chi2_quantile(2, 0.95).unwrap() - 5.991).abs() < 1e-3);
    assert!(matches!(chi2_quantile(0, 0.5), Err(Chi2DomainError { dof: 0, .. })));
}

#[test]
fn a_landmark_past_the_map_is_named() {
    use slam::ekf::EkfError;
    let model = RangeBearingModel::default();
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity());
    let z = Vector2::new(5.0, 0.0);
    let missing = EkfError::UnknownLandmark(0);
    assert_eq!(ekf.mahalanobis2(&model, 0, &z), Err(missing.clone()));
    assert_eq!(ekf.landmark(0), Err(missing.clone()));
    assert_eq!(ekf.landmark_covariance(0), Err(missing.clone()));
    assert_eq!(ekf.predict_observation(&model, 0).map(|p| p.0), Err(missing.clone()));
    assert_eq!(ekf.remove_landmark(0), Err(missing));
    let a = ekf.add_landmark(&model, &z).unwrap();
    assert_eq!(ekf.landmark_difference(a, 1).map(|d| d.0), Err(EkfError::UnknownLandmark(1)));
    assert!(ekf.mahalanobis2(&model, a, &z).unwrap() < 1e-9);
    let b = ekf.add_landmark(&model, &Vector2::new(7.0, 0.4)).unwrap();
    ekf.predict(&OdometryMotionModel::default(), &[0.3, 0.05, 0.1]).unwrap();
    let all = ekf.mahalanobis2_to_all(&model, &z);
    let one_by_one = [ekf.mahalanobis2(&model, a, &z).unwrap(), ekf.mahalanobis2(&model, b, &z).unwrap()];
    assert_eq!(all.iter().map(|d| d.to_bits()).collect::<Vec<_>>(), one_by_one.map(f64::to_bits).to_vec());
    ekf.remove_landmark(b).unwrap();
    assert_eq!(ekf.landmarks().collect::<Vec<_>>(), vec![ekf.landmark(a).unwrap()]);
    assert_eq!(ekf.remove_landmark(a), Ok(()));
    assert_eq!(ekf.landmark_count(), 0);
}

#[test]
fn an_observation_of_another_feature_space_is_no_divergence() {
    use slam::object_model::{MosaicView, ObjectModel};
    let model = ObjectModel {
        gmm: Gmm { components: vec![gaussian(1.0, &[0.0; 6])] },
        patches: 10.0,
        observations: 1,
        mosaic: MosaicView { cells: vec![], appearance: vec![], pixels: vec![] },
    };
    let other = Gmm { components: vec![gaussian(1.0, &[0.0; 5])] };
    for appearance_only in [false, true] {
        let e = model
            .kl_from(&other, [0.0; 2], [0.0; 2], &Matrix2::identity(), &ObjectModelConfig::default(), appearance_only)
            .unwrap_err();
        assert!(matches!(e, ObjectModelError::Dimension { observation: 5, model: 6 }), "{e}");
    }
    let same = Gmm { components: vec![gaussian(1.0, &[0.0; 6])] };
    let kl = model.kl_from(&same, [0.0; 2], [0.0; 2], &Matrix2::identity(), &ObjectModelConfig::default(), true);
    assert!(kl.unwrap().abs() < 1e-9);
    // Nor is an observation of another feature space merged into the model.
    let observation = |columns: usize| ObjectObservation {
        centre: [0.0, 0.0],
        rows: DMatrix::from_fn(5, columns, |i, j| (i + j) as f64 * 0.1),
        appearance: vec![],
        cells: vec![],
        pixels: vec![],
        centre_covariance: Matrix2::identity(),
    };
    let mut merged = model.clone();
    let e = merged.update(&observation(5), [0.0; 2], 3).unwrap_err();
    assert!(matches!(e, ObjectModelError::Dimension { observation: 5, model: 6 }), "{e}");
    assert_eq!(merged, model, "a refused observation changed the model");
    merged.update(&observation(6), [0.0; 2], 3).unwrap();
    assert_eq!(merged.observations, 2);
    let narrow = ObjectModel { gmm: Gmm { components: vec![gaussian(1.0, &[0.0; 3])] }, ..model.clone() };
    let e = narrow.clone().update(&observation(3), [0.0; 2], 0).unwrap_err();
    assert!(matches!(e, ObjectModelError::TooFewColumns(3)), "{e}");
    assert_eq!(observation(2).appearance_dims(), 0);
}

#[test]
fn weights_whose_sum_overflows_weigh_as_their_ratios() {
    use slam::kl::kl_variational;
    let huge = Gmm { components: vec![gaussian(1e308, &[0.0, 0.0]), gaussian(1e308, &[3.0, 0.0])] };
    let halves = Gmm { components: vec![gaussian(0.5, &[0.0, 0.0]), gaussian(0.5, &[3.0, 0.0])] };
    let other = Gmm { components: vec![gaussian(1.0, &[1.0, 1.0])] };
    let (huge, halves, other) =
        (PreparedGmm::new(&huge).unwrap(), PreparedGmm::new(&halves).unwrap(), PreparedGmm::new(&other).unwrap());
    let (a, b) = (kl_variational(&huge, &other).unwrap(), kl_variational(&halves, &other).unwrap());
    assert!(a.is_finite() && (a - b).abs() < 1e-12, "{a} against {b}");
}

#[test]
fn a_gaussian_not_finite_is_no_divergence() {
    use slam::kl::PreparedGaussian;
    let mean = DVector::from_column_slice(&[f64::NAN, 0.0]);
    let e = PreparedGaussian::new(&mean, &DMatrix::identity(2, 2), 3).unwrap_err();
    assert!(matches!(e, KlError::Component { component: 3, .. }), "{e}");
}

#[test]
fn a_control_or_landmark_not_finite_leaves_the_filter_as_it_was() {
    use slam::ekf::{AckermannMotionModel, EkfError};
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity());
    let model = RangeBearingModel::default();
    ekf.add_landmark(&model, &Vector2::new(5.0, 0.1)).unwrap();
    let before = ekf.clone();
    let odometry = OdometryMotionModel::default();
    assert!(matches!(ekf.predict(&odometry, &[f64::NAN, 0.0, 0.0]), Err(EkfError::NonFinite)));
    // A car model of no wheelbase predicts no pose.
    let car = AckermannMotionModel { wheelbase_m: 0.0, ..Default::default() };
    assert!(matches!(ekf.predict(&car, &[1.0, 0.1, 0.1]), Err(EkfError::NonFinite)));
    assert!(matches!(ekf.add_landmark(&model, &Vector2::new(f64::NAN, 0.0)), Err(EkfError::NonFinite)));
    let one_far = [Vector2::new(4.0, 0.0), Vector2::new(f64::INFINITY, 0.0)];
    assert!(matches!(ekf.add_landmarks(&model, &one_far), Err(EkfError::NonFinite)));
    assert_eq!(ekf, before, "refused inputs changed the filter");
    ekf.predict(&odometry, &[0.5, 0.0, 0.0]).unwrap();
    assert!(ekf.state().iter().all(|v| v.is_finite()));
}

#[test]
fn an_image_built_field_by_field_is_checked_before_its_features() {
    use slam::features::{FeatureConfig, FeatureError, FeatureExtractor, ImageRef};
    let config = FeatureConfig::default();
    let dims = config.raw_dims();
    let data = DMatrix::from_fn(40, dims, |i, j| ((i * 7 + j * 3) % 11) as f64 + (i as f64).sin());
    let extractor = FeatureExtractor::new(config, Pca::fit(&data, 3).unwrap()).unwrap();
    let short = vec![0u8; 10];
    let image = ImageRef { width: 64, height: 48, rgb: &short };
    let e = extractor.features(&image, None).unwrap_err();
    assert!(matches!(e, FeatureError::ImageSize { expected: 9216, found: 10, .. }), "{e}");
    let mut no_patches = extractor.clone();
    no_patches.config.patch_size = 0;
    let whole = vec![0u8; 64 * 48 * 3];
    let e = no_patches.features(&ImageRef::new(64, 48, &whole).unwrap(), None).unwrap_err();
    assert!(e.to_string().contains("patch_size"), "{e}");
    // Settings that make no sense beside a PCA that fits them: named, not filtered with.
    let mut no_gain = extractor.clone();
    no_gain.config.channel_gain = vec![0.0; 7];
    let e = no_gain.features(&ImageRef::new(64, 48, &whole).unwrap(), None).unwrap_err();
    assert!(matches!(&e, FeatureError::Settings(s) if s.to_string().contains("channel_gain")), "{e}");
    let mut flat_filter = extractor.clone();
    flat_filter.config.bank.filters[0].gamma = 0.0;
    assert!(matches!(
        flat_filter.features(&ImageRef::new(64, 48, &whole).unwrap(), None),
        Err(FeatureError::Settings(_))
    ));
}

#[test]
fn boards_images_and_drives_of_impossible_sizes_are_refused() {
    use slam::checkerboard::{DetectionError, detect};
    use slam::ekf::synthetic::{Route, drive};
    let k = Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0);
    // Noise, not a flat image (which has no corner candidates whatever the board).
    let rgb: Vec<u8> = (0..32 * 32 * 3).map(|i: usize| (i.wrapping_mul(2654435761) >> 7) as u8).collect();
    assert!(matches!(detect(&rgb, usize::MAX, 3, (7, 5), 0.1, &k), Err(DetectionError::BadImage { .. })));
    let e = detect(&rgb, 32, 32, (usize::MAX, 2), 0.1, &k).unwrap_err();
    assert!(matches!(e, DetectionError::TooFewCorners { found: 0, expected: usize::MAX }), "{e}");
    // More corners than pixels: refused before a search (which finds candidates in noise).
    let e = detect(&rgb, 32, 32, (40, 40), 0.1, &k).unwrap_err();
    assert!(matches!(e, DetectionError::TooFewCorners { found: 0, expected: 1600 }), "{e}");
    assert!(!matches!(detect(&rgb, 32, 32, (4, 4), 0.1, &k), Err(DetectionError::TooFewCorners { found: 0, .. })));
    let route =
        Route { steps: 20, step_m: 0.1, turn: 0.0, scale: 0.0, turn_scale: 0.0, observe_every: 0, max_range_m: 8.0 };
    let d = drive(&route, &[Vector2::new(3.0, 0.0)]).unwrap();
    assert_eq!(d.ekf.landmark_count(), 0, "observed every 0 steps: never");
    let bad = Route { step_m: f64::NAN, observe_every: 2, ..route };
    assert!(matches!(drive(&bad, &[Vector2::new(3.0, 0.0)]), Err(slam::ekf::EkfError::NonFinite)));
}

#[test]
fn a_filter_whose_parts_disagree_is_refused_when_read() {
    let model = RangeBearingModel::default();
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity());
    ekf.use_first_estimates();
    ekf.add_landmark(&model, &Vector2::new(5.0, 0.1)).unwrap();
    assert_eq!(ekf.check(), Ok(()));
    assert_eq!((ekf.state().len(), ekf.covariance().shape(), ekf.vehicle_dims()), (5, (5, 5), 3));
    assert_eq!(ekf.first_estimates().map(|fe| fe.landmarks.len()), Some(1));
    let json = serde_json::to_string(&ekf).unwrap();
    assert_eq!(serde_json::from_str::<Ekf>(&json).unwrap(), ekf);
    // The parts are not public: a filter whose parts disagree can only be read.
    let parts = serde_json::to_value(&ekf).unwrap();
    let with = |edit: &dyn Fn(&mut serde_json::Value)| {
        let mut v = parts.clone();
        edit(&mut v);
        v
    };
    let no_estimates = with(&|v| v["first_estimates"]["landmarks"] = serde_json::json!([]));
    let odd = with(&|v| v["x"] = serde_json::to_value(DVector::from_vec(vec![0.0, 0.0, 0.0, 5.0, 0.5, 1.0])).unwrap());
    let short = with(&|v| v["vehicle_dims"] = serde_json::json!(9));
    let wide = with(&|v| v["p"] = serde_json::to_value(DMatrix::<f64>::identity(5, 6)).unwrap());
    for (bad, says) in [
        (no_estimates, "first estimates of 0 landmarks for a map of 1"),
        (odd, "3 values after the vehicle block, not two per landmark"),
        (short, "a vehicle block of 9 values in a state of 5"),
        (wide, "a 5x6 covariance for a state of 5"),
    ] {
        let e = serde_json::from_value::<Ekf>(bad).unwrap_err();
        assert!(e.to_string().contains(says), "{e}");
    }
}
