//! Benchmarks of the `features` stage (criterion). Filled in by the issue that builds the stage.

use criterion::{Criterion, criterion_group, criterion_main};

fn placeholder(_c: &mut Criterion) {}

criterion_group!(benches, placeholder);
criterion_main!(benches);
