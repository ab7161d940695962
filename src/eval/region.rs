//! Evaluating region answers: the cameras whose truth one region answer
//! is held to, and how often a walking client that keeps its answer while
//! it stays in the region has to ask again.
//!
//! A region answer must hold every truth-visible object of every view of
//! the region; no finite sample proves that, but the extremes are where a
//! wrong enclosure or a wrongly shrunk occluder shows first: the ball's
//! centre, the six points of its surface along the camera's axes and the
//! eight along its diagonals, a few random points inside it, and the
//! directions on the cone's edge (turned by the whole angle left, right,
//! up, down, along the diagonals, and rolled both ways).

use glam::{DQuat, DVec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::walk::resample;
use crate::geom::{Camera, Region};

/// Random eyes inside the ball per frame, besides the fixed ones.
const RANDOM_EYES: usize = 2;

/// The cameras of `region` around `camera` whose truths one answer is held
/// to (module docs): one for a point region; 17 for a ball; 11 for a cone;
/// 27 and a few random pairs for both. `seed` picks the random ones.
pub fn sample_cameras(camera: &Camera, region: Region, seed: u64) -> Vec<Camera> {
    let Some(basis) = camera.basis() else {
        return vec![*camera];
    };
    let (f, r, u) = (basis.forward, basis.right, basis.up);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let radius = region.radius();
    let mut eyes = vec![camera.eye];
    if radius > 0.0 {
        for axis in [f, r, u] {
            eyes.push(camera.eye + axis * radius);
            eyes.push(camera.eye - axis * radius);
        }
        for k in 0..8 {
            let s = |bit: usize| if k & bit == 0 { -1.0 } else { 1.0 };
            let d = (r * s(1) + u * s(2) + f * s(4)) / 3f64.sqrt();
            eyes.push(camera.eye + d * radius);
        }
        for _ in 0..RANDOM_EYES {
            eyes.push(camera.eye + random_in_ball(&mut rng) * radius);
        }
    }
    let angle = region.angle_deg().to_radians();
    let mut turns = vec![DQuat::IDENTITY];
    if angle > 0.0 {
        let diagonal = |a: DVec3, b: DVec3| (a + b).normalize();
        for axis in [
            u,
            -u,
            r,
            -r,
            diagonal(u, r),
            diagonal(u, -r),
            diagonal(-u, r),
            diagonal(-u, -r),
            f,
            -f,
        ] {
            turns.push(DQuat::from_axis_angle(axis, angle));
        }
    }
    let turned = |eye: DVec3, q: DQuat| Camera {
        eye,
        forward: q * f,
        up: q * u,
        ..*camera
    };
    let mut out: Vec<Camera> = eyes.iter().map(|&e| turned(e, DQuat::IDENTITY)).collect();
    out.extend(turns[1..].iter().map(|&q| turned(camera.eye, q)));
    if radius > 0.0 && angle > 0.0 {
        // Both at their extremes at once: surface eyes, cone-edge turns.
        for _ in 0..4 {
            let eye = eyes[rng.random_range(1..15)];
            let q = turns[rng.random_range(1..turns.len())];
            out.push(turned(eye, q));
        }
    }
    out
}

fn random_in_ball(rng: &mut ChaCha8Rng) -> DVec3 {
    loop {
        let v = DVec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if v.length_squared() <= 1.0 {
            return v;
        }
    }
}

/// The share of its frames on which a client walking the path of
/// `cameras` at `speed` (units/s), 30 frames a second, asks for a new
/// answer, when it keeps each answer while its eye stays within the
/// region's radius of the eye asked for and its direction within the
/// angle (1 for a point region: every frame).
pub fn request_share(cameras: &[Camera], region: Region, speed: f64) -> f64 {
    let step = speed / 30.0;
    let length: f64 = cameras
        .windows(2)
        .map(|w| w[0].eye.distance(w[1].eye))
        .sum();
    if !step.is_finite() || step <= 0.0 || length <= 0.0 {
        return 1.0;
    }
    let frames = ((length / step).ceil() as usize + 1).min(1_000_000);
    let walked = resample(cameras, step, frames);
    let mut asked: Option<Camera> = None;
    let mut requests = 0usize;
    for c in &walked {
        let keeps = asked.is_some_and(|a| {
            a.eye.distance(c.eye) <= region.radius() && turn_deg(&a, c) <= region.angle_deg()
        }) && !region.is_point();
        if !keeps {
            asked = Some(*c);
            requests += 1;
        }
    }
    requests as f64 / walked.len() as f64
}

/// The angle of the rotation from `a`'s camera frame to `b`'s, degrees
/// (roll included: how the region's `angle` is defined); 180 when either
/// has no frame.
fn turn_deg(a: &Camera, b: &Camera) -> f64 {
    let (Some(a), Some(b)) = (a.basis(), b.basis()) else {
        return 180.0;
    };
    let trace = a.right.dot(b.right) + a.up.dot(b.up) + a.forward.dot(b.forward);
    ((trace - 1.0) * 0.5).clamp(-1.0, 1.0).acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_hold_the_extremes_of_the_region() {
        let cam = Camera::default();
        assert_eq!(sample_cameras(&cam, Region::POINT, 1).len(), 1);
        let ball = sample_cameras(&cam, Region::new(2.0, 0.0).unwrap(), 1);
        assert_eq!(ball.len(), 17);
        assert!(ball.iter().all(|c| c.eye.distance(cam.eye) <= 2.0 + 1e-12));
        assert_eq!(
            ball.iter()
                .filter(|c| (c.eye.distance(cam.eye) - 2.0).abs() < 1e-12)
                .count(),
            14
        );
        let cone = sample_cameras(&cam, Region::new(0.0, 15.0).unwrap(), 1);
        assert_eq!(cone.len(), 11);
        for c in &cone[1..] {
            // Every turn is by the whole angle: the frame's rotation angle.
            let b = c.basis().unwrap();
            let o = cam.basis().unwrap();
            let trace = b.right.dot(o.right) + b.up.dot(o.up) + b.forward.dot(o.forward);
            let turn = ((trace - 1.0) / 2.0).acos().to_degrees();
            assert!((turn - 15.0).abs() < 1e-9, "{turn}");
        }
        let both = sample_cameras(&cam, Region::new(1.0, 5.0).unwrap(), 1);
        assert!(both.len() >= 16 + 4, "{}", both.len());
    }

    #[test]
    fn a_walker_keeping_its_answer_asks_less_the_larger_the_ball() {
        let cams: Vec<Camera> = (0..50)
            .map(|i| Camera {
                eye: DVec3::new(i as f64, 1.7, 0.0),
                forward: DVec3::X,
                ..Camera::default()
            })
            .collect();
        assert_eq!(request_share(&cams, Region::POINT, 1.4), 1.0);
        let one = request_share(&cams, Region::new(1.0, 0.0).unwrap(), 1.4);
        // 1.4 m/s at 30 frames/s: a new request every 22nd frame.
        assert!((one - 1.0 / 22.0).abs() < 0.01, "{one}");
        assert!(request_share(&cams, Region::new(5.0, 0.0).unwrap(), 1.4) < one);
    }
}
