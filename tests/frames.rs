//! Frame sources on real files of each kind, y4m round trips, and every bad-input error.
//!
//! Real data comes from `../shared/data` (skipped with a printed reason when absent).
//! ffmpeg-dependent tests skip when ffmpeg is not on PATH, except under `CI`, where they fail.

mod shared_data;

use std::io::Write;
use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};
use pftrack::frames::{
    self, FfmpegTools, Frame, FrameError, FrameSource, SourceOptions, resize_bilinear,
};

fn say(msg: &str) {
    let _ = writeln!(std::io::stderr(), "{msg}");
}

/// A path under `../shared/data`, or `None` (with a printed reason) when it is absent.
fn data(rel: &str) -> Option<PathBuf> {
    shared_data::path(rel)
}

/// Whether ffmpeg can be used; under `CI` its absence is a failure, not a skip.
fn have_ffmpeg() -> bool {
    if FfmpegTools::default().available() {
        return true;
    }
    if std::env::var_os("CI").is_some() {
        panic!("CI is set but ffmpeg/ffprobe are not on PATH (CI must install ffmpeg)");
    }
    say("skip: ffmpeg not on PATH");
    false
}

/// A fresh, empty scratch directory for one test.
fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pftrack-frames-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn collect(src: FrameSource) -> Result<Vec<Frame>, FrameError> {
    src.collect()
}

// ---------------------------------------------------------------- image directories

#[test]
fn girl_jpg_directory() {
    let Some(dir) = data("girl/img") else { return };
    let src = frames::open(&dir, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (128, 96));
    assert_eq!(src.len_hint(), Some(500));
    assert!(src.describe().contains("500 frames"), "{}", src.describe());
    let mut n = 0;
    let mut first = None;
    for f in src {
        let f = f.unwrap();
        assert_eq!(f.dimensions(), (128, 96));
        if n == 0 {
            first = Some(f);
        }
        n += 1;
    }
    assert_eq!(n, 500);
    // The first frame is 0001.jpg, and it is colour.
    let direct = image::open(dir.join("0001.jpg")).unwrap().into_rgb8();
    let first = first.unwrap();
    assert_eq!(first, direct);
    assert!(first.pixels().any(|p| p[0] != p[1] || p[1] != p[2]));
}

#[test]
fn car4_grayscale_becomes_equal_channels() {
    let Some(dir) = data("car4/img") else { return };
    let src = frames::open(&dir, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (360, 240));
    let mut n = 0;
    for f in src {
        let f = f.unwrap();
        assert_eq!(f.dimensions(), (360, 240));
        assert!(
            f.pixels().all(|p| p[0] == p[1] && p[1] == p[2]),
            "frame {n}"
        );
        n += 1;
    }
    assert_eq!(n, 659);
}

#[test]
fn resize_applies_to_every_frame() {
    let Some(dir) = data("girl/img") else { return };
    let opts = SourceOptions {
        resize: Some((64, 40)),
    };
    let mut src = frames::open(&dir, &opts).unwrap();
    assert_eq!(src.size(), (64, 40));
    assert_eq!(src.native_size(), (128, 96));
    assert!(src.describe().contains("resized to 64x40"));
    let f0 = src.next().unwrap().unwrap();
    let direct = image::open(dir.join("0001.jpg")).unwrap().into_rgb8();
    assert_eq!(f0, frames::resize(&direct, 64, 40));
    assert!(src.take(20).all(|f| f.unwrap().dimensions() == (64, 40)));
}

/// A size set after the source is open applies to the frames delivered from then on; a bad
/// one is refused and leaves the source as it was; `None` goes back to the stored size.
#[test]
fn a_resize_set_after_opening_applies_from_then_on() {
    // Three frames of fine texture, which bilinear sampling aliases.
    let dir = scratch("set_resize");
    for i in 0..3u32 {
        let img = RgbImage::from_fn(128, 96, |x, y| {
            let v = ((x * 37 + y * 101 + i * 13) % 7 * 40) as u8;
            Rgb([v, 255 - v, (x ^ y) as u8])
        });
        img.save(dir.join(format!("{:04}.png", i + 1))).unwrap();
    }
    let mut src = frames::open(&dir, &SourceOptions::default()).unwrap();
    let f0 = src.next().unwrap().unwrap();
    assert_eq!(f0.dimensions(), (128, 96));
    for bad in [(0, 5), (1 << 20, 1 << 20)] {
        assert!(matches!(
            src.set_resize(Some(bad)),
            Err(FrameError::BadSize { .. })
        ));
        assert_eq!(src.size(), (128, 96));
    }
    src.set_resize(Some((40, 30))).unwrap();
    assert_eq!((src.size(), src.native_size()), ((40, 30), (128, 96)));
    assert!(src.describe().contains("resized to 40x30"));
    let f1 = src.next().unwrap().unwrap();
    let direct = image::open(dir.join("0002.png")).unwrap().into_rgb8();
    assert_eq!(f1, frames::resize(&direct, 40, 30));
    // Shrunk by more than two, every pixel counts: not what bilinear sampling gives.
    assert_ne!(f1, resize_bilinear(&direct, 40, 30));
    src.set_resize(None).unwrap();
    assert_eq!(src.next().unwrap().unwrap().dimensions(), (128, 96));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Writes a small image whose every pixel is `v`.
fn save_flat(p: &Path, w: u32, h: u32, v: u8) {
    RgbImage::from_pixel(w, h, Rgb([v, v, v])).save(p).unwrap();
}

#[test]
fn natural_sort_and_ignored_files() {
    let d = scratch("natural");
    for (name, v) in [("10.png", 10), ("2.png", 2), ("1.PNG", 1), ("3.bmp", 3)] {
        save_flat(&d.join(name), 4, 3, v);
    }
    image::GrayImage::from_pixel(4, 3, image::Luma([7]))
        .save(d.join("7.pgm"))
        .unwrap();
    std::fs::write(d.join("notes.txt"), "not a frame").unwrap();
    std::fs::write(d.join("0.gif.bak"), "not a frame").unwrap();
    std::fs::create_dir(d.join("5.png")).unwrap(); // a directory named like a frame
    let got: Vec<u8> = frames::open(&d, &SourceOptions::default())
        .unwrap()
        .map(|f| f.unwrap().get_pixel(0, 0)[0])
        .collect();
    assert_eq!(got, [1, 2, 3, 7, 10]);
    // Said before tracking: the numbering skips, and an image of a format not read is left
    // out; a folder numbered without gaps and with only frames says nothing.
    std::fs::remove_dir_all(&d).unwrap();
    let d = scratch("natural-gaps");
    for k in [1, 2, 4, 5, 9] {
        save_flat(&d.join(format!("{k:04}.png")), 4, 3, k as u8);
    }
    std::fs::write(d.join("0010.gif"), "an image this source does not read").unwrap();
    let c = frames::open(&d, &SourceOptions::default())
        .unwrap()
        .caveats();
    assert_eq!(c.len(), 2, "{c:?}");
    assert!(c[0].contains("skips from 0002.png to 0004.png"), "{}", c[0]);
    assert!(c[0].contains("and at 1 more places"), "{}", c[0]);
    assert!(c[1].contains("0010.gif left out"), "{}", c[1]);
    std::fs::remove_dir_all(&d).unwrap();
    let d = scratch("natural-whole");
    for k in 1..=3 {
        save_flat(&d.join(format!("{k:04}.png")), 4, 3, k as u8);
    }
    std::fs::write(d.join("notes.txt"), "not a frame").unwrap();
    let c = frames::open(&d, &SourceOptions::default())
        .unwrap()
        .caveats();
    assert!(c.is_empty(), "{c:?}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn directory_errors() {
    let d = scratch("direrr");
    // Missing.
    let missing = d.join("nope");
    let e = frames::open(&missing, &SourceOptions::default()).unwrap_err();
    assert!(matches!(e, FrameError::NotFound { .. }), "{e}");
    assert!(e.to_string().contains("nope"));
    // Empty, and only non-image files.
    let empty = d.join("empty");
    std::fs::create_dir(&empty).unwrap();
    let e = FrameSource::from_dir(&empty, &SourceOptions::default()).unwrap_err();
    assert!(matches!(e, FrameError::NoImages { .. }), "{e}");
    std::fs::write(empty.join("readme.txt"), "x").unwrap();
    let e = FrameSource::from_dir(&empty, &SourceOptions::default()).unwrap_err();
    assert!(matches!(e, FrameError::NoImages { .. }), "{e}");

    // A frame that fails to decode: named in the error, and the stream stops there.
    let bad = d.join("bad");
    std::fs::create_dir(&bad).unwrap();
    save_flat(&bad.join("1.png"), 4, 3, 1);
    std::fs::write(bad.join("2.png"), b"\x89PNG\r\n\x1a\n garbage").unwrap();
    save_flat(&bad.join("3.png"), 4, 3, 3);
    let res: Vec<_> = frames::open(&bad, &SourceOptions::default())
        .unwrap()
        .collect();
    assert_eq!(res.len(), 2, "the iterator ends after the error");
    assert!(res[0].is_ok());
    let e = res[1].as_ref().unwrap_err();
    assert!(matches!(e, FrameError::Decode { .. }), "{e}");
    assert!(e.to_string().contains("2.png"), "{e}");
    // A first frame that cannot be read fails at open.
    let bad0 = d.join("bad0");
    std::fs::create_dir(&bad0).unwrap();
    std::fs::write(bad0.join("1.jpg"), b"not a jpeg at all").unwrap();
    assert!(frames::open(&bad0, &SourceOptions::default()).is_err());
    // A first frame of no size fails at open, as decoding it would, not as a frame of no size
    // that no start fits.
    let zero = d.join("zero");
    std::fs::create_dir(&zero).unwrap();
    std::fs::write(zero.join("00000.pgm"), b"P5 0 24 255\n").unwrap();
    save_flat(&zero.join("00001.png"), 4, 3, 1);
    let e = frames::open(&zero, &SourceOptions::default()).unwrap_err();
    assert!(matches!(e, FrameError::Decode { .. }), "{e}");
    assert!(e.to_string().contains("00000.pgm"), "{e}");
    assert!(e.to_string().contains("an empty image (0x24)"), "{e}");

    // Hidden files are not frames; a dangling link is one, and fails naming itself rather
    // than being skipped (which renumbered every later frame).
    let links = d.join("links");
    std::fs::create_dir(&links).unwrap();
    save_flat(&links.join("1.png"), 4, 3, 1);
    save_flat(&links.join(".thumb.png"), 4, 3, 9);
    std::fs::write(links.join("._1.png"), b"\x00\x05\x16\x07 resource fork").unwrap();
    save_flat(&links.join("3.png"), 4, 3, 3);
    let listed = frames::dir::list_images(&links).unwrap();
    let names: Vec<_> = listed.iter().map(|p| p.file_name().unwrap()).collect();
    assert_eq!(names, ["1.png", "3.png"]);
    #[cfg(unix)]
    {
        // A named pipe is no frame: reading it would wait for ever.
        let fifo = links.join("4.png");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let listed = frames::dir::list_images(&links).unwrap();
            assert!(!listed.contains(&fifo), "{listed:?}");
        }
        std::os::unix::fs::symlink(d.join("gone.png"), links.join("2.png")).unwrap();
        let res: Vec<_> = frames::open(&links, &SourceOptions::default())
            .unwrap()
            .collect();
        assert_eq!(res.len(), 2, "the iterator ends after the error");
        let e = res[1].as_ref().unwrap_err().to_string();
        assert!(e.contains("2.png"), "{e}");
    }

    // A JPEG cut short decoded "successfully", its missing part grey.
    let jpg = d.join("jpg");
    std::fs::create_dir(&jpg).unwrap();
    let img = image::RgbImage::from_fn(64, 48, |x, y| {
        image::Rgb([(x * 4) as u8, (y * 5) as u8, 90])
    });
    img.save(jpg.join("1.jpg")).unwrap();
    let bytes = std::fs::read(jpg.join("1.jpg")).unwrap();
    std::fs::write(jpg.join("2.jpg"), &bytes[..bytes.len() * 3 / 4]).unwrap();
    let res: Vec<_> = frames::open(&jpg, &SourceOptions::default())
        .unwrap()
        .collect();
    assert!(res[0].is_ok());
    let e = res[1].as_ref().unwrap_err().to_string();
    assert!(
        e.contains("2.jpg") && e.contains("truncated or damaged JPEG"),
        "{e}"
    );

    // A header claiming more pixels than an image may have is refused before decoding: 23
    // bytes of PGM claiming 20000x10000.
    let huge = d.join("huge");
    std::fs::create_dir(&huge).unwrap();
    std::fs::write(huge.join("1.pgm"), b"P5\n20000 10000\n255\nabc").unwrap();
    let e = match frames::dir::decode_rgb(&huge.join("1.pgm")) {
        Ok(_) => panic!("a 20000x10000 claim decoded"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains("1.pgm") && e.contains("20000x10000 is more than the 134217728 pixels"),
        "{e}"
    );
    // Frames stored larger than the tracker takes (8000x5000, 40 megapixels, over 2^25) are
    // read only when scaled down (the size comes from the first file's header).
    let photos = d.join("photos");
    std::fs::create_dir(&photos).unwrap();
    std::fs::write(photos.join("1.pgm"), b"P5\n8000 5000\n255\nabc").unwrap();
    let e = frames::open(&photos, &SourceOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frames of 8000x5000 are more than the 33554432 pixels")
            && e.contains("scale them down"),
        "{e}"
    );
    let scaled = SourceOptions {
        resize: Some((800, 500)),
    };
    assert_eq!(frames::open(&photos, &scaled).unwrap().size(), (800, 500));

    // Frames of different sizes: the frame and both sizes named.
    let mixed = d.join("mixed");
    std::fs::create_dir(&mixed).unwrap();
    save_flat(&mixed.join("1.png"), 4, 3, 1);
    save_flat(&mixed.join("2.png"), 4, 3, 2);
    save_flat(&mixed.join("10.png"), 5, 3, 10);
    let res: Vec<_> = frames::open(&mixed, &SourceOptions::default())
        .unwrap()
        .collect();
    assert_eq!(res.len(), 3);
    let e = res[2].as_ref().unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, FrameError::SizeMismatch { .. }), "{msg}");
    assert!(
        msg.contains("10.png") && msg.contains("5x3") && msg.contains("4x3"),
        "{msg}"
    );
    assert!(!msg.contains('\n'));
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn bad_resize_and_sizes() {
    assert_eq!(frames::parse_size("160x120").unwrap(), (160, 120));
    let e = frames::parse_size("160by120").unwrap_err();
    assert!(e.to_string().contains("160by120"));
    // At most 2^25 pixels: 8K UHD fits, 8192x8192 does not.
    assert_eq!(frames::parse_size("7680x4320").unwrap(), (7680, 4320));
    assert_eq!(frames::parse_size("8192x4096").unwrap(), (8192, 4096));
    assert_eq!(frames::parse_size("32768x1024").unwrap(), (32768, 1024));
    for big in ["8192x4097", "8192x8192", "32768x2048", "32768x32768"] {
        let e = frames::parse_size(big).unwrap_err().to_string();
        assert!(e.contains("pixels in all"), "{big}: {e}");
    }
    let d = scratch("badresize");
    save_flat(&d.join("1.png"), 4, 3, 1);
    // Zero, and (as parse_size bounds them) more than 32768 a side: 100000x100000 once
    // aborted on its allocation at the first frame, u32::MAX overflowed the buffer's size.
    for resize in [
        (0, 5),
        (32769, 10),
        // Sides within bounds but more pixels than a source reads: 32768x32768 was killed
        // for memory on the first frame.
        (32768, 32768),
        (8193, 8192),
        (100_000, 100_000),
        (u32::MAX, u32::MAX),
    ] {
        let opts = SourceOptions {
            resize: Some(resize),
        };
        assert!(
            matches!(frames::open(&d, &opts), Err(FrameError::BadSize { .. })),
            "{resize:?}"
        );
    }
    std::fs::remove_dir_all(&d).unwrap();
}

// ---------------------------------------------------------------- y4m

/// BT.601 limited range, computed here independently of the library: (Y, Cb, Cr) as reals.
fn ycbcr(rgb: [f64; 3]) -> [f64; 3] {
    let [r, g, b] = rgb.map(|v| v / 255.0);
    let e = 0.299 * r + 0.587 * g + 0.114 * b;
    [
        16.0 + 219.0 * e,
        128.0 + 224.0 * (b - e) / 1.772,
        128.0 + 224.0 * (r - e) / 1.402,
    ]
}

fn q(v: f64) -> u8 {
    v.round().clamp(0.0, 255.0) as u8
}

/// Where chroma sample (i, j) of a 4:2:0 layout sits, in luma pixel coordinates.
fn chroma_site(tag: &str, i: u32, j: u32) -> (f64, f64) {
    let (i, j) = (i as f64, j as f64);
    match tag {
        "420jpeg" | "420" => (2.0 * i + 0.5, 2.0 * j + 0.5),
        "420mpeg2" => (2.0 * i, 2.0 * j + 0.5),
        "420paldv" => (2.0 * i, 2.0 * j),
        _ => unreachable!(),
    }
}

/// The planes of one frame of content `f(x, y) → RGB` (reals, so chroma can be sampled where
/// its layout puts it).
fn planes(w: u32, h: u32, tag: &str, f: &dyn Fn(f64, f64) -> [f64; 3]) -> Vec<u8> {
    let mut yp = Vec::new();
    for y in 0..h {
        for x in 0..w {
            yp.push(q(ycbcr(f(x as f64, y as f64))[0]));
        }
    }
    let (mut cb, mut cr) = (Vec::new(), Vec::new());
    if tag == "444" {
        for y in 0..h {
            for x in 0..w {
                let c = ycbcr(f(x as f64, y as f64));
                cb.push(q(c[1]));
                cr.push(q(c[2]));
            }
        }
    } else {
        for j in 0..h.div_ceil(2) {
            for i in 0..w.div_ceil(2) {
                let (sx, sy) = chroma_site(tag, i, j);
                let c = ycbcr(f(sx, sy));
                cb.push(q(c[1]));
                cr.push(q(c[2]));
            }
        }
    }
    yp.extend(cb);
    yp.extend(cr);
    yp
}

fn write_y4m(p: &Path, w: u32, h: u32, tag: &str, frames: &[Vec<u8>]) {
    let mut out = format!("YUV4MPEG2 W{w} H{h} F25:1 Ip A1:1 C{tag}\n").into_bytes();
    for (k, f) in frames.iter().enumerate() {
        if k % 2 == 1 {
            out.extend_from_slice(b"FRAME Ixyz\n"); // a frame parameter, ignored
        } else {
            out.extend_from_slice(b"FRAME\n");
        }
        out.extend_from_slice(f);
    }
    std::fs::write(p, out).unwrap();
}

/// A smooth (affine) colour ramp: bilinear chroma upsampling reproduces it.
fn ramp(k: f64) -> impl Fn(f64, f64) -> [f64; 3] {
    move |x, y| [20.0 + 3.0 * x + k, 30.0 + 2.0 * y, 220.0 - 2.0 * x - y - k]
}

#[test]
fn y4m_round_trip_420_and_444() {
    let d = scratch("y4m");
    // Odd size, to exercise ceil(W/2) chroma planes.
    let (w, h) = (63u32, 45u32);
    for tag in ["444", "420jpeg", "420", "420mpeg2", "420paldv"] {
        let content: Vec<_> = (0..3).map(|k| ramp(5.0 * k as f64)).collect();
        let fr: Vec<Vec<u8>> = content.iter().map(|f| planes(w, h, tag, f)).collect();
        let p = d.join(format!("ramp-{tag}.Y4M"));
        write_y4m(&p, w, h, tag, &fr);
        let src = frames::open(&p, &SourceOptions::default()).unwrap();
        assert_eq!(src.size(), (w, h));
        assert_eq!(src.len_hint(), Some(3), "{tag}");
        assert!(src.describe().contains("y4m"), "{}", src.describe());
        let got = collect(src).unwrap();
        assert_eq!(got.len(), 3, "{tag}");
        for (img, f) in got.iter().zip(&content) {
            let mut worst_inner: f64 = 0.0;
            let mut worst: f64 = 0.0;
            for (x, y, px) in img.enumerate_pixels() {
                let want = f(x as f64, y as f64);
                let err = (0..3)
                    .map(|c| (px[c] as f64 - want[c]).abs())
                    .fold(0.0, f64::max);
                worst = worst.max(err);
                if x > 0 && y > 0 && x < w - 1 && y < h - 1 {
                    worst_inner = worst_inner.max(err);
                }
            }
            // Quantisation of Y, Cb, Cr (and of upsampled chroma) costs up to ~3 levels.
            assert!(worst_inner <= 3.0, "{tag}: inner error {worst_inner}");
            // At the border 4:2:0 chroma is clamped (edge replication): a little more.
            assert!(worst <= 6.0, "{tag}: border error {worst}");
        }
    }

    // 4:4:4 with unstructured content: every pixel stands alone.
    let noise = |x: f64, y: f64| {
        let h = |s: f64| {
            ((x * 12.9898 + y * 78.233 + s).sin() * 43758.5453)
                .fract()
                .abs()
        };
        [255.0 * h(0.0), 255.0 * h(1.0), 255.0 * h(2.0)]
    };
    let p = d.join("noise.y4m");
    write_y4m(&p, 20, 10, "444", &[planes(20, 10, "444", &noise)]);
    let got = collect(frames::open(&p, &SourceOptions::default()).unwrap()).unwrap();
    for (x, y, px) in got[0].enumerate_pixels() {
        let want = noise(x as f64, y as f64);
        for c in 0..3 {
            assert!(
                (px[c] as f64 - want[c]).abs() <= 3.0,
                "({x},{y}) {c}: {} vs {}",
                px[c],
                want[c]
            );
        }
    }
    std::fs::remove_dir_all(&d).unwrap();
}

/// Textured frames, the pattern moving a pixel right each frame.
fn moving_noise(w: u32, h: u32, n: usize) -> Vec<Vec<u8>> {
    (0..n)
        .map(|k| {
            let f = move |x: f64, y: f64| {
                let v = (((x - k as f64) * 12.9898 + y * 78.233).sin() * 43758.5453)
                    .fract()
                    .abs();
                [255.0 * v, 200.0 * v, 120.0 + 100.0 * v]
            };
            planes(w, h, "444", &f)
        })
        .collect()
}

#[test]
fn a_y4m_stream_reads_as_its_file_does() {
    let d = scratch("y4mstream");
    let p = d.join("clip.y4m");
    write_y4m(&p, 64, 48, "444", &moving_noise(64, 48, 4));
    let opts = SourceOptions::default();
    let from_file = collect(frames::open(&p, &opts).unwrap()).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let stream =
        FrameSource::from_y4m_reader(Box::new(std::io::Cursor::new(bytes.clone())), "pipe", &opts)
            .unwrap();
    assert_eq!(stream.size(), (64, 48));
    assert_eq!(stream.len_hint(), None);
    assert!(stream.describe().contains("pipe"), "{}", stream.describe());
    assert_eq!(collect(stream).unwrap(), from_file);
    // Cut inside the last frame: the stream says so, as the file would.
    let cut = bytes[..bytes.len() - 10].to_vec();
    let mut stream =
        FrameSource::from_y4m_reader(Box::new(std::io::Cursor::new(cut)), "pipe", &opts).unwrap();
    let got = stream.by_ref().collect::<Result<Vec<_>, _>>().unwrap();
    assert_eq!(got[..], from_file[..from_file.len() - 1]);
    let short = stream.shortfall().expect("a cut stream says so");
    assert!(short.contains("pipe"), "{short}");

    // `pftrack track -` reads standard input: the same poses as from the file.
    let track = |input: &str, out: &Path, stdin: std::process::Stdio| {
        let run = std::process::Command::new(env!("CARGO_BIN_EXE_pftrack"))
            .args([
                "track",
                input,
                "--init-ellipse",
                "32,24,12,10",
                "--backend",
                "cpu",
            ])
            .arg("--out")
            .arg(out)
            .stdin(stdin)
            .output()
            .unwrap();
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        std::fs::read_to_string(out).unwrap()
    };
    let file_poses = track(
        p.to_str().unwrap(),
        &d.join("file.csv"),
        std::process::Stdio::null(),
    );
    let piped = std::fs::File::open(&p).unwrap();
    let stdin_poses = track("-", &d.join("stdin.csv"), piped.into());
    assert_eq!(stdin_poses.lines().count(), 5);
    assert_eq!(stdin_poses, file_poses);
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn y4m_errors() {
    let d = scratch("y4merr");
    let f = planes(8, 6, "420jpeg", &ramp(0.0));
    let good = d.join("good.y4m");
    write_y4m(&good, 8, 6, "420jpeg", &[f.clone(), f.clone()]);
    let bytes = std::fs::read(&good).unwrap();

    // Truncated: a partial last frame ends the stream after the complete ones, as a damaged
    // video through ffmpeg does, and the source says where it was cut; with no complete frame
    // it is the error.
    let cut = d.join("cut.y4m");
    std::fs::write(&cut, &bytes[..bytes.len() - 5]).unwrap();
    let mut src = frames::open(&cut, &SourceOptions::default()).unwrap();
    let res: Vec<_> = src.by_ref().collect();
    assert_eq!(res.len(), 1);
    assert!(res[0].is_ok());
    let short = src.shortfall().expect("a cut stream says so");
    assert!(
        short.contains("cut.y4m") && short.contains("inside frame 1"),
        "{short}"
    );
    let mut whole = frames::open(&good, &SourceOptions::default()).unwrap();
    assert_eq!(whole.by_ref().count(), 2);
    assert_eq!(whole.shortfall(), None);
    let first_cut = d.join("first-cut.y4m");
    let one_frame = bytes.len() / 2;
    std::fs::write(&first_cut, &bytes[..one_frame]).unwrap();
    let res: Vec<_> = frames::open(&first_cut, &SourceOptions::default())
        .unwrap()
        .collect();
    assert_eq!(res.len(), 1);
    let e = res[0].as_ref().unwrap_err();
    assert!(matches!(e, FrameError::Truncated { frame: 0, .. }), "{e}");
    assert!(e.to_string().contains("first-cut.y4m"));

    // Malformed and unsupported headers.
    let cases: [(&str, &[u8]); 7] = [
        ("nosig", b"YUV4MPEG W8 H6\nFRAME\n"),
        ("now", b"YUV4MPEG2 H6 C420jpeg\nFRAME\n"),
        ("badw", b"YUV4MPEG2 Wabc H6\nFRAME\n"),
        ("c422", b"YUV4MPEG2 W8 H6 C422\nFRAME\n"),
        ("p10", b"YUV4MPEG2 W8 H6 C420p10\nFRAME\n"),
        ("noline", b"YUV4MPEG2 W8 H6"),
        ("empty", b""),
    ];
    for (name, content) in cases {
        let p = d.join(format!("{name}.y4m"));
        std::fs::write(&p, content).unwrap();
        // (`open` hands a colour space the parser does not read to ffmpeg; see below.)
        let e = FrameSource::from_y4m(&p, &SourceOptions::default()).unwrap_err();
        assert!(matches!(e, FrameError::Y4m { .. }), "{name}: {e}");
        assert!(!e.to_string().contains('\n'));
    }
    let e = FrameSource::from_y4m(&d.join("p10.y4m"), &SourceOptions::default()).unwrap_err();
    assert!(e.to_string().contains("C420p10"), "{e}");
    assert!(e.to_string().contains("-pix_fmt yuv420p"), "{e}");
    // A file of a colour space the parser does not read goes through ffmpeg, which does.
    if have_ffmpeg() {
        for (pix, tag) in [("yuv422p", "C422"), ("yuv420p10le", "C420p10")] {
            let p = d.join(format!("real-{pix}.y4m"));
            testsrc("32x24", 2, &["-pix_fmt", pix, "-strict", "-1"], &p);
            let head = std::fs::read(&p).unwrap();
            let line =
                String::from_utf8_lossy(&head[..head.iter().position(|&b| b == b'\n').unwrap()])
                    .to_string();
            assert!(line.contains(tag), "{line}");
            let src = frames::open(&p, &SourceOptions::default()).unwrap();
            assert!(src.describe().contains("ffmpeg"), "{}", src.describe());
            let got = collect(src).unwrap();
            assert_eq!(got.len(), 2);
            assert_eq!(got[0].dimensions(), (32, 24));
            // Cut inside its last frame, the file gives its whole frames, as through the
            // parser, and says where it ends: ffmpeg itself ends it with success and no word.
            let cut = d.join(format!("cut-{pix}.y4m"));
            std::fs::write(&cut, &head[..head.len() - 7]).unwrap();
            let mut src = frames::open(&cut, &SourceOptions::default()).unwrap();
            assert_eq!(src.len_hint(), Some(1));
            assert_eq!(src.by_ref().map(Result::unwrap).count(), 1);
            let short = src.shortfall().expect("a cut file says so");
            assert!(short.contains("ends inside frame 1"), "{short}");
            assert!(!short.contains('\n'), "{short}");
        }
    }

    // Garbage where the second FRAME header belongs.
    let mut bad = bytes.clone();
    let second = bytes.len() - f.len() - 6;
    bad[second..second + 5].copy_from_slice(b"JUNK!");
    let badp = d.join("badframe.y4m");
    std::fs::write(&badp, &bad).unwrap();
    let res: Vec<_> = frames::open(&badp, &SourceOptions::default())
        .unwrap()
        .collect();
    assert_eq!(res.len(), 2);
    assert!(matches!(res[1], Err(FrameError::Y4m { .. })));

    // A header and no frames.
    let none = d.join("none.y4m");
    std::fs::write(&none, b"YUV4MPEG2 W8 H6\n").unwrap();
    let res: Vec<_> = frames::open(&none, &SourceOptions::default())
        .unwrap()
        .collect();
    assert!(matches!(res[..], [Err(FrameError::NoFrames { .. })]));

    // Missing file.
    let e = frames::open(&d.join("absent.y4m"), &SourceOptions::default()).unwrap_err();
    assert!(matches!(e, FrameError::NotFound { .. }), "{e}");
    std::fs::remove_dir_all(&d).unwrap();
}

// ---------------------------------------------------------------- ffmpeg

#[test]
fn carphone_mp4_through_ffmpeg() {
    let Some(p) = data("carphone/carphone_pristine.mp4") else {
        return;
    };
    if !have_ffmpeg() {
        return;
    }
    let src = frames::open(&p, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (176, 144));
    assert_eq!(src.len_hint(), Some(120));
    assert!(src.describe().contains("ffmpeg"));
    let mut src = src;
    let mut n = 0;
    for f in src.by_ref() {
        assert_eq!(f.unwrap().dimensions(), (176, 144));
        n += 1;
    }
    assert_eq!(n, 120);
    assert_eq!(src.shortfall(), None, "every declared frame came");
    // With a resize to the paper's 128x96.
    let opts = SourceOptions {
        resize: Some((128, 96)),
    };
    let mut src = frames::open(&p, &opts).unwrap();
    assert_eq!(src.size(), (128, 96));
    assert_eq!(src.next().unwrap().unwrap().dimensions(), (128, 96));
    // Dropping a source mid-stream shuts ffmpeg down (the test would hang otherwise).
    drop(src);
}

#[test]
fn box_mp4_gives_each_decoded_frame_once() {
    // The OpenCV box clip has a slice ffmpeg cannot decode: its container lists 456 frames and
    // 455 decode. Written as constant-rate raw video, ffmpeg repeated frames to fill the gap
    // and sent 457, so frame numbers drifted from the video's own.
    let Some(p) = data("box/box.mp4") else {
        return;
    };
    if !have_ffmpeg() {
        return;
    }
    let out = std::process::Command::new("ffprobe")
        .args(["-v", "error", "-count_frames", "-select_streams", "v:0"])
        .args(["-show_entries", "stream=nb_read_frames", "-of", "csv=p=0"])
        .arg(&p)
        .output()
        .unwrap();
    assert!(out.status.success());
    let decoded: usize = String::from_utf8_lossy(&out.stdout).trim().parse().unwrap();
    let mut src = frames::open(&p, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (640, 480));
    let mut n = 0;
    for f in src.by_ref() {
        f.unwrap();
        n += 1;
    }
    assert_eq!(n, decoded, "frames read against ffprobe's decoded count");
    // ffmpeg ends with success; the source says a frame is missing, and why.
    let short = src.shortfall().expect("455 of 456 frames is a shortfall");
    assert!(short.contains("decoded 455 of the 456 frames"), "{short}");
    assert!(short.contains("numbered as decoded"), "{short}");
    assert!(
        short.contains("[h264] ") && !short.contains("0x"),
        "{short}"
    );
}

#[test]
fn a_truncated_video_says_it_is_short() {
    if !have_ffmpeg() {
        return;
    }
    let d = scratch("truncated-video");
    // Textured frames, so the encoded file has some length to cut.
    for k in 0..6u32 {
        let img = image::RgbImage::from_fn(96, 72, |x, y| {
            let v = (x * 37 + y * 91 + k * 13) ^ (x * y + k);
            image::Rgb([(v % 251) as u8, (v / 3 % 241) as u8, (v / 7 % 239) as u8])
        });
        img.save(d.join(format!("{k}.png"))).unwrap();
    }
    // The six frames encoded with ffmpeg's own MPEG-4 encoder (`extra`: more options).
    let pattern = d.join("%d.png");
    let encode = |out: &Path, extra: &[&str]| {
        let os = std::ffi::OsStr::new;
        let mut args = vec![os("-framerate"), os("10"), os("-i"), pattern.as_os_str()];
        args.extend([os("-c:v"), os("mpeg4")]);
        args.extend(extra.iter().map(|a| os(a)));
        args.push(out.as_os_str());
        ffmpeg(&args);
    };
    let full = d.join("full.avi");
    encode(&full, &[]);
    let bytes = std::fs::read(&full).unwrap();
    let cut = d.join("cut.avi");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 5]).unwrap();
    let mut whole = frames::open(&full, &SourceOptions::default()).unwrap();
    assert_eq!(whole.by_ref().map(Result::unwrap).count(), 6);
    assert_eq!(whole.shortfall(), None);
    // However this ffmpeg takes the cut file, it never passes for a whole video: refused at
    // open, an error while reading, or (ffmpeg 5.1 here: 3 frames and success) a shortfall.
    let said = match frames::open(&cut, &SourceOptions::default()) {
        Err(_) => true,
        Ok(mut src) => {
            let mut n = 0;
            let mut failed = false;
            for f in src.by_ref() {
                match f {
                    Ok(_) => n += 1,
                    Err(_) => failed = true,
                }
            }
            assert!(n < 6, "{n} frames from two fifths of the file");
            let short = src.shortfall();
            if let Some(s) = &short {
                assert!(s.contains(&format!("decoded {n} of the 6 frames")), "{s}");
            }
            failed || short.is_some()
        }
    };
    assert!(said, "a cut video passed for a whole one");

    // Matroska declares no frame count: cut, the frames decoded come with ffmpeg's complaint.
    let mkv = d.join("full.mkv");
    encode(&mkv, &[]);
    let mut whole = frames::open(&mkv, &SourceOptions::default()).unwrap();
    assert_eq!(whole.by_ref().map(Result::unwrap).count(), 6);
    assert_eq!((whole.len_hint(), whole.shortfall()), (None, None));
    let bytes = std::fs::read(&mkv).unwrap();
    let cut_mkv = d.join("cut.mkv");
    std::fs::write(&cut_mkv, &bytes[..bytes.len() / 2]).unwrap();
    // Refused at open says it too.
    if let Ok(mut src) = frames::open(&cut_mkv, &SourceOptions::default()) {
        let results: Vec<_> = src.by_ref().collect();
        let n = results.iter().filter(|r| r.is_ok()).count();
        assert!(n < 6, "{n} frames from half the file");
        let short = src.shortfall();
        assert!(
            results.iter().any(Result::is_err)
                || short
                    .as_ref()
                    .is_some_and(|s| s.contains("declares no frame count")),
            "a cut Matroska file passed for a whole one: {n} frames, {short:?}"
        );
    }

    // A clip cut without re-encoding keeps samples before its start that ffmpeg decodes but
    // never shows: fewer frames than declared, no complaint, no shortfall.
    let mp4 = d.join("full.mp4");
    encode(&mp4, &["-g", "4"]);
    let trimmed = d.join("trimmed.mp4");
    ffmpeg(&[
        "-ss".as_ref(),
        "0.25".as_ref(),
        "-i".as_ref(),
        mp4.as_os_str(),
        "-c".as_ref(),
        "copy".as_ref(),
        trimmed.as_os_str(),
    ]);
    let mut src = frames::open(&trimmed, &SourceOptions::default()).unwrap();
    let n = src.by_ref().map(Result::unwrap).count();
    // ffmpeg 5.1: 3 of the 6 samples shown.
    assert!(
        src.len_hint().is_some_and(|d| 0 < n && n < d),
        "{n} of {:?}",
        src.len_hint()
    );
    assert_eq!(src.shortfall(), None);
    std::fs::remove_dir_all(&d).unwrap();
}

/// Runs ffmpeg with `args`, failing the test when it fails.
fn ffmpeg(args: &[&std::ffi::OsStr]) {
    let out = std::process::Command::new("ffmpeg")
        .args(["-v", "error", "-nostdin", "-y"])
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Runs ffmpeg with `args`, then the output file `out`.
fn ffmpeg_to(args: &[&str], out: &Path) {
    let mut all: Vec<&std::ffi::OsStr> = args.iter().map(std::ffi::OsStr::new).collect();
    all.push(out.as_os_str());
    ffmpeg(&all);
}

/// `frames` frames of ffmpeg's test pattern at `size` (`WxH`), with the output options
/// `extra`, into `out`.
fn testsrc(size: &str, frames: usize, extra: &[&str], out: &Path) {
    let (input, count) = (format!("testsrc=size={size}:rate=25"), frames.to_string());
    let mut args = vec!["-f", "lavfi", "-i", &input, "-frames:v", &count];
    args.extend(extra);
    ffmpeg_to(&args, out);
}

/// Compares our parser's decode of `y4m` with ffmpeg's rgb24 decode of the same file (with
/// `sws_flags`): (frames, mean |difference|, largest difference, share above 12 levels).
fn compare_with_ffmpeg(y4m: &Path, sws_flags: &str) -> (usize, f64, u8, f64) {
    let raw = y4m.with_extension("rgb");
    ffmpeg(&[
        "-i".as_ref(),
        y4m.as_os_str(),
        "-sws_flags".as_ref(),
        sws_flags.as_ref(),
        "-f".as_ref(),
        "rawvideo".as_ref(),
        "-pix_fmt".as_ref(),
        "rgb24".as_ref(),
        raw.as_os_str(),
    ]);
    let theirs = std::fs::read(&raw).unwrap();
    let ours = frames::open(y4m, &SourceOptions::default()).unwrap();
    assert!(ours.describe().starts_with("y4m"), "{}", ours.describe());
    let (w, h) = ours.size();
    let fb = (w * h * 3) as usize;
    let (mut n, mut sum, mut worst, mut big) = (0usize, 0u64, 0u8, 0u64);
    for f in ours {
        let f = f.unwrap();
        let reference = &theirs[n * fb..(n + 1) * fb];
        for (x, y) in f.as_raw().iter().zip(reference) {
            let d = x.abs_diff(*y);
            sum += d as u64;
            worst = worst.max(d);
            big += u64::from(d > 12);
        }
        n += 1;
    }
    assert_eq!(theirs.len(), n * fb, "frame count differs from ffmpeg's");
    let total = (n * fb) as f64;
    (n, sum as f64 / total, worst, big as f64 / total)
}

#[test]
fn y4m_parser_matches_ffmpeg_on_carphone() {
    let Some(mp4) = data("carphone/carphone_pristine.mp4") else {
        return;
    };
    if !have_ffmpeg() {
        return;
    }
    let d = scratch("carphone-y4m");
    // 4:4:4 isolates the colour matrix and range: no chroma upsampling on either side.
    let y444 = d.join("carphone444.y4m");
    ffmpeg(&[
        "-i".as_ref(),
        mp4.as_os_str(),
        "-pix_fmt".as_ref(),
        "yuv444p".as_ref(),
        "-f".as_ref(),
        "yuv4mpegpipe".as_ref(),
        y444.as_os_str(),
    ]);
    let (n, mean, worst, _) = compare_with_ffmpeg(&y444, "accurate_rnd+full_chroma_int");
    say(&format!(
        "y4m 4:4:4 vs ffmpeg rgb24: {n} frames, mean |diff| {mean:.4}, max {worst}"
    ));
    assert_eq!(n, 120);
    assert!(worst <= 1 && mean < 0.05, "mean {mean}, max {worst}");

    // 4:2:0 (C420mpeg2, as ffmpeg writes it for this H.264 stream) against ffmpeg's
    // interpolating conversion: the upsampling filters differ a little at colour edges.
    let y420 = d.join("carphone420.y4m");
    ffmpeg(&[
        "-i".as_ref(),
        mp4.as_os_str(),
        "-pix_fmt".as_ref(),
        "yuv420p".as_ref(),
        "-f".as_ref(),
        "yuv4mpegpipe".as_ref(),
        y420.as_os_str(),
    ]);
    let (n, mean, worst, big) = compare_with_ffmpeg(&y420, "bilinear+accurate_rnd+full_chroma_int");
    say(&format!(
        "y4m 4:2:0 vs ffmpeg rgb24: {n} frames, mean |diff| {mean:.4}, max {worst}, \
         share > 12 levels {big:.5}"
    ));
    assert_eq!(n, 120);
    assert!(mean < 1.2, "mean |diff| {mean}");
    assert!(big < 0.005, "share of differences above 12 levels {big}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn ffmpeg_missing_says_how_to_install() {
    let d = scratch("noffmpeg");
    let p = d.join("clip.mp4");
    std::fs::write(&p, b"whatever").unwrap();
    let tools = FfmpegTools {
        ffmpeg: "pftrack-no-such-ffmpeg".into(),
        ffprobe: "pftrack-no-such-ffprobe".into(),
    };
    let e = FrameSource::from_video(&p, &SourceOptions::default(), &tools).unwrap_err();
    assert!(matches!(e, FrameError::FfmpegMissing { .. }), "{e}");
    assert!(
        e.to_string().contains("clip.mp4"),
        "the video is named: {e}"
    );
    assert!(
        e.to_string()
            .contains("install ffmpeg (Debian: apt-get install ffmpeg)"),
        "{e}"
    );
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn ffmpeg_bad_inputs() {
    if !have_ffmpeg() {
        return;
    }
    let d = scratch("ffbad");
    let e = frames::open(&d.join("absent.mp4"), &SourceOptions::default()).unwrap_err();
    assert!(matches!(e, FrameError::NotFound { .. }), "{e}");
    let junk = d.join("junk.mp4");
    std::fs::write(&junk, b"this is not a video file at all").unwrap();
    let e = frames::open(&junk, &SourceOptions::default()).unwrap_err();
    assert!(matches!(e, FrameError::Ffmpeg { .. }), "{e}");
    let msg = e.to_string();
    assert!(msg.contains("junk.mp4") && !msg.contains('\n'), "{msg}");
    std::fs::remove_dir_all(&d).unwrap();
}

/// Stand-in ffmpeg/ffprobe scripts, to test failure paths real ffmpeg rarely shows.
#[cfg(unix)]
mod fake {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    fn script(dir: &Path, name: &str, body: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, format!("#!/bin/sh\n{body}\n")).unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
        p
    }

    /// Opens with the fake tools, retrying while another test's fork briefly holds the
    /// freshly written script open for writing (ETXTBSY).
    fn open_fake(p: &Path, tools: &FfmpegTools) -> FrameSource {
        for _ in 0..50 {
            match FrameSource::from_video(p, &SourceOptions::default(), tools) {
                Ok(s) => return s,
                Err(FrameError::Io { cause, .. }) if cause.raw_os_error() == Some(26) => {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                Err(e) => panic!("{e}"),
            }
        }
        panic!("scripts stayed busy");
    }

    #[test]
    fn failure_after_some_frames_partial_frames_and_drop() {
        let d = scratch("fake");
        let input = d.join("in.avi");
        std::fs::write(&input, b"x").unwrap();
        let ffprobe = script(
            &d,
            "ffprobe",
            "echo width=2; echo height=2; echo nb_frames=N/A",
        );
        // Two whole 2x2 RGB frames (24 bytes), then a failure with a message.
        let failing = script(
            &d,
            "ffmpeg-fail",
            "head -c 24 /dev/zero; echo 'first line' >&2; echo 'decoder exploded' >&2; exit 3",
        );
        let tools = FfmpegTools {
            ffmpeg: failing,
            ffprobe: ffprobe.clone(),
        };
        let src = open_fake(&input, &tools);
        assert_eq!(src.len_hint(), None);
        let res: Vec<_> = src.collect();
        assert_eq!(res.len(), 3);
        assert!(res[0].is_ok() && res[1].is_ok());
        let e = res[2].as_ref().unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, FrameError::Ffmpeg { .. }), "{msg}");
        assert!(
            msg.contains("decoder exploded") && msg.contains("after 2 frames"),
            "{msg}"
        );
        assert!(!msg.contains('\n'));

        // A clean exit with a partial trailing frame.
        let partial = script(&d, "ffmpeg-partial", "head -c 30 /dev/zero");
        let tools = FfmpegTools {
            ffmpeg: partial,
            ffprobe: ffprobe.clone(),
        };
        let res: Vec<_> = open_fake(&input, &tools).collect();
        assert_eq!(res.len(), 3);
        assert!(matches!(
            res[2],
            Err(FrameError::Truncated { frame: 2, .. })
        ));

        // Failing before any frame.
        let none = script(&d, "ffmpeg-none", "echo 'no way' >&2; exit 1");
        let tools = FfmpegTools {
            ffmpeg: none,
            ffprobe: ffprobe.clone(),
        };
        let res: Vec<_> = open_fake(&input, &tools).collect();
        assert!(matches!(res[..], [Err(FrameError::Ffmpeg { .. })]));

        // An endless stream: dropping the source mid-way kills and reaps the child.
        let endless = script(&d, "ffmpeg-endless", "exec cat /dev/zero");
        let tools = FfmpegTools {
            ffmpeg: endless,
            ffprobe: ffprobe.clone(),
        };
        let mut src = open_fake(&input, &tools);
        for _ in 0..5 {
            assert_eq!(src.next().unwrap().unwrap().dimensions(), (2, 2));
        }
        drop(src);

        // An ffmpeg older than 5.1 rejects `-fps_mode`: the decode restarts with `-vsync`.
        let old = script(
            &d,
            "ffmpeg-old",
            "case \"$*\" in\n\
             *-fps_mode*) echo \"Unrecognized option 'fps_mode'.\" >&2;\n\
               echo 'Error splitting the argument list: Option not found' >&2; exit 1;;\n\
             *'-vsync passthrough'*) head -c 24 /dev/zero;;\n\
             *) exit 4;;\n\
             esac",
        );
        let tools = FfmpegTools {
            ffmpeg: old,
            ffprobe: ffprobe.clone(),
        };
        let res: Vec<_> = open_fake(&input, &tools).collect();
        assert_eq!(res.len(), 2, "{res:?}");
        assert!(
            res.iter()
                .all(|f| f.as_ref().unwrap().dimensions() == (2, 2))
        );
        // Any other failure before the first frame is reported, not retried.
        let other = script(
            &d,
            "ffmpeg-other",
            "case \"$*\" in *-vsync*) head -c 24 /dev/zero;; *) echo 'bad codec' >&2; exit 1;; esac",
        );
        let tools = FfmpegTools {
            ffmpeg: other,
            ffprobe: ffprobe.clone(),
        };
        let res: Vec<_> = open_fake(&input, &tools).collect();
        assert!(
            matches!(res[..], [Err(FrameError::Ffmpeg { .. })]),
            "{res:?}"
        );

        // ffprobe that finds no video stream.
        let noprobe = script(&d, "ffprobe-empty", "exit 0");
        let tools = FfmpegTools {
            ffmpeg: "ffmpeg".into(),
            ffprobe: noprobe,
        };
        let e = loop {
            match FrameSource::from_video(&input, &SourceOptions::default(), &tools) {
                Err(FrameError::Io { cause, .. }) if cause.raw_os_error() == Some(26) => {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                other => break other.unwrap_err(),
            }
        };
        assert!(e.to_string().contains("no video stream"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}

// ---------------------------------------------------------------- interlacing, pixel shape

/// A y4m whose header says it is interlaced top field first, of 12:11 pixels, warns of both;
/// resized to square pixels (the size the warning names) it warns of the fields alone.
#[test]
fn interlaced_y4m_and_non_square_pixels_are_said() {
    let d = scratch("layout-y4m");
    let p = d.join("il.y4m");
    write_y4m(&p, 16, 12, "444", &[planes(16, 12, "444", &ramp(0.0))]);
    let bytes = std::fs::read(&p).unwrap();
    let header_end = bytes.iter().position(|&b| b == b'\n').unwrap();
    let header = String::from_utf8(bytes[..header_end].to_vec()).unwrap();
    assert!(header.contains(" Ip A1:1 "), "{header}");
    let plain = frames::open(&p, &SourceOptions::default()).unwrap();
    assert_eq!(plain.caveats(), Vec::<String>::new(), "progressive, square");

    let mut changed = header.replace(" Ip A1:1 ", " It A12:11 ").into_bytes();
    changed.extend_from_slice(&bytes[header_end..]);
    std::fs::write(&p, changed).unwrap();
    let src = frames::open(&p, &SourceOptions::default()).unwrap();
    assert_eq!(
        src.layout(),
        frames::Layout {
            interlaced: Some(frames::FieldOrder::TopFirst),
            pixel_aspect: Some((12, 11)),
        }
    );
    let c = src.caveats();
    assert_eq!(c.len(), 2, "{c:?}");
    assert!(c[0].contains("interlaced, top field first"), "{}", c[0]);
    // 16 × 12/11 = 17.45.
    assert!(
        c[1].contains("12:11, not square") && c[1].contains("--resize 17x12"),
        "{}",
        c[1]
    );
    assert!(c.iter().all(|l| !l.contains('\n')));
    let resized = frames::open(
        &p,
        &SourceOptions {
            resize: Some((17, 12)),
        },
    )
    .unwrap();
    let c = resized.caveats();
    assert_eq!(c.len(), 1, "square after the resize: {c:?}");
    assert!(c[0].contains("interlaced"), "{}", c[0]);
    // The frame itself reads as before: the two fields interleaved.
    assert_eq!(collect(src).unwrap().len(), 1);
    std::fs::remove_dir_all(&d).unwrap();
}

/// A video stored sideways with a display rotation (a phone's) is read as a player shows it:
/// the sides swapped, the pixels ffmpeg's own autorotation gives, and the pixel shape turned
/// with the frame; the probe reports the rotation.
#[test]
fn a_turned_video_is_read_as_shown() {
    if !have_ffmpeg() {
        return;
    }
    let d = scratch("turned-video");
    let plain = d.join("plain.mp4");
    let turned = d.join("turned.mp4");
    testsrc(
        "64x48",
        3,
        &["-vf", "setsar=12/11", "-c:v", "mpeg4"],
        &plain,
    );
    // A display matrix is written when the stream is copied (ffmpeg 5 and 6).
    let p = plain.to_str().unwrap();
    ffmpeg_to(
        &["-i", p, "-c", "copy", "-metadata:s:v:0", "rotate=90"],
        &turned,
    );
    let probed = frames::ffmpeg::probe(&FfmpegTools::default(), &turned).unwrap();
    if probed.rotation.is_none() {
        say("skip: this ffmpeg wrote no display rotation");
        std::fs::remove_dir_all(&d).unwrap();
        return;
    }
    assert!(probed.quarter_turn(), "{probed:?}");
    assert_eq!((probed.width, probed.height), (64, 48));

    let src = frames::open(&turned, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (48, 64));
    assert_eq!(src.layout().pixel_aspect, Some((11, 12)));
    let frames = collect(src).unwrap();
    assert_eq!(frames.len(), 3);
    // The first frame as ffmpeg turns it.
    let shown = d.join("shown.png");
    ffmpeg_to(&["-i", turned.to_str().unwrap(), "-frames:v", "1"], &shown);
    let want = image::open(&shown).unwrap().to_rgb8();
    assert_eq!(want.dimensions(), (48, 64));
    assert!(
        frames[0] == want,
        "the first frame is not ffmpeg's turned one"
    );
    // Unturned, the same file reads as stored.
    let stored = collect(frames::open(&plain, &SourceOptions::default()).unwrap()).unwrap();
    assert_eq!(stored[0].dimensions(), (64, 48));
    std::fs::remove_dir_all(&d).unwrap();
}

/// A JPEG with an Exif orientation (a phone's photo stored sideways) is read as a viewer
/// shows it, in a folder of frames as alone.
#[test]
fn an_image_is_turned_as_its_exif_orientation_says() {
    let d = scratch("exif");
    let img = RgbImage::from_fn(40, 24, |x, y| Rgb([(x * 6) as u8, (y * 10) as u8, 77]));
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 100)
        .encode_image(&img)
        .unwrap();
    let plain = image::load_from_memory(&jpeg).unwrap().to_rgb8();
    // An APP1 Exif segment after the start marker: a little-endian TIFF header and one IFD
    // entry, orientation (0x0112) = 6, "turn 90 degrees clockwise to show".
    let mut exif: Vec<u8> = b"Exif\0\0II*\0\x08\0\0\0\x01\0".to_vec();
    exif.extend([0x12, 0x01, 3, 0, 1, 0, 0, 0, 6, 0, 0, 0, 0, 0, 0, 0]);
    let len = (exif.len() + 2) as u16;
    let mut tagged = jpeg[..2].to_vec();
    tagged.extend([0xFF, 0xE1]);
    tagged.extend(len.to_be_bytes());
    tagged.extend(&exif);
    tagged.extend(&jpeg[2..]);
    for i in 1..=2 {
        std::fs::write(d.join(format!("{i:04}.jpg")), &tagged).unwrap();
    }
    let src = frames::open(&d, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (24, 40));
    let frames = collect(src).unwrap();
    assert_eq!(frames.len(), 2);
    assert!(frames[0] == image::imageops::rotate90(&plain));
    std::fs::remove_dir_all(&d).unwrap();
}

/// ffprobe's field order and sample aspect ratio reach the source's caveats: an interlaced
/// MPEG-2 file, an MPEG-4 file of 12:11 pixels, and carphone, stored in 128:117 pixels.
#[test]
fn interlaced_video_and_non_square_pixels_are_said() {
    if !have_ffmpeg() {
        return;
    }
    let d = scratch("layout-video");
    let source = [
        "-f",
        "lavfi",
        "-i",
        "testsrc=size=64x48:rate=25",
        "-frames:v",
        "3",
    ];
    let arg = |s: &str| std::ffi::OsString::from(s);
    let run = |extra: &[&str], out: &Path| {
        let mut args: Vec<std::ffi::OsString> = source.iter().map(|s| arg(s)).collect();
        args.extend(extra.iter().map(|s| arg(s)));
        args.push(out.as_os_str().to_owned());
        let refs: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        ffmpeg(&refs);
    };
    let fields = d.join("fields.mpg");
    run(
        &[
            "-vf",
            "setfield=bff",
            "-flags",
            "+ildct+ilme",
            "-c:v",
            "mpeg2video",
        ],
        &fields,
    );
    let src = frames::open(&fields, &SourceOptions::default()).unwrap();
    assert_eq!(
        src.layout().interlaced,
        Some(frames::FieldOrder::BottomFirst)
    );
    let c = src.caveats();
    assert_eq!(c.len(), 1, "{c:?}");
    assert!(c[0].contains("bottom field first"), "{}", c[0]);

    let wide = d.join("wide.avi");
    run(&["-vf", "setsar=12/11", "-c:v", "mpeg4"], &wide);
    let src = frames::open(&wide, &SourceOptions::default()).unwrap();
    assert_eq!(
        src.layout(),
        frames::Layout {
            interlaced: None,
            pixel_aspect: Some((12, 11)),
        }
    );
    let c = src.caveats();
    assert_eq!(c.len(), 1, "{c:?}");
    // 64 × 12/11 = 69.8.
    assert!(c[0].contains("--resize 70x48"), "{}", c[0]);
    std::fs::remove_dir_all(&d).unwrap();

    if let Some(p) = data("carphone/carphone_pristine.mp4") {
        let src = frames::open(&p, &SourceOptions::default()).unwrap();
        assert_eq!(src.layout().pixel_aspect, Some((128, 117)));
        // 176 × 128/117 = 192.5.
        assert!(
            src.caveats().iter().any(|l| l.contains("--resize 193x144")),
            "{:?}",
            src.caveats()
        );
    }
}

// ---------------------------------------------------------------- starting later

/// `skip_frames(n)` then reading gives the frames from `n` on, exactly those `next` gives
/// after `n` calls, from an image folder (whose skipped images are not decoded: a broken one
/// there is no error), a y4m file, a y4m stream cut inside a frame, and a video through
/// ffmpeg; fewer are skipped where the input ends first, and an empty input is the error the
/// first read gives.
#[test]
fn skipped_frames_leave_the_rest_in_place() {
    let d = scratch("skip");
    let opts = SourceOptions::default();
    // The frames after `n` skipped, with how many were skipped and the place after them.
    let after_skip = |mut src: FrameSource, n: usize| {
        let skipped = src.skip_frames(n).unwrap();
        let place = src.frames_read();
        let rest = src.by_ref().collect::<Result<Vec<_>, _>>().unwrap();
        (skipped, place, rest, src.frames_read())
    };

    // An image folder, its third image broken.
    let frames = moving_noise(64, 48, 6);
    let y4m = d.join("clip.y4m");
    write_y4m(&y4m, 64, 48, "444", &frames);
    let all = collect(frames::open(&y4m, &opts).unwrap()).unwrap();
    let dir = d.join("dir");
    std::fs::create_dir(&dir).unwrap();
    for (k, f) in all.iter().enumerate() {
        f.save(dir.join(format!("{k:02}.png"))).unwrap();
    }
    std::fs::write(dir.join("02.png"), b"not a png").unwrap();
    assert!(collect(frames::open(&dir, &opts).unwrap()).is_err());
    let (skipped, place, rest, end) = after_skip(frames::open(&dir, &opts).unwrap(), 4);
    assert_eq!((skipped, place, end), (4, 4, 6));
    assert_eq!(rest, all[4..]);
    // Past the end: as many as there are, then nothing.
    let (skipped, _, rest, end) = after_skip(frames::open(&dir, &opts).unwrap(), 9);
    assert_eq!((skipped, rest.len(), end), (6, 0, 6));

    // A y4m file, resized: a skipped frame is neither converted nor resized, the rest are.
    let (skipped, place, rest, _) = after_skip(frames::open(&y4m, &opts).unwrap(), 2);
    assert_eq!((skipped, place), (2, 2));
    assert_eq!(rest, all[2..]);
    let small = SourceOptions {
        resize: Some((32, 24)),
    };
    let resized = collect(frames::open(&y4m, &small).unwrap()).unwrap();
    let (_, _, rest, _) = after_skip(frames::open(&y4m, &small).unwrap(), 3);
    assert_eq!(rest, resized[3..]);

    // A stream cut inside its last frame, the cut met while skipping: it ends after the
    // complete frames and says so, as when read.
    let bytes = std::fs::read(&y4m).unwrap();
    let cut = bytes[..bytes.len() - 10].to_vec();
    let mut stream =
        FrameSource::from_y4m_reader(Box::new(std::io::Cursor::new(cut)), "pipe", &opts).unwrap();
    assert_eq!(stream.skip_frames(8).unwrap(), 5);
    assert!(stream.next().is_none());
    let short = stream.shortfall().expect("a cut stream says so");
    assert!(short.contains("inside frame 5"), "{short}");

    // A malformed frame header met while skipping is the error reading it gives.
    let mut bad = bytes.clone();
    let second = bytes
        .windows(6)
        .enumerate()
        .filter(|(_, w)| w.starts_with(b"FRAME"))
        .nth(1)
        .unwrap()
        .0;
    bad[second..second + 5].copy_from_slice(b"FRAMX");
    let mut stream =
        FrameSource::from_y4m_reader(Box::new(std::io::Cursor::new(bad)), "pipe", &opts).unwrap();
    let err = stream.skip_frames(3).unwrap_err().to_string();
    assert!(err.contains("frame 1: expected a FRAME header"), "{err}");

    // An input with no frames is that error, whether skipped or read.
    let empty = d.join("empty.y4m");
    std::fs::write(&empty, b"YUV4MPEG2 W8 H8 F25:1 C444\n").unwrap();
    let mut src = frames::open(&empty, &opts).unwrap();
    assert!(matches!(
        src.skip_frames(1),
        Err(FrameError::NoFrames { .. })
    ));

    // A video through ffmpeg.
    if have_ffmpeg() {
        let tools = FfmpegTools::default();
        // Past the end, a decode that converts nothing counts the frames: as many as a read
        // gives, with B-frames (decoded out of order) and with uneven timestamps too.
        for (name, extra) in [
            ("clip.mp4", &["-c:v", "mpeg4"][..]),
            ("bframes.mp4", &["-c:v", "mpeg4", "-bf", "2", "-g", "4"][..]),
            (
                "uneven.mkv",
                &[
                    "-vf",
                    "setpts=N*N/TB",
                    "-fps_mode",
                    "passthrough",
                    "-c:v",
                    "mpeg4",
                ][..],
            ),
        ] {
            let video_path = d.join(name);
            testsrc("64x48", 7, extra, &video_path);
            let video = || FrameSource::from_video(&video_path, &opts, &tools).unwrap();
            let all = collect(video()).unwrap();
            assert_eq!(all.len(), 7, "{name}");
            let (skipped, place, rest, end) = after_skip(video(), 5);
            assert_eq!((skipped, place, end), (5, 5, 7), "{name}");
            assert_eq!(rest, all[5..], "{name}");
            for past in [7, 10, 1000] {
                let (skipped, place, rest, end) = after_skip(video(), past);
                assert_eq!(
                    (skipped, place, rest.len(), end),
                    (7, 7, 0, 7),
                    "{name} {past}"
                );
            }
        }
    }
    std::fs::remove_dir_all(&d).unwrap();
}

/// A folder of TIFF (8-bit RGB, 16-bit grey as machine-vision cameras write, 32-bit float
/// RGB, one-channel float) and lossless WebP frames reads the pixels written, as a PNG of the same image does; a
/// 16-bit level is taken to 8 bits by its share of 65535.
#[test]
fn tiff_and_webp_frames_are_read() {
    let d = scratch("tiff-webp");
    let rgb = RgbImage::from_fn(6, 4, |x, y| Rgb([(40 * x) as u8, (60 * y) as u8, 200]));
    let grey16 = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(6, 4, |x, y| {
        image::Luma([(x * 10000 + y * 257) as u16])
    });
    let float = image::Rgb32FImage::from_fn(6, 4, |x, _| image::Rgb([x as f32 / 5.0, 0.5, 1.0]));
    rgb.save(d.join("0.tif")).unwrap();
    image::DynamicImage::ImageLuma16(grey16.clone())
        .save(d.join("1.TIFF"))
        .unwrap();
    image::DynamicImage::ImageRgb32F(float.clone())
        .save(d.join("2.tiff"))
        .unwrap();
    rgb.save(d.join("3.webp")).unwrap();
    rgb.save(d.join("4.png")).unwrap();
    let src = frames::open(&d, &SourceOptions::default()).unwrap();
    assert!(src.caveats().is_empty(), "{:?}", src.caveats());
    let got = collect(src).unwrap();
    assert_eq!(got.len(), 5);
    assert_eq!(got[0], rgb);
    assert_eq!(got[3], rgb);
    assert_eq!(got[4], rgb);
    for (x, y, p) in got[1].enumerate_pixels() {
        let v = grey16.get_pixel(x, y)[0];
        let want = (f64::from(v) * 255.0 / 65535.0).round() as u8;
        assert_eq!(p.0, [want; 3], "16-bit level {v} at {x},{y}");
    }
    for (x, y, p) in got[2].enumerate_pixels() {
        let want = ((x as f32 / 5.0) * 255.0).round() as u8;
        assert_eq!(p.0, [want, 128, 255], "float pixel at {x},{y}");
    }
    std::fs::remove_dir_all(&d).unwrap();

    // One channel of floating point (32 and 64 bits), which the image crate does not decode:
    // taken from 0 to 1 as RGB floats are, clamped, NaN as 0; the folder's size is read from
    // such a first frame too.
    let d = scratch("tiff-grey-float");
    let values: Vec<f32> = (0..24)
        .map(|i| match i {
            0 => f32::NAN,
            1 => -0.5,
            2 => 7.0,
            i => i as f32 / 23.0,
        })
        .collect();
    let write = |name: &str, f64s: bool| {
        let file = std::fs::File::create(d.join(name)).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(file).unwrap();
        if f64s {
            let v: Vec<f64> = values.iter().map(|&v| f64::from(v)).collect();
            enc.write_image::<tiff::encoder::colortype::Gray64Float>(6, 4, &v)
                .unwrap();
        } else {
            enc.write_image::<tiff::encoder::colortype::Gray32Float>(6, 4, &values)
                .unwrap();
        }
    };
    write("0.tif", false);
    write("1.tif", true);
    let src = frames::open(&d, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (6, 4));
    let got = collect(src).unwrap();
    assert_eq!(got.len(), 2);
    for frame in &got {
        for (x, y, p) in frame.enumerate_pixels() {
            let v = values[(y * 6 + x) as usize];
            let want = if v.is_nan() {
                0
            } else {
                (v.clamp(0.0, 1.0) * 255.0).round() as u8
            };
            assert_eq!(p.0, [want; 3], "value {v} at {x},{y}");
        }
    }
    std::fs::remove_dir_all(&d).unwrap();

    // Stored with an orientation tag: turned as `image` turns the TIFFs it decodes (a 6 x 4
    // image stored with tag 6, "turn 90 degrees clockwise to show", shows 4 x 6), the folder's
    // size from its first frame as shown.
    let d = scratch("tiff-grey-float-turned");
    let levels: Vec<f32> = (0..24).map(|i| i as f32 / 23.0).collect();
    for name in ["0.tif", "1.tif"] {
        let file = std::fs::File::create(d.join(name)).unwrap();
        let mut enc = tiff::encoder::TiffEncoder::new(file).unwrap();
        let mut img = enc
            .new_image::<tiff::encoder::colortype::Gray32Float>(6, 4)
            .unwrap();
        img.encoder()
            .write_tag(tiff::tags::Tag::Orientation, 6u16)
            .unwrap();
        img.write_data(&levels).unwrap();
    }
    let src = frames::open(&d, &SourceOptions::default()).unwrap();
    assert_eq!(src.size(), (4, 6));
    let got = collect(src).unwrap();
    assert_eq!(got.len(), 2);
    let stored = RgbImage::from_fn(6, 4, |x, y| {
        Rgb([(levels[(y * 6 + x) as usize] * 255.0).round() as u8; 3])
    });
    let shown = image::imageops::rotate90(&stored);
    assert_eq!(got[0], shown);
    assert_eq!(got[1], shown);
    std::fs::remove_dir_all(&d).unwrap();
}
