//! One integration-test binary, a module per area (as ripgrep does): every test here starts
//! real services on loopback ports and talks gRPC to them, or runs the full closed loop, or
//! checks a deployment file with an independent tool (`k8s`).

mod closed_loop;
mod controller;
mod external;
mod fault;
mod foxglove;
mod gateway;
mod k8s;
mod mavsdk;
mod netem;
mod plant;
mod python;
mod record;
mod tls;
mod udp;
