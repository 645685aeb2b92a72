//! `vehiclectl`: the explicit calls of a gateway's VehicleControl service from a shell (arm,
//! disarm, set a mode, read the status), so that a person or a script, never the gateway,
//! decides when the vehicle arms and changes mode.

use clap::{Parser, Subcommand};
use hilbench_proto::pb;
use hilbench_proto::pb::vehicle_control_client::VehicleControlClient;
use std::time::Duration;

/// Arms, disarms, sets the mode of, or reads the status of the vehicle behind a hilbench
/// gateway (hilbench.v1.VehicleControl).
#[derive(Debug, Parser)]
#[command(name = "vehiclectl", version)]
struct Args {
    /// The gateway, HOST:PORT.
    #[arg(long, default_value = "127.0.0.1:50054")]
    gateway: String,
    /// Wait this long for the gateway, the vehicle's heartbeat and the setpoint stream before
    /// the first call, s.
    #[arg(long, default_value_t = 0)]
    wait_s: u64,
    #[command(flatten)]
    identity: hilbench_svc::tls::IdentityArgs,
    #[command(flatten)]
    trust: hilbench_svc::tls::TrustArgs,
    #[command(subcommand)]
    action: Action,
}

#[derive(Debug, Subcommand)]
enum Action {
    /// Print the vehicle's status as JSON: every field of hilbench.v1.VehicleStatus by its
    /// name in vehicle.proto (units in the names), an optional one absent while unknown.
    Status,
    /// Arm the vehicle.
    Arm,
    /// Disarm the vehicle.
    Disarm,
    /// Switch to PX4's OFFBOARD (the gateway must be streaming setpoints: it always does).
    Offboard,
    /// Switch to ArduCopter's GUIDED_NOGPS (refused unless its GUID_OPTIONS has bit 3, 8: the
    /// setpoints' thrust read as thrust, not as a climb rate).
    GuidedNogps,
    /// Arm, then switch to PX4's OFFBOARD.
    ArmOffboard,
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let tls = hilbench_svc::tls::TlsFiles::client(&args.identity, &args.trust).load()?;
    let endpoint = tls.endpoint(&args.gateway).map_err(|e| anyhow::anyhow!("--gateway: {e}"))?;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(args.wait_s);
    let mut client = loop {
        match endpoint.connect().await {
            Ok(channel) => break VehicleControlClient::new(channel),
            Err(e) if tokio::time::Instant::now() >= deadline => {
                let why = hilbench_svc::error_chain(&e);
                anyhow::bail!("cannot reach the gateway at {}: {why}", args.gateway)
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(200)).await,
        }
    };
    loop {
        let status = answer("status", client.get_status(pb::GetVehicleStatusRequest {}).await)?;
        // PX4 takes OFFBOARD only once setpoints stream: a tenth of a second of them.
        if (status.link_alive && status.setpoints_sent >= 5) || tokio::time::Instant::now() >= deadline {
            break;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let offboard = || pb::SetModeRequest { mode: pb::FlightMode::Px4Offboard as i32 };
    match args.action {
        Action::Status => {
            let status = answer("status", client.get_status(pb::GetVehicleStatusRequest {}).await)?;
            say(&status_json(&status)?)?
        }
        Action::Arm => say(&format!("arm: {}", answer("arm", client.arm(pb::ArmRequest {}).await)?.result))?,
        Action::Disarm => {
            say(&format!("disarm: {}", answer("disarm", client.disarm(pb::DisarmRequest {}).await)?.result))?
        }
        Action::Offboard => {
            say(&format!("offboard: {}", answer("offboard", client.set_mode(offboard()).await)?.result))?
        }
        Action::GuidedNogps => {
            let r = pb::SetModeRequest { mode: pb::FlightMode::ArdupilotGuidedNogps as i32 };
            say(&format!("guided_nogps: {}", answer("guided-nogps", client.set_mode(r).await)?.result))?
        }
        Action::ArmOffboard => {
            say(&format!("arm: {}", answer("arm", client.arm(pb::ArmRequest {}).await)?.result))?;
            say(&format!("offboard: {}", answer("offboard", client.set_mode(offboard()).await)?.result))?;
        }
    }
    Ok(())
}

/// `status` in the protobuf JSON mapping, read through the descriptors the gateway's reflection
/// serves (so that the names are vehicle.proto's, every field is there, defaults too, and a
/// field added there is printed without a change here); 64-bit counts as JSON numbers (they
/// stay below 2^53) rather than the mapping's strings, for `jq`.
fn status_json(status: &pb::VehicleStatus) -> anyhow::Result<String> {
    use prost::Message;
    let pool = prost_reflect::DescriptorPool::decode(hilbench_proto::FILE_DESCRIPTOR_SET)?;
    let descriptor = pool
        .get_message_by_name("hilbench.v1.VehicleStatus")
        .ok_or_else(|| anyhow::anyhow!("hilbench.v1.VehicleStatus is not in the descriptors"))?;
    let message = prost_reflect::DynamicMessage::decode(descriptor, status.encode_to_vec().as_slice())?;
    let options = prost_reflect::SerializeOptions::new()
        .use_proto_field_name(true)
        .skip_default_fields(false)
        .stringify_64_bit_integers(false);
    let mut out = serde_json::Serializer::pretty(Vec::new());
    message.serialize_with_options(&mut out, &options)?;
    Ok(String::from_utf8(out.into_inner())?)
}

/// Prints `line` on stdout. A reader that stopped reading (`vehiclectl status | head`) is not
/// an error: what it did not read was not wanted, and the call was made all the same (`println!`
/// panicked there); any other failure to write is.
fn say(line: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{line}").and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(anyhow::anyhow!("cannot write to stdout: {e}"))
        }
        _ => Ok(()),
    }
}

/// The answer of the call `what`, or an error naming the call, the gRPC code and the gateway's
/// message (for a refusal by the vehicle: FailedPrecondition and the `COMMAND_ACK` result).
fn answer<T>(what: &str, reply: Result<tonic::Response<T>, tonic::Status>) -> anyhow::Result<T> {
    reply
        .map(tonic::Response::into_inner)
        .map_err(|s| anyhow::anyhow!("{what}: {:?}: {}", s.code(), s.message()))
}
