//! The library's misuse: bad data is a typed error, never a quiet NaN; a caller's bug
//! (a slice of the wrong length) is a panic that says what was wrong, never a wrong answer.

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
    let ln_p = sound.evaluator().unwrap().log_density(&[0.0, 0.0]);
    assert!((ln_p + (2.0 * std::f64::consts::PI).ln()).abs() < 1e-12, "{ln_p}");
}

#[test]
#[should_panic(expected = "a point of 3 dimensions for a mixture of 2")]
fn a_point_of_another_dimension_is_not_scored() {
    let g = Gmm { components: vec![gaussian(1.0, &[0.0, 0.0])] };
    g.evaluator().unwrap().log_density(&[0.0, 0.0, 9.0]);
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
#[should_panic(expected = "a control of 1 values for a motion model of 3")]
fn a_control_of_the_wrong_length_is_named() {
    let mut ekf = Ekf::new(Vector3::zeros(), Matrix3::identity());
    ekf.predict(&OdometryMotionModel::default(), &[0.1]).unwrap();
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
#[should_panic(expected = "need dof >= 1 and 0 <= p < 1")]
fn a_chi_square_quantile_outside_its_domain_is_named() {
    chi2_quantile(2, 1.5);
}

#[test]
#[should_panic(expected = "Ekf: no landmark with index 0 (the map holds 0)")]
fn a_landmark_past_the_map_is_named() {
    let ekf = Ekf::new(Vector3::zeros(), Matrix3::identity());
    ekf.mahalanobis2(&RangeBearingModel::default(), 0, &Vector2::new(5.0, 0.0));
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
    assert!(ekf.x.iter().all(|v| v.is_finite()));
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
}
