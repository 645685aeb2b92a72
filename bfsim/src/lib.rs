//! `bfsim`: the Betaflight vehicle. The real flight firmware (Betaflight 4.6.0 SITL, built and
//! cached by `scripts/betaflight-sitl.sh`, run as a child process in a working directory of
//! its own) flies `quad`'s rigid-body quadrotor in real time: the body's state goes to the
//! firmware as `fdm_packet`s (UDP 9003), the firmware's mixer answers with motor outputs
//! (`servo_packet`, UDP 9002) that the body flies with, and the body's pose is published as a
//! motion-capture system would (MAVLink 2 ODOMETRY, [`pose`]). The gateway talks MSP to the
//! firmware on TCP 5761 as a companion computer does; bfsim only asks it who it is.
//! docs/betaflight.md has the packets, the configuration and the pose stream.
//!
//! - [`packets`], [`pose`], [`stats`]: pure (bytes, frames, counters).
//! - [`firmware`]: the child process, its configuration over the CLI, MSP questions.
//! - [`vehicle`]: the loop (sockets and the simulation, time from a clock passed in, or the
//!   exchange in lockstep).

pub mod firmware;
pub mod packets;
pub mod pose;
pub mod stats;
pub mod vehicle;
