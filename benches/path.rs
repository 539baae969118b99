//! Benchmarks of the pivotal and PATH-like backends (filled in by issue #5).
fn main() {}
