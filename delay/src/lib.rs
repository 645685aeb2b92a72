//! Pure delay profiles and delay lines for netem (see ARCHITECTURE.md).
