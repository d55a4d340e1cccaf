//! Property tests of the park generator and the file formats.

use std::path::Path;

use proptest::prelude::*;
use worlds::generate::{ParkParams, park};
use worlds::{ObjectClass, validate::validate};

fn params() -> impl Strategy<Value = ParkParams> {
    (500.0f64..900.0, 1.2f64..2.0, 4usize..14, 0usize..6, 0usize..3, 0usize..6, any::<bool>(), 0.5f64..1.5).prop_map(
        |(area, aspect, trees, posts, palms, people, wall, post_min)| ParkParams {
            area_m2: area,
            aspect,
            trees,
            posts: posts.min(trees),
            palms,
            people,
            wall,
            post_distance_m: [post_min, post_min + 1.5],
            ..Default::default()
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn generated_worlds_are_valid(p in params(), seed in any::<u64>()) {
        // These bounds leave room for everything: any error is a bug.
        let world = park(&p, seed).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let problems = validate(&world, Path::new("."));
        prop_assert!(problems.is_empty(), "{problems:?}");
        prop_assert_eq!(world.objects.iter().filter(|o| o.class == ObjectClass::Tree).count(), p.trees);
        prop_assert_eq!(world.people.len(), p.people);
        // Posts are within their distance band of some tree, to the 0.71 mm that rounding
        // positions to the millimetre can move them.
        let rounding = 0.0005 * std::f64::consts::SQRT_2 + 1e-9;
        for post in world.objects.iter().filter(|o| o.class == ObjectClass::Post) {
            let near = world.objects.iter().filter(|o| o.class == ObjectClass::Tree).any(|t| {
                let d = ((t.pose.x - post.pose.x).powi(2) + (t.pose.y - post.pose.y).powi(2)).sqrt();
                d >= p.post_distance_m[0] - rounding && d <= p.post_distance_m[1] + rounding
            });
            prop_assert!(near, "post {} is not within {:?} of a tree", post.id, p.post_distance_m);
        }
    }

    #[test]
    fn toml_round_trip_is_lossless(seed in any::<u64>()) {
        let world = park(&ParkParams::default(), seed).unwrap();
        let text = world.to_toml();
        let again = worlds::parse(&text, Path::new("roundtrip.toml")).unwrap();
        prop_assert_eq!(&world, &again);
        prop_assert_eq!(text, again.to_toml());
    }

    #[test]
    fn same_seed_same_bytes(seed in any::<u64>()) {
        let a = park(&ParkParams::default(), seed).unwrap().to_toml();
        let b = park(&ParkParams::default(), seed).unwrap().to_toml();
        prop_assert_eq!(a, b);
    }
}

#[test]
fn park_matches_the_papers_scene() {
    let w = park(&ParkParams::default(), 2006).unwrap();
    let count = |c| w.objects.iter().filter(|o| o.class == c).count();
    assert!((w.ground.area_m2() - 600.0).abs() < 1.0);
    assert!(
        count(ObjectClass::Tree) >= 10
            && count(ObjectClass::Post) >= 4
            && count(ObjectClass::Palm) >= 1
            && count(ObjectClass::Wall) == 1
    );
    for o in w.objects.iter().filter(|o| o.class == ObjectClass::Tree) {
        let worlds::Shape::Trunk { radius_m, .. } = o.shape else { panic!("tree without trunk") };
        assert!((0.1..=0.4).contains(&radius_m));
    }
    assert!(w.robot.laps >= 2 && w.robot.route.looping, "the robot must revisit the park");
    // Every person's walk crosses the robot's loop.
    for p in &w.people {
        let (a, b) = (p.route.waypoints[0], p.route.waypoints[1]);
        let crosses = w.robot.route.segments().iter().any(|(c, d)| segments_intersect(a, b, *c, *d));
        assert!(crosses, "person {} never crosses the robot's path", p.id);
    }
}

fn segments_intersect(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let cross = |o: [f64; 2], p: [f64; 2], q: [f64; 2]| (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0]);
    let d1 = cross(c, d, a);
    let d2 = cross(c, d, b);
    let d3 = cross(a, b, c);
    let d4 = cross(a, b, d);
    d1 * d2 < 0.0 && d3 * d4 < 0.0
}

/// Generator parameters whose ground reaches farther from the origin than a world may are
/// refused at the parameter, with the most area the aspect allows; the largest allowed
/// ground passes validation.
#[test]
fn a_ground_beyond_what_the_simulator_resolves_is_refused_at_its_parameters() {
    let big = ParkParams { area_m2: 2e6, aspect: 4.0, trees: 4, posts: 0, palms: 0, people: 0, ..Default::default() };
    let e = park(&big, 1).unwrap_err().to_string();
    assert!(e.contains("area_m2") && e.contains("at most 1000000 m² at aspect 4"), "{e}");
    let largest = ParkParams { area_m2: 1e6, ..big };
    let world = park(&largest, 1).unwrap();
    assert!(validate(&world, Path::new(".")).is_empty());
}
