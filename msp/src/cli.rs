//! Betaflight's CLI as the SITL's configuration is applied through it (docs/betaflight.md):
//! the commands of a `.cli` file, and what the firmware's answer to one says. Pure: the
//! caller owns the connection (TCP 5761 in SITL, a serial port on a flight controller).
//!
//! The CLI is entered by sending `#` *alone* and waiting for the prompt: bytes that follow the
//! `#` before the firmware's serial task has read it cancel the request
//! (`mspSerialProcess`: "There are bytes incoming - abort pending request"). While the CLI is
//! open the port speaks no MSP and arming is refused (`CLI`); `save` writes the configuration
//! and reboots, which in SITL ends the process (exit status 0), and so does `exit`.

/// What the firmware prints after each command's output.
pub const PROMPT: &str = "\r\n# ";

/// The byte that opens the CLI from MSP.
pub const ENTER: u8 = b'#';

/// The commands of a CLI file: one a line, blank lines and `#` comments left out, surrounding
/// blanks trimmed. `save` is the caller's to send.
pub fn commands(text: &str) -> Vec<&str> {
    text.lines().map(str::trim).filter(|l| !l.is_empty() && !l.starts_with('#')).collect()
}

/// The firmware's complaint in a command's output (`###ERROR IN set: INVALID NAME: ...###`,
/// `Invalid ...`, `ERROR...`), if any.
pub fn error_in(output: &str) -> Option<&str> {
    output.lines().map(str::trim).find(|l| {
        l.starts_with("###ERROR")
            || l.starts_with("ERROR")
            || l.starts_with("Invalid")
            || l.starts_with("Parse error")
    })
}

/// Whether `output` ends at the prompt (the command's output is complete).
pub fn at_prompt(output: &str) -> bool {
    output.ends_with(PROMPT) || output.ends_with("\n# ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_project_s_file_is_read_as_commands_without_comments() {
        let text = include_str!("../../firmware/betaflight/hilbench.cli");
        let cmds = commands(text);
        assert!(cmds.contains(&"aux 0 0 0 1700 2100 0 0"), "ARM on AUX1: {cmds:?}");
        assert!(cmds.contains(&"aux 1 1 1 1700 2100 0 0"), "ANGLE on AUX2: {cmds:?}");
        assert!(cmds.iter().any(|c| c.starts_with("set angle_limit = ")));
        assert!(cmds.iter().all(|c| !c.starts_with('#') && *c != "save"), "{cmds:?}");
    }

    #[test]
    fn errors_and_the_prompt_are_recognised() {
        assert_eq!(
            error_in("# get receiver\r\n###ERROR IN get: INVALID NAME: receiver###\r\n\r\n# "),
            Some("###ERROR IN get: INVALID NAME: receiver###")
        );
        assert_eq!(error_in("# set angle_limit = 20\r\nangle_limit set to 20\r\n"), None);
        assert!(at_prompt("angle_limit set to 20\r\n# "));
        assert!(!at_prompt("angle_limit set"));
    }
}
