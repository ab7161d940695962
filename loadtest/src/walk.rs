//! Smooth walkthroughs made from a scene's bounds alone (the load tester
//! knows a scene only through `GET /scenes`): each virtual user gets its
//! own seeded path.

use pvsd_proto::json::Bounds;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The kind of path.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum WalkKind {
    /// Long straight runs at eye height, turning rarely.
    Street,
    /// Around the scene from outside, looking at its centre.
    Orbit,
    /// Wandering at eye height, turning often.
    Random,
}

/// One frame's camera: eye and forward.
pub type Pose = ([f64; 3], [f64; 3]);

/// An endless path through the box `bounds`.
pub struct Walk {
    kind: WalkKind,
    lo: [f64; 3],
    hi: [f64; 3],
    pos: [f64; 2],
    heading: f64,
    step: f64,
    frame: u64,
    /// Metres walked since the heading last turned.
    since_turn: f64,
    rng: ChaCha8Rng,
}

/// The heading turns (a random amount) once per this many metres walked,
/// whatever the frame rate: a walker at 1.4 m/s and 30 frames a second
/// turns as often per metre as one at the default 0.5 m a frame (once a
/// frame), not 30 times a second.
const TURN_EVERY: f64 = 0.5;

impl Walk {
    /// A path for user `seed`, moving `step` metres a frame.
    pub fn new(kind: WalkKind, bounds: &Bounds, seed: u64, step: f64) -> Walk {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (lo, hi) = (bounds.min, bounds.max);
        let pos = [
            rng.random_range(lo[0]..=hi[0].max(lo[0])),
            rng.random_range(lo[2]..=hi[2].max(lo[2])),
        ];
        Walk {
            kind,
            lo,
            hi,
            pos,
            heading: rng.random_range(0.0..std::f64::consts::TAU),
            step,
            frame: 0,
            since_turn: 0.0,
            rng,
        }
    }

    /// The next pose.
    pub fn next_pose(&mut self) -> Pose {
        self.frame += 1;
        let centre = [
            (self.lo[0] + self.hi[0]) * 0.5,
            (self.lo[1] + self.hi[1]) * 0.5,
            (self.lo[2] + self.hi[2]) * 0.5,
        ];
        if self.kind == WalkKind::Orbit {
            let r = 0.5 * (self.hi[0] - self.lo[0]).hypot(self.hi[2] - self.lo[2]) + 10.0;
            self.heading += self.step / r;
            let eye = [
                centre[0] + r * self.heading.cos(),
                self.hi[1] + 0.1 * r,
                centre[2] + r * self.heading.sin(),
            ];
            let f = [centre[0] - eye[0], centre[1] - eye[1], centre[2] - eye[2]];
            return (eye, f);
        }
        let turn = match self.kind {
            WalkKind::Street => 0.02,
            _ => 0.15,
        };
        self.since_turn += self.step;
        while self.since_turn >= TURN_EVERY {
            self.since_turn -= TURN_EVERY;
            self.heading += self.rng.random_range(-turn..=turn);
        }
        for axis in 0..2 {
            let (lo, hi) = (self.lo[axis * 2], self.hi[axis * 2]);
            let next = self.pos[axis]
                + self.step
                    * if axis == 0 {
                        self.heading.cos()
                    } else {
                        self.heading.sin()
                    };
            if next < lo || next > hi {
                // Turn back into the box.
                self.heading = if axis == 0 {
                    std::f64::consts::PI - self.heading
                } else {
                    -self.heading
                };
            }
        }
        let (dx, dz) = (self.heading.cos(), self.heading.sin());
        self.pos[0] = (self.pos[0] + self.step * dx).clamp(self.lo[0], self.hi[0]);
        self.pos[1] = (self.pos[1] + self.step * dz).clamp(self.lo[2], self.hi[2]);
        ([self.pos[0], self.lo[1] + 1.7, self.pos[1]], [dx, 0.0, dz])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walks_stay_in_the_box_and_move_smoothly() {
        let b = Bounds {
            min: [-10.0, 0.0, -5.0],
            max: [10.0, 20.0, 5.0],
        };
        for kind in [WalkKind::Street, WalkKind::Random, WalkKind::Orbit] {
            let mut w = Walk::new(kind, &b, 3, 0.5);
            let mut last = w.next_pose().0;
            for _ in 0..2000 {
                let (eye, f) = w.next_pose();
                let moved = ((eye[0] - last[0]).powi(2) + (eye[2] - last[2]).powi(2)).sqrt();
                assert!(moved <= 0.51, "{kind:?} jumped {moved}");
                assert!(f.iter().any(|v| *v != 0.0));
                if kind != WalkKind::Orbit {
                    assert!(eye[0] >= -10.0 && eye[0] <= 10.0 && eye[2] >= -5.0 && eye[2] <= 5.0);
                }
                last = eye;
            }
        }
    }
}
