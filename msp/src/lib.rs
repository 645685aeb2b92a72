//! `msp`: the MultiWii Serial Protocol as Betaflight speaks it, a pure core (ARCHITECTURE.md):
//! no sockets, no serial ports, no clock. The caller moves the bytes (TCP 5761 to the SITL, a
//! UART on a flight controller) and keeps the time.
//!
//! - [`frame`]: v1 (`$M`, XOR, jumbo frames) and v2 (`$X`, CRC-8/DVB-S2) frames, encoded.
//! - [`decoder`]: bytes in any chunking to checked frames; garbage skipped, bad frames dropped
//!   and counted ([`Counters`]), a bounded buffer.
//! - [`messages`]: the messages a companion computer needs, typed, with units.
//! - [`cli`]: the commands of a CLI file and what the firmware's answers say.
//!
//! ```
//! use msp::{Decoder, DecoderSettings, Direction, Version, command, messages::ApiVersion};
//!
//! let mut to_fc = Vec::new();
//! msp::request(Version::V1, command::API_VERSION, &mut to_fc).unwrap();
//! assert_eq!(to_fc, b"$M<\x00\x01\x01");
//!
//! // The flight controller's reply, split anywhere:
//! let reply = [b'$', b'M', b'>', 3, 1, 0, 1, 47, 3 ^ 1 ^ 1 ^ 47];
//! let mut decoder = Decoder::new(DecoderSettings::default()).unwrap();
//! let mut frames: Vec<_> = decoder.feed(&reply[..4]).collect();
//! frames.extend(decoder.feed(&reply[4..]));
//! assert_eq!(frames[0].direction, Direction::FromFc);
//! let api = ApiVersion::decode(msp::reply_payload(&frames[0], command::API_VERSION).unwrap()).unwrap();
//! assert_eq!((api.major, api.minor), (1, 47));
//! ```

pub mod cli;
pub mod decoder;
pub mod frame;
pub mod messages;

pub use decoder::{Counters, Decoder, DecoderSettings, Dropped, Frames, SettingsError};
pub use frame::{Direction, EncodeError, Frame, Version, crc8_dvb_s2, encode};
pub use messages::{DecodeError, command, reply_payload, request};
