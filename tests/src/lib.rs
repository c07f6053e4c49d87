//! End-to-end tests across Glint crates live in `tests/`; this library is empty on purpose.
