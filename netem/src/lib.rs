//! The netem service (see ARCHITECTURE.md).
