//! Walking people: where each one is after walking a distance along its route, and how
//! its legs swing. People give way: the simulator stops advancing a person while the robot
//! stands right ahead of them (see `PhysicsScene::pose_people`).

use worlds::{Person, mesh::HIP_FRACTION};

use crate::messages::PersonState;

/// The state of a person walking freely (never blocked) at time `t`.
pub fn person_state(p: &Person, t: f64) -> PersonState {
    person_state_at(p, ((t - p.start_time_s).max(0.0)) * p.speed_mps)
}

/// The state of a person that has walked `walked` metres along its route.
pub fn person_state_at(p: &Person, walked: f64) -> PersonState {
    let (pos, heading) = p.route.point_at(walked);
    // One gait cycle is two strides; the swing amplitude puts the feet half a stride
    // either side of the hip at full stride.
    let hip = HIP_FRACTION * p.height_m;
    let amplitude = (0.5 * p.stride_m / hip).atan();
    let phase = std::f64::consts::PI * walked / p.stride_m;
    PersonState { id: p.id, x: pos[0], y: pos[1], heading, leg_swing: amplitude * phase.sin() }
}

/// Where a leg's hip joint is, and its swing: (hip x, hip y, hip z, swing rad).
/// `side` is +1 for the left leg, -1 for the right.
pub fn leg_pose(p: &Person, s: &PersonState, side: f64) -> ([f64; 3], f64) {
    let (sn, cs) = s.heading.sin_cos();
    let lateral = side * p.hip_half_width_m;
    let hip = HIP_FRACTION * p.height_m;
    ([s.x - sn * lateral, s.y + cs * lateral, hip], side * s.leg_swing)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn legs_alternate_while_walking_and_stand_still_before_start() {
        let w = worlds::generate::park(&Default::default(), 4).unwrap();
        let p = &w.people[0];
        let before = person_state(p, p.start_time_s - 0.1);
        assert_eq!(before.leg_swing, 0.0);
        let a = person_state(p, p.start_time_s + 0.3);
        let b = person_state(p, p.start_time_s + 0.3 + p.stride_m / p.speed_mps);
        // One stride later the legs have swapped.
        assert!(a.leg_swing.abs() > 0.05 && (a.leg_swing + b.leg_swing).abs() < 1e-9);
    }
}
