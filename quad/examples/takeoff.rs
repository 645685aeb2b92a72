//! Take off from the ground, climb for a second, hover, and print what a Betaflight SITL
//! bridge would send the firmware.
//!
//! `cargo run --release -p quad --example takeoff`

use quad::betaflight::{FdmState, motors_from_servo_packet};
use quad::{QuadParams, QuadSim, QuadState, SimSettings};

fn main() -> Result<(), quad::SimError> {
    let params = QuadParams::default();
    println!(
        "hover command {:.4}, thrust-to-weight {:.2}",
        params.hover_command(),
        params.thrust_to_weight()
    );
    let mut sim = QuadSim::new(params, SimSettings::default(), QuadState::resting_at(0.0, 0.0))?;

    // Commands arrive as the firmware's servo packet (motors 2, 3, 4, 1), 0..1 each.
    let climb = (1.2 * params.hover_command()) as f32;
    sim.set_commands(motors_from_servo_packet([climb; 4]));
    sim.advance_to(1_000_000_000)?;
    sim.set_commands([params.hover_command(); 4]);
    sim.advance_to(3_000_000_000)?;

    let sample = sim.sample();
    println!("t = {} ns, position ENU {:?} m", sample.time_ns, sample.state.position_m.as_slice());
    println!(
        "velocity ENU {:?} m/s, on ground: {}",
        sample.state.velocity_mps.as_slice(),
        sample.contact.on_ground
    );
    let fdm = FdmState::from_sample(&sample);
    println!("fdm gyro FRD {:?} rad/s", fdm.imu_angular_velocity_rpy);
    println!("fdm accel FRD {:?} m/s^2", fdm.imu_linear_acceleration_xyz);
    println!("fdm quat FRD->NED {:?}", fdm.imu_orientation_quat);
    Ok(())
}
