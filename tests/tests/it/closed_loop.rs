//! Integration tests: closed_loop.
