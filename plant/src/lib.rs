//! The plant service (see ARCHITECTURE.md).
