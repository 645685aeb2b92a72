//! hilbench's integration tests, one binary (one link of the crate, its tests run side by
//! side): each module tests one command or one property as a user meets it.

mod campaigns;
mod common;
mod delay_trace;
mod exit_codes;
mod explanation;
mod falsify;
mod layout;
mod progress;
mod runs;
mod sweep;
mod tls;
mod trace;
