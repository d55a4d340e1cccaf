//! The pipeline's inputs: odometry or controls, scans or detections, camera images,
//! each checked for time order.

use super::*;

impl Pipeline {
    /// Odometry: the motion since the previous message, in the robot frame (the `odometry`
    /// motion model).
    pub fn on_odometry(&mut self, o: &OdometryIncrement) -> Result<(), PipelineError> {
        self.check_time("odometry", o.t)?;
        if ![o.dx, o.dy, o.dtheta].iter().all(|v| v.is_finite()) {
            return Err(PipelineError::NonFinite { input: "odometry", t: o.t });
        }
        if !matches!(self.config.motion, MotionConfig::Odometry(_)) {
            return Err(PipelineError::MotionInput { model: self.config.motion.name(), input: "odometry increments" });
        }
        self.predict([o.dx, o.dy, o.dtheta], o.t)?;
        self.check_state(o.t)
    }

    /// A control (speeds, or speed and steering) that holds from `t` until the next input:
    /// the pipeline first moves on to `t` with the control held so far, so odometry needs no
    /// splitting at scan times.
    pub fn on_control(&mut self, t: f64, control: Control) -> Result<(), PipelineError> {
        self.check_time("control", t)?;
        let finite = match control {
            Control::Differential { v, omega } => v.is_finite() && omega.is_finite(),
            Control::Ackermann { speed, steering } => speed.is_finite() && steering.is_finite(),
        };
        if !finite {
            return Err(PipelineError::NonFinite { input: "control", t });
        }
        match (control, self.config.motion) {
            (Control::Differential { .. }, MotionConfig::Odometry(_))
            | (Control::Ackermann { .. }, MotionConfig::Ackermann(_)) => {}
            (Control::Differential { .. }, m) => {
                return Err(PipelineError::MotionInput { model: m.name(), input: "differential-drive controls" });
            }
            (Control::Ackermann { .. }, m) => {
                return Err(PipelineError::MotionInput { model: m.name(), input: "speed and steering controls" });
            }
        }
        self.advance_to(t)?;
        // The new control holds from t, also when none held before (the vehicle stood).
        self.t = t;
        self.record_pose();
        self.control = Some((t, control));
        self.check_state(t)
    }

    /// Moves the filter on to `t` with the control held since the previous input (nothing
    /// when there is none, as with odometry increments).
    pub(super) fn advance_to(&mut self, t: f64) -> Result<(), PipelineError> {
        let Some((_, control)) = self.control else { return Ok(()) };
        let dt = t - self.t;
        if dt <= 0.0 {
            return Ok(());
        }
        let u = match control {
            // Along the arc of constant speeds, in the robot frame at the start.
            Control::Differential { v, omega } => {
                let turn = omega * dt;
                let (dx, dy) = if turn.abs() < 1e-9 {
                    (v * dt, 0.5 * v * dt * turn)
                } else {
                    (v / omega * turn.sin(), v / omega * (1.0 - turn.cos()))
                };
                [dx, dy, turn]
            }
            Control::Ackermann { speed, steering } => [speed, steering, dt],
        };
        self.predict(u, t)
    }

    /// The prediction with control `u` of the motion model, up to time `t`. One the
    /// filter refuses (a pose it would make not finite) stops the pipeline as a diverged
    /// one, before the input that asked for it changes anything: this input and every one
    /// after it are refused, naming this time.
    pub(super) fn predict(&mut self, u: [f64; 3], t: f64) -> Result<(), PipelineError> {
        match self.ekf.predict(&self.config.motion, &u) {
            Ok(()) => {}
            Err(EkfError::NonFinite) => {
                let (at, how) = *self.diverged_at.get_or_insert((t, super::Divergence::NotFinite));
                return Err(how.error(at));
            }
            // A control or calibration the motion model refuses: the pipeline builds both,
            // so this is not an input's fault, and it is named as it is.
            Err(source) => return Err(PipelineError::Filter { t, source }),
        }
        if let Some(h) = &mut self.history {
            h.push_control(u, self.ekf.pose());
        }
        // The dead-reckoned pose follows the same model, without the filter's corrections.
        let (next, _, _) =
            self.config.motion.predict(&Vector3::from(self.odometry_pose), &u).expect("the filter took this control");
        self.odometry_pose = [next.x, next.y, next.z];
        self.t = t;
        self.record_pose();
        Ok(())
    }

    /// Point features already extracted from a scan (range, bearing and, where known,
    /// diameter, as in Victoria Park's tree detections), for the position-only methods.
    pub fn on_detections(&mut self, t: f64, detections: &[Detection]) -> Result<ScanReport, PipelineError> {
        self.check_time("detections", t)?;
        if self.config.method.uses_appearance() {
            return Err(PipelineError::DetectionsNeedPositionMethod(self.config.method.name()));
        }
        if detections.iter().any(|d| {
            !(d.range_m.is_finite() && d.bearing_rad.is_finite()) || d.diameter_m.is_some_and(|v| !v.is_finite())
        }) {
            return Err(PipelineError::NonFinite { input: "detections", t });
        }
        if detections.iter().any(|d| d.diameter_m.is_some_and(|v| v < 0.0)) {
            return Err(PipelineError::NegativeDiameter { input: "detections", t });
        }
        if detections.iter().any(|d| d.range_m < 0.0) {
            return Err(PipelineError::NegativeRange { input: "detections", t });
        }
        self.advance_to(t)?;
        let clusters: Vec<Cluster> = detections.iter().enumerate().map(|(k, d)| d.as_cluster(k)).collect();
        let keep = vec![true; clusters.len()];
        let report = self.observe_positions(t, clusters, &keep, "unknown")?;
        self.check_state(t)?;
        Ok(report)
    }

    /// Processes a scan. Position-only methods: every size-compatible cluster is an
    /// observation. Appearance methods: the clusters are segmented in the latest image (if
    /// it is recent enough) and only objects are observed.
    pub fn on_scan(&mut self, scan: &LaserScan) -> Result<ScanReport, PipelineError> {
        self.check_time("scan", scan.t)?;
        scan.check().map_err(|problem| PipelineError::Scan { t: scan.t, problem })?;
        self.advance_to(scan.t)?;
        let clusters = cluster(scan, &self.config.clustering);
        let report = if self.config.method.uses_appearance() {
            self.on_scan_with_appearance(scan, clusters)?
        } else {
            let keep = vec![true; clusters.len()];
            self.observe_positions(scan.t, clusters, &keep, "unknown")?
        };
        self.check_state(scan.t)?;
        Ok(report)
    }

    /// Stores a camera image (8-bit RGB, row-major) for the next scans to segment, and
    /// gives back the pixels of the image it replaces, for the caller to reuse.
    pub fn on_image(
        &mut self,
        t: f64,
        width: u32,
        height: u32,
        rgb: Vec<u8>,
    ) -> Result<Option<Vec<u8>>, PipelineError> {
        self.on_image_regions(t, width, height, rgb, None)
    }

    /// [`Pipeline::on_image`] for an image rendered only in the pixel `regions` (see
    /// [`Pipeline::image_region`]). A cluster whose segmentation would read outside them
    /// is not segmented and is counted in [`Pipeline::unrendered_reads`].
    pub fn on_image_regions(
        &mut self,
        t: f64,
        width: u32,
        height: u32,
        rgb: Vec<u8>,
        regions: Option<Vec<PixelRegion>>,
    ) -> Result<Option<Vec<u8>>, PipelineError> {
        // Images may come after scans of later times (a camera's latency), but not before
        // the image they replace: a scan would be segmented in the older one.
        self.check_running("image", t)?;
        if let Some(previous) = &self.image
            && t < previous.t
        {
            return Err(PipelineError::ImageTimeReversed { t, previous: previous.t });
        }
        let expected = (width as usize).saturating_mul(height as usize).saturating_mul(3);
        if rgb.len() != expected {
            return Err(PipelineError::Image { width, height, expected, found: rgb.len() });
        }
        // Segmentation projects clusters with the camera's geometry: an image of another
        // size would be read at the wrong pixels.
        if let Some(app) = &self.appearance
            && (width, height) != (app.camera.width, app.camera.height)
        {
            return Err(PipelineError::ImageSize { width, height, camera: (app.camera.width, app.camera.height) });
        }
        Ok(self.image.replace(StoredImage { t, width, height, rgb, regions }).map(|spent| spent.rgb))
    }

    /// The pixels this pipeline's segmentation reads, scan by scan (appearance
    /// methods only): a camera that renders just those gives it the same results.
    pub fn image_region(&self) -> Option<ImageRegion> {
        let app = self.appearance.as_ref()?;
        Some(ImageRegion {
            clustering: self.config.clustering,
            segmentation: self.config.segmentation.clone(),
            features: app.model.extractor.config.clone(),
            camera: app.camera.clone(),
        })
    }

    /// Clusters left unsegmented because their image was not rendered where segmentation
    /// reads: non-zero only when a camera's regions disagree with [`Pipeline::image_region`].
    pub fn unrendered_reads(&self) -> usize {
        self.unrendered_reads
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ekf::AckermannMotionModel;

    fn car_config(method: AssociationMethod) -> PipelineConfig {
        PipelineConfig {
            method,
            motion: MotionConfig::Ackermann(AckermannMotionModel::default()),
            confirm_observations: 1,
            ..Default::default()
        }
    }

    fn detection(range_m: f64, bearing_rad: f64, diameter_m: f64) -> Detection {
        Detection { range_m, bearing_rad, diameter_m: Some(diameter_m) }
    }

    #[test]
    fn a_new_image_gives_back_the_pixels_of_the_one_it_replaces() {
        let config = PipelineConfig { method: AssociationMethod::Nn, ..Default::default() };
        let mut p = Pipeline::new(config, [0.0; 3], None).unwrap();
        assert_eq!(p.on_image(0.0, 2, 1, vec![1; 6]).unwrap(), None);
        assert_eq!(p.on_image(0.1, 2, 1, vec![2; 6]).unwrap(), Some(vec![1; 6]));
        // A refused image replaces nothing.
        assert!(p.on_image(0.2, 2, 1, vec![3; 5]).is_err());
        assert_eq!(p.on_image(0.3, 2, 1, vec![4; 6]).unwrap(), Some(vec![2; 6]));
    }

    /// Images, scans, clusters and the start are checked as odometry is: a value that is
    /// not finite, a time that goes back or a scan whose beams have no angles is an error,
    /// not a quiet scan of no clusters or a landmark that is not finite.
    #[test]
    fn malformed_images_scans_clusters_and_starts_are_errors() {
        let config = PipelineConfig { method: AssociationMethod::Nn, ..Default::default() };
        assert!(matches!(
            Pipeline::new(config.clone(), [f64::NAN, 0.0, 0.0], None),
            Err(PipelineError::StartNotFinite("pose"))
        ));
        let fresh = || Pipeline::new(config.clone(), [0.0; 3], None).unwrap();
        assert!(matches!(fresh().starting_at(f64::INFINITY), Err(PipelineError::StartNotFinite("time"))));
        let mut p = fresh();
        assert!(matches!(p.on_image(f64::NAN, 2, 1, vec![0; 6]), Err(PipelineError::NonFinite { input: "image", .. })));
        p.on_image(1.0, 2, 1, vec![0; 6]).unwrap();
        let e = p.on_image(0.5, 2, 1, vec![0; 6]).unwrap_err();
        assert!(matches!(e, PipelineError::ImageTimeReversed { t: 0.5, previous: 1.0 }), "{e}");
        // An image may lag the scans: one of an earlier time than the latest input is fine.
        p.on_odometry(&OdometryIncrement { t: 2.0, dx: 0.0, dy: 0.0, dtheta: 0.0 }).unwrap();
        p.on_image(1.5, 2, 1, vec![0; 6]).unwrap();
        let scan = LaserScan {
            t: 2.0,
            angle_min: -1.0,
            angle_increment: 0.01,
            range_min: 0.0,
            range_max: f64::INFINITY,
            ranges: vec![5.0; 200],
        };
        p.on_scan(&scan).unwrap();
        for (broken, named) in [
            (LaserScan { angle_increment: f64::NAN, ..scan.clone() }, "angle_increment NaN"),
            (LaserScan { angle_increment: 0.0, ..scan.clone() }, "angle_increment 0"),
            (LaserScan { angle_min: f64::NEG_INFINITY, ..scan.clone() }, "angle_min -inf"),
            (LaserScan { range_min: f64::NAN, ..scan.clone() }, "range_min NaN"),
            (LaserScan { range_min: -1.0, ..scan.clone() }, "range_min -1"),
            (LaserScan { range_min: 5.0, range_max: 1.0, ..scan.clone() }, "range_max 1"),
        ] {
            let e = p.on_scan(&LaserScan { t: 2.5, ..broken }).unwrap_err();
            assert!(matches!(e, PipelineError::Scan { t: 2.5, .. }) && e.to_string().contains(named), "{e}");
        }
        // A refused input leaves the clock and the estimate as they were.
        let before = p.pose();
        assert_eq!((p.time(), before.t), (2.0, 2.0));
        let mut c = detection(5.0, 0.0, 0.3).as_cluster(0);
        c.range_m = f64::NAN;
        assert!(matches!(
            p.on_scan_with_objects(3.0, vec![c], &[true], "tree"),
            Err(PipelineError::NonFinite { input: "clusters", t: 3.0 })
        ));
        let mut c = detection(5.0, 0.0, 0.3).as_cluster(0);
        c.diameter_m = f64::INFINITY;
        assert!(matches!(
            p.on_scan_with_objects(3.0, vec![c.clone()], &[true], "tree"),
            Err(PipelineError::NonFinite { input: "clusters", t: 3.0 })
        ));
        c.diameter_m = -0.3;
        assert!(matches!(
            p.on_scan_with_objects(3.0, vec![c], &[true], "tree"),
            Err(PipelineError::NegativeDiameter { input: "clusters", t: 3.0 })
        ));
        assert!(matches!(
            p.on_detections(3.0, &[detection(5.0, 0.0, -0.3)]),
            Err(PipelineError::NegativeDiameter { input: "detections", t: 3.0 })
        ));
        assert!(matches!(
            p.on_detections(3.0, &[detection(-5.0, 0.0, 0.3)]),
            Err(PipelineError::NegativeRange { input: "detections", t: 3.0 })
        ));
        let mut behind = detection(5.0, 0.0, 0.3).as_cluster(0);
        behind.range_m = -5.0;
        assert!(matches!(
            p.on_scan_with_objects(3.0, vec![behind], &[true], "tree"),
            Err(PipelineError::NegativeRange { input: "clusters", t: 3.0 })
        ));
        assert_eq!((p.time(), p.pose()), (2.0, before), "refused inputs changed the pipeline");
        // Refused inputs leave the pipeline as it was: a sound scan goes on, and a cluster
        // of unknown diameter (NaN) is sound.
        let unknown = Detection { range_m: 5.0, bearing_rad: 0.0, diameter_m: None }.as_cluster(1);
        assert!(unknown.diameter_m.is_nan());
        let both = vec![detection(5.0, 0.0, 0.3).as_cluster(0), unknown];
        p.on_scan_with_objects(3.0, both, &[true, true], "tree").unwrap();
    }

    #[test]
    fn inputs_out_of_time_order_are_errors() {
        let mut p =
            Pipeline::new(PipelineConfig { method: AssociationMethod::Nn, ..Default::default() }, [0.0; 3], None)
                .unwrap()
                .starting_at(100.0)
                .unwrap();
        assert_eq!(p.pose().t, 100.0, "the first pose is stamped at the log's start");
        let early = OdometryIncrement { t: 99.0, dx: 0.1, dy: 0.0, dtheta: 0.0 };
        assert!(matches!(p.on_odometry(&early), Err(PipelineError::TimeReversed { t: 99.0, previous: 100.0, .. })));
        p.on_odometry(&OdometryIncrement { t: 101.0, ..early }).unwrap();
        let bad = p.on_detections(100.5, &[]).unwrap_err();
        assert!(bad.to_string().contains("t = 100.5 s comes before the previous input at t = 101 s"), "{bad}");
        let nan = OdometryIncrement { t: 102.0, dx: f64::NAN, dy: 0.0, dtheta: 0.0 };
        assert!(matches!(p.on_odometry(&nan), Err(PipelineError::NonFinite { .. })));
        assert!(matches!(
            p.on_scan_with_objects(103.0, vec![detection(5.0, 0.0, 0.3).as_cluster(0)], &[], "tree"),
            Err(PipelineError::ObjectFlags { given: 0, clusters: 1 })
        ));
        // A car's controls do not fit the odometry model, nor increments the car model.
        assert!(matches!(
            p.on_control(104.0, Control::Ackermann { speed: 1.0, steering: 0.0 }),
            Err(PipelineError::MotionInput { model: "odometry", .. })
        ));
        let mut car = Pipeline::new(car_config(AssociationMethod::Nn), [0.0; 3], None).unwrap();
        assert!(matches!(
            car.on_odometry(&OdometryIncrement { t: 1.0, ..early }),
            Err(PipelineError::MotionInput { .. })
        ));
        // The camera methods need an appearance model; without one's checks, they still
        // refuse point detections.
        assert!(matches!(
            Pipeline::new(PipelineConfig::default(), [0.0; 3], None),
            Err(PipelineError::NeedsAppearance("combined"))
        ));
        let mut combined = Pipeline::unchecked(PipelineConfig::default(), [0.0; 3]);
        assert!(matches!(combined.on_detections(1.0, &[]), Err(PipelineError::DetectionsNeedPositionMethod(_))));
    }

    #[test]
    fn a_held_control_moves_the_car_up_to_each_detection() {
        let mut p = Pipeline::new(car_config(AssociationMethod::Nn), [0.0; 3], None).unwrap();
        p.on_control(0.0, Control::Ackermann { speed: 2.0, steering: 0.0 }).unwrap();
        // No further control: the detections at 1.5 s find the car 3 m on.
        p.on_detections(1.5, &[]).unwrap();
        assert!((p.pose().pose[0] - 3.0).abs() < 1e-12 && p.pose().t == 1.5);
        p.on_control(2.0, Control::Ackermann { speed: 0.0, steering: 0.0 }).unwrap();
        assert!((p.pose().pose[0] - 4.0).abs() < 1e-12);
        // A first control after other inputs holds from its own time, not theirs.
        let mut late = Pipeline::new(car_config(AssociationMethod::Nn), [0.0; 3], None).unwrap();
        late.on_detections(4.9, &[]).unwrap();
        late.on_control(5.0, Control::Ackermann { speed: 2.0, steering: 0.0 }).unwrap();
        late.on_detections(5.1, &[]).unwrap();
        assert!((late.pose().pose[0] - 0.2).abs() < 1e-12, "{:?}", late.pose());
        // A differential drive's speeds through the odometry model: a quarter circle.
        let mut robot =
            Pipeline::new(PipelineConfig { method: AssociationMethod::Nn, ..Default::default() }, [0.0; 3], None)
                .unwrap();
        robot.on_control(0.0, Control::Differential { v: 1.0, omega: std::f64::consts::FRAC_PI_2 }).unwrap();
        robot.on_detections(1.0, &[]).unwrap();
        let r = 2.0 / std::f64::consts::PI;
        let [x, y, th] = robot.pose().pose;
        assert!((x - r).abs() < 1e-9 && (y - r).abs() < 1e-9 && (th - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
    }

    /// A covariance no longer positive definite while the state stays finite (what a
    /// corrupt odometry row of kilometres left in a real log) gives negative squared
    /// distances: the scan is refused, and every input after it, rather than replayed into
    /// negative NIS figures.
    #[test]
    fn a_covariance_that_is_no_longer_positive_definite_is_refused() {
        let mut p =
            Pipeline::new(PipelineConfig { method: AssociationMethod::Nn, ..Default::default() }, [0.0; 3], None)
                .unwrap();
        let seen = [detection(5.0, 0.3, 0.3), detection(8.0, -0.4, 0.3)];
        for k in 1..=5 {
            p.on_detections(0.1 * k as f64, &seen).unwrap();
        }
        assert!(p.ekf.landmark_count() >= 2);
        // The landmarks' variances turned negative, as cancellation leaves them.
        for i in p.ekf.landmark_offset()..p.ekf.p.nrows() {
            p.ekf.p[(i, i)] = -1e3;
        }
        let moved = [detection(5.1, 0.3, 0.3), detection(8.0, -0.4, 0.3)];
        let err = p.on_detections(0.6, &moved).unwrap_err();
        assert!(matches!(err, PipelineError::Indefinite { t: 0.6 }), "{err}");
        assert!(err.to_string().contains("stopped being positive definite at t = 0.6 s"), "{err}");
        let sane = OdometryIncrement { t: 0.7, dx: 0.1, dy: 0.0, dtheta: 0.0 };
        assert!(matches!(p.on_odometry(&sane), Err(PipelineError::Indefinite { t: 0.6 })));
    }

    /// A negative variance is found without waiting for a scan to measure a distance: the
    /// next input that moves the filter reports it, and every input after it is refused.
    #[test]
    fn a_negative_variance_is_refused_at_the_next_input() {
        let mut p =
            Pipeline::new(PipelineConfig { method: AssociationMethod::Nn, ..Default::default() }, [0.0; 3], None)
                .unwrap();
        p.on_odometry(&OdometryIncrement { t: 0.1, dx: 0.1, dy: 0.0, dtheta: 0.0 }).unwrap();
        p.ekf.p[(2, 2)] = -1.0;
        let err = p.on_odometry(&OdometryIncrement { t: 0.2, dx: 0.1, dy: 0.0, dtheta: 0.0 }).unwrap_err();
        assert!(matches!(err, PipelineError::Indefinite { t: 0.2 }), "{err}");
        assert!(matches!(p.on_detections(0.3, &[]), Err(PipelineError::Indefinite { t: 0.2 })));
    }

    #[test]
    fn a_control_that_overflows_the_prediction_changes_nothing_after_it() {
        let mut p = Pipeline::new(car_config(AssociationMethod::Nn), [0.0; 3], None).unwrap();
        p.on_control(0.0, Control::Ackermann { speed: 1e300, steering: 0.0 }).unwrap();
        let (time, pose, landmarks) = (p.time(), p.pose(), p.landmarks().len());
        let err = p.on_detections(1.0, &[detection(5.0, 0.0, 0.3)]).unwrap_err();
        assert!(matches!(err, PipelineError::Diverged { t: 1.0 }), "{err}");
        assert_eq!((p.time(), p.pose(), p.landmarks().len()), (time, pose, landmarks), "the scan was not applied");
        assert!(matches!(p.on_detections(2.0, &[]), Err(PipelineError::Diverged { t: 1.0 })));
    }

    #[test]
    fn an_input_that_overflows_the_filter_is_refused_and_so_is_everything_after_it() {
        // A finite but absurd increment: its noise's variance overflows.
        let mut p =
            Pipeline::new(PipelineConfig { method: AssociationMethod::Nn, ..Default::default() }, [0.0; 3], None)
                .unwrap();
        p.on_odometry(&OdometryIncrement { t: 0.1, dx: 0.1, dy: 0.0, dtheta: 0.0 }).unwrap();
        let absurd = OdometryIncrement { t: 0.2, dx: 1e300, dy: 0.0, dtheta: 0.0 };
        let err = p.on_odometry(&absurd).unwrap_err();
        assert!(matches!(err, PipelineError::Diverged { t: 0.2 }), "{err}");
        assert!(err.to_string().contains("stopped being finite at t = 0.2 s"), "{err}");
        assert!(p.ekf.is_finite(), "the refused prediction left the filter as it was");
        // Sticky: sane inputs later are refused, naming the same instant.
        let sane = OdometryIncrement { t: 0.3, dx: 0.1, dy: 0.0, dtheta: 0.0 };
        assert!(matches!(p.on_odometry(&sane), Err(PipelineError::Diverged { t: 0.2 })));
        assert!(matches!(p.on_detections(0.4, &[]), Err(PipelineError::Diverged { t: 0.2 })));
    }

    #[test]
    fn the_diameter_cue_keeps_a_thin_post_off_a_thick_tree() {
        // A thick tree mapped at 10 m; then, from the same place, a thin one 0.4 m beside
        // it, well inside the position gate of a filter this unsure.
        let run = |for_position_methods: bool| {
            let config = PipelineConfig {
                diameter: DiameterCheck { for_position_methods, ..Default::default() },
                sensor: RangeBearingModel { range_sigma_m: 0.3, bearing_sigma_rad: 0.05, ..Default::default() },
                ..car_config(AssociationMethod::Nn)
            };
            let mut p = Pipeline::new(config, [0.0; 3], None).unwrap();
            p.on_detections(0.1, &[detection(10.0, 0.0, 0.8)]).unwrap();
            let report = p.on_detections(0.2, &[detection(10.0, 0.04, 0.2)]).unwrap();
            report.decisions[0].choice
        };
        assert_eq!(run(false), Choice::Existing { landmark: 0 }, "position alone takes the tree");
        assert!(!matches!(run(true), Choice::Existing { .. }), "the diameter refuses it");
        // Without a diameter the detection fits any landmark.
        let d = DiameterCheck::default();
        assert!(d.compatible(f64::NAN, 10.0, 0.8, 3) && d.compatible(0.2, 10.0, f64::NAN, 1));
    }

    #[test]
    fn batched_updates_make_the_same_associations() {
        // A car driving along a row of trees, detections with a little noise: the batched
        // and sequential filters associate identically and end within centimetres.
        let trees: Vec<[f64; 2]> = (0..12).map(|k| [4.0 * k as f64, if k % 2 == 0 { 6.0 } else { -5.0 }]).collect();
        let run = |batch_updates: bool| {
            let mut p =
                Pipeline::new(PipelineConfig { batch_updates, ..car_config(AssociationMethod::Nn) }, [0.0; 3], None)
                    .unwrap();
            let mut choices = Vec::new();
            for step in 0..100 {
                let t = step as f64 * 0.25;
                p.on_control(t, Control::Ackermann { speed: 2.0 * 1.01, steering: 0.002 }).unwrap();
                let truth = [2.0 * t, 0.0];
                let dets: Vec<Detection> = trees
                    .iter()
                    .enumerate()
                    .filter_map(|(k, tr)| {
                        let (dx, dy) = (tr[0] - truth[0] - 0.16, tr[1] - truth[1]);
                        let r = dx.hypot(dy);
                        let noise = ((step * 7 + k * 3) % 5) as f64 * 0.004 - 0.008;
                        (r < 15.0).then(|| detection(r + noise, dy.atan2(dx) + noise * 0.1, 0.3))
                    })
                    .collect();
                let report = p.on_detections(t + 0.1, &dets).unwrap();
                choices.extend(report.decisions.into_iter().map(|d| d.choice));
            }
            (choices, p.pose().pose)
        };
        let (seq_choices, seq_pose) = run(false);
        let (batch_choices, batch_pose) = run(true);
        assert_eq!(seq_choices, batch_choices);
        assert!(seq_choices.iter().filter(|c| matches!(c, Choice::Existing { .. })).count() > 300);
        assert!((seq_pose[0] - batch_pose[0]).hypot(seq_pose[1] - batch_pose[1]) < 0.02, "{seq_pose:?} {batch_pose:?}");
    }
}
