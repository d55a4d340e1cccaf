//! Calibration target: the rendered checkerboard is found and its plane recovered.

use nalgebra::{Matrix3, Vector3};
use worlds::*;

#[test]
fn rendered_checkerboards_are_detected_with_their_planes() {
    let mut world = worlds::generate::park(&Default::default(), 2006).unwrap();
    world.objects.clear();
    world.people.clear();
    let cam_cfg = sim::camera::CameraConfig::default();
    let k = cam_cfg.intrinsics();
    let km = Matrix3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0);
    let eye = [0.0, 0.0, 0.6];
    let cases = [
        // (distance, bearing, turn away from facing the camera, tilt): deg
        (2.0f64, 0.0f64, 0.0f64, 0.0f64),
        (2.5, 10.0, 30.0, 0.0),
        (1.8, -12.0, -35.0, 0.0),
        (3.0, 5.0, 20.0, 0.0),
        (2.2, 0.0, 0.0, 30.0),
        (2.0, -5.0, 25.0, -30.0),
    ];
    for (i, (dist, bearing_deg, turn_deg, tilt_deg)) in cases.into_iter().enumerate() {
        let b = f64::to_radians(bearing_deg);
        let (bx, by) = (dist * b.cos(), dist * b.sin());
        // Facing back towards the camera, turned by turn_deg.
        let yaw = b + std::f64::consts::PI + turn_deg.to_radians();
        let mut w = world.clone();
        let shape =
            Shape::Board { width_m: 0.8, height_m: 0.6, bottom_m: 0.3, squares: [8, 6], tilt_deg, roll_deg: 0.0 };
        let frame = shape.board_frame().unwrap();
        w.objects.push(StaticObject::checkerboard(700, Pose2 { x: bx, y: by, yaw_deg: yaw.to_degrees() }, shape));
        let mut cam = sim::camera::CameraSensor::new(&w, &cam_cfg, 1).unwrap();
        let pose = scenarios::dataset::look_at(eye, [bx, by, 0.6]);
        let fr = cam.render_from(0.0, pose).unwrap();
        let det = slam::checkerboard::detect(&fr.image.rgb, 640, 480, (7, 5), 0.1, &km)
            .unwrap_or_else(|e| panic!("board {i}: {e}"));
        assert!(
            det.rms_px < 0.2 && det.reprojection_rms_px < 0.2,
            "board {i}: corner residual {} px",
            det.reprojection_rms_px
        );
        // True plane: the board's front face, in the camera frame.
        let (s, c) = yaw.sin_cos();
        let nm = frame.normal();
        let n_w = Vector3::new(c * nm[0] - s * nm[1], s * nm[0] + c * nm[1], nm[2]);
        let pm = frame.apply([BOARD_THICKNESS_M / 2.0, 0.0, 0.0]);
        let p_w = Vector3::new(bx + c * pm[0] - s * pm[1], by + s * pm[0] + c * pm[1], pm[2]);
        let cam_from_world = pose.inverse();
        let r = Matrix3::from_fn(|a, c| cam_from_world.r[a][c]);
        let n_c = r * n_w;
        let p_c = Vector3::from(cam_from_world.apply([p_w.x, p_w.y, p_w.z]));
        // N = n (n . p) does not depend on the sign of n.
        let truth = n_c * n_c.dot(&p_c);
        let angle = det.plane.normalize().dot(&truth.normalize()).clamp(-1.0, 1.0).acos().to_degrees();
        let distance = (det.plane.norm() - truth.norm()).abs();
        eprintln!(
            "board {i}: angle {angle:.3} deg, distance est {:.4} true {:.4}, rms {:.3}",
            det.plane.norm(),
            truth.norm(),
            det.reprojection_rms_px
        );
        // Measured (llvmpipe): at most 0.06 deg and 1 mm. Before the pose fit and the
        // gradient corner refinement, boards turned 15-35 deg were off by up to 0.85 deg
        // and 3 cm (the plane read from the homography's columns amplified corner noise).
        assert!(angle < 0.2, "board {i}: normal off by {angle} deg");
        assert!(distance < 0.005, "board {i}: distance off by {distance} m");
    }
}

#[test]
fn no_board_in_view_is_reported_not_fatal() {
    let world = worlds::generate::park(&Default::default(), 2006).unwrap();
    let cam_cfg = sim::camera::CameraConfig::default();
    let k = cam_cfg.intrinsics();
    let km = Matrix3::new(k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0);
    let mut cam = sim::camera::CameraSensor::new(&world, &cam_cfg, 1).unwrap();
    let frame = cam.render_from(0.0, scenarios::dataset::look_at([0.0, -6.0, 0.6], [5.0, -6.0, 0.6])).unwrap();
    assert!(slam::checkerboard::detect(&frame.image.rgb, 640, 480, (7, 5), 0.1, &km).is_err());
}
