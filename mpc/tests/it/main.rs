//! mpc's integration tests, one binary: the closed loop's accounting, accuracy against a careful
//! reference (its campaigns `#[ignore]`d), random delay traces, the episode, the gradient.

mod accounting;
mod accuracy;
mod delay_traces;
mod episode;
mod gradient_options;
