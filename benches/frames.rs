//! Benchmarks of the `frames` stage (criterion): decoding real frames (girl 128x96 colour jpg,
//! car4 360x240 grayscale jpg), y4m reading (4:2:0 and 4:4:4, 640x480), bilinear resize.
//!
//! Real data is read from `../shared/data`; those benches are skipped (with a message) when
//! it is absent.

use std::hint::black_box;
use std::io::Write;
use std::path::{Path, PathBuf};

use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};
use image::{Rgb, RgbImage};
use pftrack::frames::{self, SourceOptions, Y4mReader, resize_bilinear};

fn data(rel: &str) -> Option<PathBuf> {
    let p = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")).join(rel);
    if p.exists() {
        Some(p)
    } else {
        let _ = writeln!(std::io::stderr(), "skip: {} missing", p.display());
        None
    }
}

/// Decoding the first 50 frames of an image directory through a frame source.
fn decode_dirs(c: &mut Criterion) {
    let mut g = c.benchmark_group("frames/dir");
    g.sample_size(10);
    for (name, rel) in [
        ("girl_128x96_jpg", "girl/img"),
        ("car4_360x240_gray_jpg", "car4/img"),
    ] {
        let Some(dir) = data(rel) else { continue };
        // Opening: listing, natural sort, reading the first header.
        g.throughput(Throughput::Elements(1));
        g.bench_function(format!("{name}/open"), |b| {
            b.iter(|| black_box(frames::open(&dir, &SourceOptions::default()).unwrap()))
        });
        g.throughput(Throughput::Elements(50));
        // Decoding only: the listing happens in the untimed setup.
        g.bench_function(format!("{name}/decode_50"), |b| {
            b.iter_batched(
                || frames::open(&dir, &SourceOptions::default()).unwrap(),
                |src| {
                    for f in src.take(50) {
                        black_box(f.unwrap());
                    }
                },
                BatchSize::PerIteration,
            )
        });
    }
    g.finish();
}

/// A smooth, textured test frame.
fn test_frame(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        Rgb([
            (x * 255 / w) as u8,
            (y * 255 / h) as u8,
            ((x ^ y) & 0xff) as u8,
        ])
    })
}

/// An in-memory y4m stream of `n` frames (planes need no meaningful content to time).
fn y4m_bytes(w: usize, h: usize, tag: &str, n: usize) -> Vec<u8> {
    let (cw, ch) = if tag == "444" {
        (w, h)
    } else {
        (w.div_ceil(2), h.div_ceil(2))
    };
    let size = w * h + 2 * cw * ch;
    let mut out = format!("YUV4MPEG2 W{w} H{h} F30:1 C{tag}\n").into_bytes();
    for k in 0..n {
        out.extend_from_slice(b"FRAME\n");
        out.extend((0..size).map(|i| (i * 7 + k) as u8));
    }
    out
}

fn y4m(c: &mut Criterion) {
    let mut g = c.benchmark_group("frames/y4m_640x480");
    let n = 10;
    g.throughput(Throughput::Elements(n as u64));
    for tag in ["420jpeg", "444"] {
        let bytes = y4m_bytes(640, 480, tag, n);
        g.bench_function(tag, |b| {
            b.iter(|| {
                let mut r = Y4mReader::new(&bytes[..], "bench").unwrap();
                while let Some(f) = r.read_frame().unwrap() {
                    black_box(f);
                }
            })
        });
    }
    g.finish();
}

fn resize(c: &mut Criterion) {
    type Resize = fn(&image::RgbImage, u32, u32) -> image::RgbImage;
    type Case = (&'static str, (u32, u32), (u32, u32));
    let groups: [(&str, Resize, [Case; 3]); 2] = [
        (
            "frames/resize_bilinear",
            resize_bilinear,
            [
                ("640x480_to_160x120", (640, 480), (160, 120)),
                ("360x240_to_128x96", (360, 240), (128, 96)),
                ("176x144_to_352x288", (176, 144), (352, 288)),
            ],
        ),
        // What a source resizes with: the mean over each pixel's footprint where it shrinks
        // (1280x960 to 640x480 is `track`'s working size for such frames).
        (
            "frames/resize",
            frames::resize,
            [
                ("640x480_to_160x120", (640, 480), (160, 120)),
                ("1280x960_to_640x480", (1280, 960), (640, 480)),
                ("1920x1080_to_640x360", (1920, 1080), (640, 360)),
            ],
        ),
    ];
    for (group, resize, cases) in groups {
        let mut g = c.benchmark_group(group);
        for (name, (sw, sh), (dw, dh)) in cases {
            let img = test_frame(sw, sh);
            g.bench_function(name, |b| b.iter(|| black_box(resize(&img, dw, dh))));
        }
        g.finish();
    }
}

criterion_group! {
    name = benches;
    // No plots: criterion's plotters backend panics when no font is installed.
    config = Criterion::default().without_plots();
    targets = decode_dirs, y4m, resize
}
criterion_main!(benches);
