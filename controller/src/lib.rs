//! The controller service (see ARCHITECTURE.md).
