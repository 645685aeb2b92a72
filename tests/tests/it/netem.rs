//! Integration tests: netem.
