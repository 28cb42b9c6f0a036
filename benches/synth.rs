//! Benchmarks of the `synth` stage (criterion): time to render one frame with its truth, at the
//! paper's 160x120 and at 640x480, and the PNG encoding that `write_sequence` adds.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use pftrack::synth::{Renderer, Scenario, SynthConfig};

fn render(c: &mut Criterion) {
    let mut g = c.benchmark_group("synth");
    for (w, h) in [(160u32, 120u32), (640, 480)] {
        let cfg = SynthConfig {
            width: w,
            height: h,
            ..SynthConfig::new(Scenario::Combo)
        };
        let r = Renderer::new(&cfg).expect("valid configuration");
        let size = format!("{w}x{h}");
        let mut k = 0;
        g.bench_function(BenchmarkId::new("render_frame_with_truth", &size), |b| {
            b.iter(|| {
                k = (k + 7) % cfg.frames;
                black_box(r.render(black_box(k)))
            })
        });
        g.bench_function(BenchmarkId::new("truth_only", &size), |b| {
            b.iter(|| black_box(r.truth(black_box(37))))
        });
        let img = r.render_image(37);
        g.bench_function(BenchmarkId::new("png_encode", &size), |b| {
            b.iter(|| {
                let mut buf = std::io::Cursor::new(Vec::new());
                img.write_to(&mut buf, image::ImageFormat::Png)
                    .expect("encode");
                black_box(buf.into_inner().len())
            })
        });
        g.bench_function(BenchmarkId::new("renderer_new", &size), |b| {
            b.iter(|| black_box(Renderer::new(black_box(&cfg)).expect("valid")))
        });
    }
    g.finish();
}

criterion_group! {
    name = benches;
    // Plots need system fonts that a bare machine lacks (criterion panics without them).
    config = Criterion::default().without_plots();
    targets = render
}
criterion_main!(benches);
