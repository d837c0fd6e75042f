//! Integration tests live in tests/hil.rs (one test binary); this crate has no library code.
