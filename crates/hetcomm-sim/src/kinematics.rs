//! Differential-drive ("tank steering") kinematics with exact arc integration.
//!
//! # Model
//!
//! A rover has two wheels a distance `wheel_base` apart. The thesis's rovers only ever
//! send dimensionless wheel *commands* (`1`/`1` to go straight, `-10`/`+10` to pivot left,
//! `0`/`0` to stop), so [`DiffDrive::speed_scale`] turns a command into a ground speed in
//! world units per second. With left and right commands `l` and `r`:
//!
//! ```text
//! v = speed_scale · (l + r) / 2            (forward speed, units/s)
//! ω = speed_scale · (r − l) / wheel_base   (turn rate, rad/s, counter-clockwise positive)
//! ```
//!
//! Over a step of `dt` seconds with constant `l`, `r` the rover follows a circular arc (a
//! straight line when `l == r`, a pivot in place when `l == −r`). [`DiffDrive::step`]
//! integrates that arc *exactly* rather than with an Euler step, so splitting one step into
//! many small ones gives the same pose up to floating-point rounding. With `φ = ω·dt`:
//!
//! ```text
//! θ₁ = θ₀ + φ
//! x₁ = x₀ + v·dt · cos(θ₀ + φ/2) · sinc(φ/2)
//! y₁ = y₀ + v·dt · sin(θ₀ + φ/2) · sinc(φ/2)      where sinc(u) = sin(u)/u, sinc(0) = 1
//! ```
//!
//! This is the textbook `R·(sin θ₁ − sin θ₀)` arc formula rewritten with the
//! sum-to-product identity; the `sinc` form has no division by ω, so it stays accurate
//! for nearly straight motion and is exact (bit for bit) for the two special cases:
//! `l == r` gives `φ = 0` (θ untouched) and `l == −r` gives `v = 0` (x, y untouched).
//!
//! # Default parameters
//!
//! [`DiffDrive::default`] uses `speed_scale = 10` and `wheel_base = 200`, chosen so that
//! trajectories have the character of the thesis's Tables 13–15:
//!
//! * wheels `1`/`1` drive straight at **10 units/s** (the thesis's rovers moved roughly
//!   5–20 units per second while going straight);
//! * wheels `−10`/`+10` pivot at **ω = 10·20/200 = 1 rad/s ≈ 57.3 °/s**, so the thesis's
//!   3 s turn (08:36:54 → 08:36:57) turns the rover ≈ 171.9° and its 2 s turn
//!   (08:37:00 → 08:37:02) ≈ 114.6°, in the range of the ≈110–150° the tables show;
//! * over the ~13 s scenario a rover travels about 80 units, so rovers starting at the
//!   thesis's poses stay within roughly ±210 of the origin.
//!
//! # Angles
//!
//! [`Pose::theta_deg`] is in degrees, 0 along +x, counter-clockwise positive, and always
//! normalised to `[0, 360)` (as in the thesis's tables).

/// Position and heading of a rover in the plane of the virtual environment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// East coordinate in world units.
    pub x: f64,
    /// North coordinate in world units.
    pub y: f64,
    /// Heading in degrees: 0 along +x, counter-clockwise positive, in `[0, 360)`.
    pub theta_deg: f64,
}

impl Pose {
    /// Builds a pose, normalising the heading into `[0, 360)`.
    ///
    /// A non-finite heading is replaced by 0 so that a pose never carries NaN into the
    /// integration (a rover with an unknown heading faces +x rather than poisoning the log).
    pub fn new(x: f64, y: f64, theta_deg: f64) -> Self {
        Pose {
            x,
            y,
            theta_deg: normalize_deg(theta_deg),
        }
    }

    /// Returns the heading in radians (not normalised beyond what `theta_deg` already is).
    pub fn theta_rad(&self) -> f64 {
        self.theta_deg.to_radians()
    }

    /// Returns true when x, y and θ are all finite numbers.
    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta_deg.is_finite()
    }
}

/// Normalises an angle in degrees into `[0, 360)`; non-finite input maps to 0.
///
/// `rem_euclid` alone can return exactly 360.0 for tiny negative inputs (−1e−17 rounds
/// up), so that case is folded back to 0 to keep the half-open interval promise.
pub fn normalize_deg(deg: f64) -> f64 {
    if !deg.is_finite() {
        return 0.0;
    }
    let r = deg.rem_euclid(360.0);
    if r >= 360.0 {
        0.0
    } else {
        r
    }
}

/// Signed smallest difference `to − from` between two headings, in degrees, in `(−180, 180]`.
///
/// Used to measure how far a rover turned across the 0/360 wrap.
pub fn angle_diff_deg(from: f64, to: f64) -> f64 {
    let d = (to - from).rem_euclid(360.0);
    if d > 180.0 {
        d - 360.0
    } else {
        d
    }
}

/// A differential-drive rover model: wheel commands in, pose change out.
///
/// The fields are public so that a scenario can pick its own geometry; a non-positive or
/// non-finite field makes [`DiffDrive::step`] leave poses unchanged (see there) instead of
/// producing NaN. Use [`DiffDrive::new`] to have the values checked up front.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiffDrive {
    /// Distance between the two wheels in world units (must be > 0).
    pub wheel_base: f64,
    /// World units per second of wheel surface speed per unit of wheel command (must be > 0).
    pub speed_scale: f64,
}

impl Default for DiffDrive {
    /// The thesis-like defaults documented in the [module docs](self): `wheel_base = 200`,
    /// `speed_scale = 10` (10 units/s straight, 1 rad/s pivot for wheels −10/+10).
    fn default() -> Self {
        DiffDrive {
            wheel_base: 200.0,
            speed_scale: 10.0,
        }
    }
}

/// Why a [`DiffDrive`] could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DriveError {
    /// `wheel_base` was zero, negative or not finite.
    BadWheelBase(f64),
    /// `speed_scale` was zero, negative or not finite.
    BadSpeedScale(f64),
}

impl std::fmt::Display for DriveError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DriveError::BadWheelBase(v) => write!(f, "wheel_base must be finite and > 0, got {v}"),
            DriveError::BadSpeedScale(v) => {
                write!(f, "speed_scale must be finite and > 0, got {v}")
            }
        }
    }
}

impl std::error::Error for DriveError {}

impl DiffDrive {
    /// Builds a model, rejecting a wheel base or speed scale that is not finite and positive.
    pub fn new(wheel_base: f64, speed_scale: f64) -> Result<Self, DriveError> {
        if !(wheel_base.is_finite() && wheel_base > 0.0) {
            return Err(DriveError::BadWheelBase(wheel_base));
        }
        if !(speed_scale.is_finite() && speed_scale > 0.0) {
            return Err(DriveError::BadSpeedScale(speed_scale));
        }
        Ok(DiffDrive {
            wheel_base,
            speed_scale,
        })
    }

    /// Forward speed in units/s for the given wheel commands: `speed_scale·(l+r)/2`.
    pub fn linear_speed(&self, left: f64, right: f64) -> f64 {
        self.speed_scale * (left + right) / 2.0
    }

    /// Turn rate in rad/s (counter-clockwise positive): `speed_scale·(r−l)/wheel_base`.
    pub fn angular_speed(&self, left: f64, right: f64) -> f64 {
        self.speed_scale * (right - left) / self.wheel_base
    }

    /// Moves `pose` along the exact arc for constant wheel commands over `dt_s` seconds.
    ///
    /// Returns `pose` unchanged when any input (`left`, `right`, `dt_s`) is not finite,
    /// when `dt_s <= 0`, when the model's own parameters are invalid, or when the result
    /// would not be finite: the virtual environment must never log NaN, and a bad wheel
    /// command from a misbehaving rover is better ignored than allowed to teleport it.
    pub fn step(&self, pose: Pose, left: f64, right: f64, dt_s: f64) -> Pose {
        let params_ok = self.wheel_base.is_finite()
            && self.wheel_base > 0.0
            && self.speed_scale.is_finite()
            && self.speed_scale > 0.0;
        if !params_ok
            || !left.is_finite()
            || !right.is_finite()
            || !dt_s.is_finite()
            || dt_s <= 0.0
            || !pose.is_finite()
        {
            return pose;
        }
        let v = self.linear_speed(left, right);
        let omega = self.angular_speed(left, right);
        let theta0 = pose.theta_rad();
        let phi = omega * dt_s;
        let half = phi / 2.0;
        let sinc = if half == 0.0 { 1.0 } else { half.sin() / half };
        let dist = v * dt_s * sinc;
        let mid = theta0 + half;
        // v == 0 (pivot) gives dist == 0, so x and y are returned bit-identical.
        let (dx, dy) = if dist == 0.0 {
            (0.0, 0.0)
        } else {
            (dist * mid.cos(), dist * mid.sin())
        };
        // phi == 0 (straight) keeps theta bit-identical instead of a deg→rad→deg round trip.
        let theta_deg = if phi == 0.0 {
            pose.theta_deg
        } else {
            normalize_deg(pose.theta_deg + phi.to_degrees())
        };
        let next = Pose {
            x: pose.x + dx,
            y: pose.y + dy,
            theta_deg,
        };
        if next.is_finite() {
            next
        } else {
            pose
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPS: f64 = 1e-9;

    fn close(a: f64, b: f64, eps: f64) -> bool {
        (a - b).abs() <= eps
    }

    #[test]
    fn pivot_keeps_position_and_changes_heading() {
        let d = DiffDrive::default();
        let start = Pose::new(12.5, -7.25, 30.0);
        let mut p = start;
        for _ in 0..100 {
            p = d.step(p, -10.0, 10.0, 0.01);
        }
        assert!(
            close(p.x, start.x, EPS) && close(p.y, start.y, EPS),
            "{p:?}"
        );
        // 1 s at 1 rad/s = 57.2958°.
        assert!(close(p.theta_deg, 30.0 + 1f64.to_degrees(), 1e-9), "{p:?}");
        // Right pivot turns clockwise.
        let q = d.step(start, 10.0, -10.0, 0.5);
        assert!(close(q.x, start.x, EPS) && close(q.y, start.y, EPS));
        assert!(close(
            angle_diff_deg(start.theta_deg, q.theta_deg),
            -0.5f64.to_degrees(),
            1e-9
        ));
    }

    #[test]
    fn straight_keeps_heading() {
        let d = DiffDrive::default();
        let start = Pose::new(0.0, 0.0, 90.0);
        let p = d.step(start, 1.0, 1.0, 2.0);
        assert_eq!(p.theta_deg, 90.0);
        assert!(close(p.x, 0.0, EPS) && close(p.y, 20.0, EPS), "{p:?}");
        let q = d.step(Pose::new(1.0, 2.0, 0.0), 1.0, 1.0, 1.0);
        assert_eq!(q, Pose::new(11.0, 2.0, 0.0));
        // Reversing drives backwards with the same heading.
        let r = d.step(Pose::new(0.0, 0.0, 180.0), -1.0, -1.0, 1.0);
        assert!(close(r.x, 10.0, EPS) && close(r.y, 0.0, EPS) && r.theta_deg == 180.0);
    }

    #[test]
    fn full_circle_returns_to_start() {
        let d = DiffDrive::default();
        let start = Pose::new(-3.0, 4.0, 45.0);
        // Arc: l = 1, r = 2 → ω = 10·1/200 = 0.05 rad/s, period 2π/0.05 s.
        let period = 2.0 * std::f64::consts::PI / d.angular_speed(1.0, 2.0);
        let one = d.step(start, 1.0, 2.0, period);
        assert!(
            close(one.x, start.x, 1e-9) && close(one.y, start.y, 1e-9),
            "{one:?}"
        );
        assert!(close(
            angle_diff_deg(start.theta_deg, one.theta_deg),
            0.0,
            1e-9
        ));
        // The same in 1000 pieces.
        let mut p = start;
        for _ in 0..1000 {
            p = d.step(p, 1.0, 2.0, period / 1000.0);
        }
        assert!(
            close(p.x, start.x, 1e-9) && close(p.y, start.y, 1e-9),
            "{p:?}"
        );
        // Half-way the rover is on the opposite side of the circle: diameter 2R = 2v/ω.
        let half = d.step(start, 1.0, 2.0, period / 2.0);
        let diameter = 2.0 * d.linear_speed(1.0, 2.0) / d.angular_speed(1.0, 2.0);
        let dist = ((half.x - start.x).powi(2) + (half.y - start.y).powi(2)).sqrt();
        assert!(close(dist, diameter, 1e-9), "{dist} vs {diameter}");
    }

    #[test]
    fn split_steps_equal_one_big_step() {
        let d = DiffDrive::default();
        for &(l, r) in &[
            (1.0, 1.0),
            (-10.0, 10.0),
            (0.3, 1.7),
            (2.0, -0.5),
            (1.0, 1.000001),
        ] {
            let start = Pose::new(5.0, -2.0, 350.0);
            let big = d.step(start, l, r, 3.7);
            let mut p = start;
            for _ in 0..370 {
                p = d.step(p, l, r, 0.01);
            }
            assert!(close(p.x, big.x, 1e-9), "x {l},{r}: {p:?} vs {big:?}");
            assert!(close(p.y, big.y, 1e-9), "y {l},{r}: {p:?} vs {big:?}");
            assert!(
                close(angle_diff_deg(p.theta_deg, big.theta_deg), 0.0, 1e-9),
                "θ {l},{r}: {p:?} vs {big:?}"
            );
        }
    }

    #[test]
    fn default_speeds_match_documentation() {
        let d = DiffDrive::default();
        assert_eq!(d.linear_speed(1.0, 1.0), 10.0);
        assert_eq!(d.angular_speed(-10.0, 10.0), 1.0);
        assert_eq!(d.linear_speed(-10.0, 10.0), 0.0);
    }

    #[test]
    fn bad_inputs_leave_pose_unchanged() {
        let d = DiffDrive::default();
        let p = Pose::new(1.0, 2.0, 3.0);
        assert_eq!(d.step(p, f64::NAN, 1.0, 1.0), p);
        assert_eq!(d.step(p, 1.0, f64::INFINITY, 1.0), p);
        assert_eq!(d.step(p, 1.0, 1.0, f64::NAN), p);
        assert_eq!(d.step(p, 1.0, 1.0, -1.0), p);
        assert_eq!(d.step(p, 1.0, 1.0, 0.0), p);
        let broken = DiffDrive {
            wheel_base: 0.0,
            speed_scale: 10.0,
        };
        assert_eq!(broken.step(p, -1.0, 1.0, 1.0), p);
        // Overflowing result is rejected too.
        assert_eq!(d.step(p, 1e308, 1e308, 1e10), p);
        assert!(DiffDrive::new(0.0, 1.0).is_err());
        assert!(DiffDrive::new(1.0, f64::NAN).is_err());
        assert!(DiffDrive::new(-1.0, 1.0).is_err());
        assert_eq!(DiffDrive::new(200.0, 10.0), Ok(DiffDrive::default()));
    }

    #[test]
    fn heading_normalisation() {
        assert_eq!(Pose::new(0.0, 0.0, 360.0).theta_deg, 0.0);
        assert_eq!(Pose::new(0.0, 0.0, -90.0).theta_deg, 270.0);
        assert_eq!(Pose::new(0.0, 0.0, 725.0).theta_deg, 5.0);
        assert_eq!(Pose::new(0.0, 0.0, -1e-17).theta_deg, 0.0);
        assert_eq!(Pose::new(0.0, 0.0, f64::NAN).theta_deg, 0.0);
        assert_eq!(angle_diff_deg(350.0, 10.0), 20.0);
        assert_eq!(angle_diff_deg(10.0, 350.0), -20.0);
        // Pivoting across 360 wraps back into range.
        let d = DiffDrive::default();
        let p = d.step(Pose::new(0.0, 0.0, 300.0), -10.0, 10.0, 2.0);
        assert!(p.theta_deg >= 0.0 && p.theta_deg < 360.0);
        assert!(close(p.theta_deg, 300.0 + 2f64.to_degrees() - 360.0, 1e-9));
    }
}
