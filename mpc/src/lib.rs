//! The multi-stage NMPC (see ARCHITECTURE.md).
