//! Rendered output frames: ellipse on its contour, bars, text, lost colour, PNG writing.

mod shared_data;

use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};
use pftrack::geometry::Ellipse;
use pftrack::output::draw::Rect;
use pftrack::output::font::{draw_text, text_size};
use pftrack::output::overlay::{ELLIPSE_LOST, ELLIPSE_OK, PAN_COLOUR, TILT_COLOUR};
use pftrack::output::{Overlay, default_scale, layout, render_overlay, write_png};

/// A frame with a pattern no overlay colour uses (dark, varied), so drawn pixels stand out.
fn frame(w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        Rgb([(x * 7 % 50) as u8, (y * 5 % 60) as u8, ((x + y) % 40) as u8])
    })
}

fn overlay(e: Ellipse, angles: [f64; 3], lost: bool) -> Overlay {
    Overlay {
        frame_index: 12,
        ellipse: e,
        angles_deg: angles,
        score: 0.87,
        lost,
    }
}

/// Distance from `(x, y)` to the contour of `e`, by dense sampling.
fn true_distance(e: &Ellipse, x: f64, y: f64) -> f64 {
    (0..4000)
        .map(|k| {
            let (px, py) = e.point_at(k as f64 * std::f64::consts::TAU / 4000.0);
            (px - x).hypot(py - y)
        })
        .fold(f64::INFINITY, f64::min)
}

fn count(img: &RgbImage, r: Rect, c: Rgb<u8>) -> usize {
    (r.y0..r.y1)
        .flat_map(|y| (r.x0..r.x1).map(move |x| (x, y)))
        .filter(|&(x, y)| *img.get_pixel(x as u32, y as u32) == c)
        .count()
}

#[test]
fn ellipse_pixels_lie_on_the_contour_and_the_rest_is_untouched() {
    let src = frame(128, 96);
    for &(scale, lost) in &[(1u32, false), (3, false), (3, true), (2, false)] {
        let e = Ellipse {
            cx: 60.3,
            cy: 45.7,
            a: 16.0,
            b: 23.0,
            theta: 0.35,
        };
        let o = overlay(e, [12.3, -4.0, 1.2], lost);
        let img = render_overlay(&src, &o, scale);
        let lay = layout(128, 96, scale, &o);
        assert_eq!((img.width(), img.height()), (lay.width, lay.height));
        let s = scale as f64;
        let es = Ellipse {
            cx: (e.cx + 0.5) * s - 0.5,
            cy: (e.cy + 0.5) * s - 0.5,
            a: e.a * s,
            b: e.b * s,
            theta: e.theta,
        };
        let colour = if lost { ELLIPSE_LOST } else { ELLIPSE_OK };
        let mut drawn = 0;
        for y in 0..96 * scale {
            for x in 0..128 * scale {
                let p = *img.get_pixel(x, y);
                let orig = *src.get_pixel(x / scale, y / scale);
                if p == orig {
                    continue;
                }
                assert_eq!(p, colour, "({x},{y}) changed to something else");
                let d = true_distance(&es, x as f64, y as f64);
                assert!(
                    d <= 1.0 + 1e-6,
                    "scale {scale}: ({x},{y}) is {d} px off the contour"
                );
                drawn += 1;
            }
        }
        // A closed line around the contour: about perimeter × width pixels (half when dashed).
        let perimeter = std::f64::consts::PI * (es.a + es.b);
        let width = if scale >= 2 { 2.0 } else { 1.0 };
        let expect = perimeter * width * if lost { 0.6 } else { 1.0 };
        assert!(
            (drawn as f64) > 0.7 * expect && (drawn as f64) < 1.4 * expect,
            "scale {scale} lost {lost}: {drawn} pixels for {expect}"
        );
    }
}

/// The outline at scale 1 (a line a pixel wide, what footage 320 px wide or more gets) is one
/// 8-connected ring, however it falls between pixel centres: where it ran nearly level or
/// upright between them it had broken into pieces, which read as the dashed line of a lost
/// target.
#[test]
fn a_one_pixel_outline_is_unbroken() {
    let src = RgbImage::new(320, 240);
    for (cx, cy, a, b, theta) in [
        (160.0, 120.0, 50.5, 30.5, 0.0),
        (160.25, 119.5, 50.0, 30.0, 0.0),
        (100.5, 80.5, 12.25, 40.75, 0.3),
        (200.0, 120.0, 80.0, 79.5, 1.2),
        (60.0, 60.0, 3.0, 5.0, 0.7),
    ] {
        let e = Ellipse {
            cx,
            cy,
            a,
            b,
            theta,
        };
        let img = render_overlay(&src, &overlay(e, [0.0; 3], false), 1);
        let lit: std::collections::HashSet<(i64, i64)> = (0..240)
            .flat_map(|y| (0..320).map(move |x| (x, y)))
            .filter(|&(x, y)| *img.get_pixel(x as u32, y as u32) == ELLIPSE_OK)
            .collect();
        // One 8-connected piece holds every lit pixel.
        let start = *lit.iter().next().expect("an outline");
        let mut seen = std::collections::HashSet::from([start]);
        let mut todo = vec![start];
        while let Some((x, y)) = todo.pop() {
            for (dx, dy) in (-1..=1).flat_map(|dx| (-1..=1).map(move |dy| (dx, dy))) {
                let n = (x + dx, y + dy);
                if lit.contains(&n) && seen.insert(n) {
                    todo.push(n);
                }
            }
        }
        assert_eq!(seen.len(), lit.len(), "{e:?}: the outline is in pieces");
        // And still a thin line: no more than a pixel and a half of it per pixel of
        // perimeter.
        let perimeter = std::f64::consts::PI * (a + b);
        assert!(
            (lit.len() as f64) < 1.5 * perimeter,
            "{e:?}: {} pixels",
            lit.len()
        );
    }
}

/// A scale that would make a render of gigabytes (160x120 at 1000 wanted 64 GB; u32::MAX
/// overflowed the layout's sizes) is lowered so the frame part fits MAX_SCALED_SIDE.
#[test]
fn huge_scales_are_capped() {
    use pftrack::output::{MAX_SCALED_SIDE, capped_scale};
    assert_eq!(capped_scale(160, 120, 3), 3);
    assert_eq!(capped_scale(160, 120, 0), 1);
    assert_eq!(capped_scale(160, 120, 1000), MAX_SCALED_SIDE / 160);
    assert_eq!(capped_scale(40000, 10, 2), 1);
    assert_eq!(capped_scale(u32::MAX, u32::MAX, u32::MAX), 1);
    let src = frame(16, 12);
    let o = overlay(Ellipse::new(8.0, 6.0, 4.0, 3.0), [0.0; 3], false);
    let img = render_overlay(&src, &o, u32::MAX);
    let lay = layout(16, 12, u32::MAX, &o);
    assert_eq!(img.dimensions(), (lay.width, lay.height));
    assert_eq!(lay.frame.x1, i64::from(MAX_SCALED_SIDE));
    let big = layout(u32::MAX, u32::MAX, u32::MAX, &o);
    assert!(big.frame.x1 > 0);
}

#[test]
fn ellipse_partly_outside_is_clipped_to_the_frame() {
    let src = frame(64, 48);
    let o = overlay(Ellipse::new(60.0, 5.0, 20.0, 15.0), [0.0; 3], false);
    let img = render_overlay(&src, &o, 2);
    let lay = layout(64, 48, 2, &o);
    // Nothing green outside the frame area.
    for (x, y, p) in img.enumerate_pixels() {
        if !lay.frame.contains(x as i64, y as i64) {
            assert_ne!(*p, ELLIPSE_OK);
        }
    }
    assert!(count(&img, lay.frame, ELLIPSE_OK) > 20);
}

#[test]
fn bars_grow_with_the_angle_and_flip_with_its_sign() {
    let src = frame(128, 96);
    let e = Ellipse::new(64.0, 48.0, 15.0, 20.0);
    let bar_pixels = |tilt: f64, pan: f64| {
        let o = overlay(e, [tilt, pan, 0.0], false);
        let img = render_overlay(&src, &o, 3);
        let lay = layout(128, 96, 3, &o);
        let pan_n = count(&img, lay.pan_bar, PAN_COLOUR);
        let tilt_n = count(&img, lay.tilt_bar, TILT_COLOUR);
        // Centroids relative to the bars' middles.
        let mut pan_c = 0.0;
        for y in lay.pan_bar.y0..lay.pan_bar.y1 {
            for x in lay.pan_bar.x0..lay.pan_bar.x1 {
                if *img.get_pixel(x as u32, y as u32) == PAN_COLOUR {
                    pan_c += x as f64 - (lay.pan_bar.x0 + lay.pan_bar.x1) as f64 / 2.0;
                }
            }
        }
        let mut tilt_c = 0.0;
        for y in lay.tilt_bar.y0..lay.tilt_bar.y1 {
            for x in lay.tilt_bar.x0..lay.tilt_bar.x1 {
                if *img.get_pixel(x as u32, y as u32) == TILT_COLOUR {
                    tilt_c += y as f64 - (lay.tilt_bar.y0 + lay.tilt_bar.y1) as f64 / 2.0;
                }
            }
        }
        // No bar colour anywhere else.
        assert_eq!(
            count(
                &img,
                Rect::new(0, 0, img.width() as i64, img.height() as i64),
                PAN_COLOUR
            ),
            pan_n
        );
        assert_eq!(
            count(
                &img,
                Rect::new(0, 0, img.width() as i64, img.height() as i64),
                TILT_COLOUR
            ),
            tilt_n
        );
        (pan_n, tilt_n, pan_c, tilt_c)
    };
    let (p0, t0, _, _) = bar_pixels(0.0, 0.0);
    assert_eq!((p0, t0), (0, 0));
    let (p10, t10, pc10, tc10) = bar_pixels(10.0, 10.0);
    let (p45, t45, pc45, tc45) = bar_pixels(45.0, 45.0);
    let (p90, t90, _, _) = bar_pixels(90.0, 90.0);
    let (p120, t120, _, _) = bar_pixels(120.0, 120.0);
    assert!(0 < p10 && p10 < p45 && p45 < p90 && p90 == p120);
    assert!(0 < t10 && t10 < t45 && t45 < t90 && t90 == t120);
    // Length proportional to the angle (within a pixel row or column).
    assert!((p45 as f64 / p90 as f64 - 0.5).abs() < 0.02);
    assert!((t45 as f64 / t90 as f64 - 0.5).abs() < 0.02);
    // Positive pan turns the front left, positive tilt turns it down.
    assert!(pc10 < 0.0 && pc45 < 0.0 && tc10 > 0.0 && tc45 > 0.0);
    let (pm, tm, pcm, tcm) = bar_pixels(-45.0, -45.0);
    assert_eq!((pm, tm), (p45, t45));
    assert!(pcm > 0.0 && tcm < 0.0);
    // Non-finite angles draw no bar rather than panicking.
    let (pn, tn, _, _) = bar_pixels(f64::NAN, f64::INFINITY);
    assert_eq!((pn, tn), (0, 0));
}

#[test]
fn text_renders_inside_its_box_and_differs_between_digits() {
    let white = Rgb([255, 255, 255]);
    let mut seen = Vec::new();
    for d in [
        '0', '1', '2', '3', '4', '5', '6', '7', '8', '9', '-', '.', ':',
    ] {
        let text = format!("a{d}Z");
        let (w, h) = text_size(&text, 2);
        let mut img = RgbImage::new(w + 20, h + 20);
        draw_text(&mut img, 10, 10, &text, white, 2);
        let mut on = 0;
        for (x, y, p) in img.enumerate_pixels() {
            if *p == white {
                on += 1;
                assert!(
                    x >= 10 && x < 10 + w && y >= 10 && y < 10 + h,
                    "{d} at ({x},{y})"
                );
            }
        }
        assert!(on > 0);
        assert!(!seen.contains(&img), "{d} looks like an earlier character");
        seen.push(img);
    }
    // The rendered frame's text panel shows the numbers: different angles, different pixels.
    let src = frame(128, 96);
    let e = Ellipse::new(64.0, 48.0, 15.0, 20.0);
    let a = render_overlay(&src, &overlay(e, [12.3, -4.0, 1.2], false), 3);
    let b = render_overlay(&src, &overlay(e, [12.3, -4.0, 7.2], false), 3);
    let lay = layout(128, 96, 3, &overlay(e, [12.3, -4.0, 1.2], false));
    // 128x96 at scale 3 leaves room for the widest angles at font size 2 on two lines.
    assert_eq!(
        lay.lines,
        ["#12  score 0.87", "tilt 12.3 pan -4.0", "roll 1.2"]
    );
    assert!(lay.text_px >= 2, "text too small to read at 128x96");
    let diff: Vec<(u32, u32)> = a
        .enumerate_pixels()
        .filter(|(x, y, p)| *p != b.get_pixel(*x, *y))
        .map(|(x, y, _)| (x, y))
        .collect();
    assert!(!diff.is_empty());
    assert!(
        diff.iter()
            .all(|&(x, y)| lay.text.contains(x as i64, y as i64))
    );
}

/// A video is made of frames of one size, with even sides for H.264 in 4:2:0: the layout must
/// not follow the text (on carphone, 176x144 at scale 2, the frames whose angles needed more
/// characters came out 18 px lower, at a smaller font).
#[test]
fn every_frame_of_a_sequence_renders_at_one_size() {
    let texts = [
        (0, [0.0, 0.0, 0.0], 1.0, false),
        (90, [-12.9, -11.6, -14.7], 0.76, false),
        (9_999_999, [-359.9, -999.9, 720.5], 0.0, true),
        (3, [f64::NAN, 1e300, -0.04], f64::NAN, true),
    ];
    for (w, h) in [
        (8, 6),
        (40, 30),
        (128, 96),
        (160, 120),
        (176, 144),
        (640, 480),
    ] {
        let src = frame(w, h);
        for scale in 0..=4 {
            let sizes: Vec<_> = texts
                .iter()
                .map(|&(frame_index, angles_deg, score, lost)| {
                    let o = Overlay {
                        frame_index,
                        ellipse: Ellipse::new(w as f64 / 2.0, h as f64 / 2.0, 3.0, 2.0),
                        angles_deg,
                        score,
                        lost,
                    };
                    let lay = layout(w, h, scale, &o);
                    let img = render_overlay(&src, &o, scale);
                    assert_eq!(img.dimensions(), (lay.width, lay.height));
                    assert!(
                        lay.width.is_multiple_of(2) && lay.height.is_multiple_of(2),
                        "{w}x{h} at {scale}"
                    );
                    // The text fits a panel of 160 px or more (the head line at the
                    // smallest size is 155), except the absurd angle of 1e300.
                    if angles_deg[1] < 1e300 && lay.text.x1 >= 160 {
                        for line in &lay.lines {
                            let tw = i64::from(text_size(line, lay.text_px).0);
                            assert!(tw <= lay.text.x1 - 2, "{w}x{h} at {scale}: {line}");
                        }
                    }
                    (lay.width, lay.height, lay.text_px, lay.lines.len())
                })
                .collect();
            assert!(
                sizes.iter().all(|s| *s == sizes[0]),
                "{w}x{h} at scale {scale}: {sizes:?}"
            );
        }
    }
    // The size still follows the frame's width: a wide frame gets the larger font and one
    // line of angles.
    let o = overlay(Ellipse::new(64.0, 48.0, 15.0, 20.0), [1.0; 3], false);
    assert_eq!(layout(640, 480, 1, &o).text_px, 3);
    assert_eq!(layout(640, 480, 1, &o).lines.len(), 2);
    assert_eq!(layout(40, 30, 1, &o).text_px, 1);
}

#[test]
fn lost_changes_the_colour_and_adds_a_label() {
    let src = frame(128, 96);
    let e = Ellipse::new(64.0, 48.0, 15.0, 20.0);
    let ok = render_overlay(&src, &overlay(e, [0.0; 3], false), 3);
    let lost = render_overlay(&src, &overlay(e, [0.0; 3], true), 3);
    let lay = layout(128, 96, 3, &overlay(e, [0.0; 3], true));
    assert!(count(&ok, lay.frame, ELLIPSE_OK) > 100);
    assert_eq!(count(&ok, lay.frame, ELLIPSE_LOST), 0);
    assert_eq!(count(&lost, lay.frame, ELLIPSE_OK), 0);
    assert!(count(&lost, lay.frame, ELLIPSE_LOST) > 50);
    assert!(count(&lost, lay.text, ELLIPSE_LOST) > 0, "LOST label");
    assert!(lay.lines[0].ends_with("LOST"));
}

#[test]
fn tiny_and_degenerate_inputs_do_not_panic() {
    let src = frame(8, 6);
    for e in [
        Ellipse::new(4.0, 3.0, 0.0, 0.0),
        Ellipse::new(f64::NAN, 3.0, 2.0, 2.0),
        Ellipse::new(1e12, -1e12, 1e12, 3.0),
        Ellipse::new(4.0, 3.0, 0.2, 0.2),
    ] {
        for s in [0, 1, 4] {
            let o = Overlay {
                frame_index: usize::MAX,
                ellipse: e,
                angles_deg: [f64::NAN, -1e300, 0.0],
                score: f64::NAN,
                lost: true,
            };
            let img = render_overlay(&src, &o, s);
            assert!(img.width() >= 8 * s.max(1) && img.height() > 6 * s.max(1));
        }
    }
    assert_eq!(default_scale(128), 3);
    assert_eq!(default_scale(160), 2);
    assert_eq!(default_scale(320), 1);
    assert_eq!(default_scale(40), 4);
    assert_eq!(default_scale(0), 1);
}

/// A fresh file path in a directory of its own (tests run in parallel).
fn scratch(test: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pftrack-{test}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

#[test]
fn png_round_trip_and_errors() {
    let src = frame(40, 30);
    let o = overlay(Ellipse::new(20.0, 15.0, 8.0, 10.0), [5.0, -5.0, 0.0], false);
    let img = render_overlay(&src, &o, 2);
    let path = scratch("png", "f0001.png");
    write_png(&path, &img).unwrap();
    let back = image::open(&path).unwrap().to_rgb8();
    assert_eq!(back, img);
    // The length counted without a file is the file's.
    let len = std::fs::metadata(&path).unwrap().len();
    assert_eq!(pftrack::output::png_len(&img).unwrap(), len);
    assert!(len > 100, "{len}");
    // No temporary file left behind.
    let leftovers: Vec<_> = std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("partial"))
        .collect();
    assert!(leftovers.is_empty());
    // A missing directory is a typed error, and nothing appears.
    let bad = path.parent().unwrap().join("no/such/dir/f.png");
    assert!(matches!(
        write_png(&bad, &img),
        Err(pftrack::output::OutputError::File(_))
    ));
    assert!(!bad.exists());
    assert!(write_png(Path::new("/"), &img).is_err());
    std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
}

#[test]
fn renders_a_real_frame() {
    let Some(dir) = shared_data::path("girl") else {
        return;
    };
    let src = image::open(dir.join("img/0001.jpg")).unwrap().to_rgb8();
    let boxes = pftrack::io::read_otb_boxes(&dir.join("groundtruth_rect.txt")).unwrap();
    let mut e = Ellipse::from_box(&boxes[0]);
    e.theta = 8f64.to_radians();
    let o = overlay(e, [25.4, -31.0, 8.0], false);
    let img = render_overlay(&src, &o, default_scale(src.width()));
    assert_eq!(img.width(), layout(128, 96, 3, &o).width);
    // PFTRACK_RENDER_SAMPLE=/some/file.png keeps the rendering for a look.
    let keep = std::env::var_os("PFTRACK_RENDER_SAMPLE").map(PathBuf::from);
    let out = keep.clone().unwrap_or_else(|| scratch("girl", "girl.png"));
    write_png(&out, &img).unwrap();
    let lost = Overlay {
        lost: true,
        score: 0.12,
        ..o
    };
    write_png(
        &out.with_extension("lost.png"),
        &render_overlay(&src, &lost, 3),
    )
    .unwrap();
    if keep.is_none() {
        std::fs::remove_dir_all(out.parent().unwrap()).unwrap();
    }
}

/// Text and bars placed at the ends of the coordinate range draw what falls in the image
/// (nothing) instead of overflowing; a font size beyond u32 saturates.
#[test]
fn extreme_placements_do_not_overflow() {
    use pftrack::output::draw::{BarAxis, draw_bar};
    let mut img = frame(16, 12);
    let before = img.clone();
    draw_text(&mut img, i64::MAX - 1, 0, "abc", Rgb([255, 0, 0]), 2);
    draw_text(&mut img, 0, i64::MIN + 1, "abc", Rgb([255, 0, 0]), u32::MAX);
    assert_eq!(img, before);
    assert_eq!(text_size("abc", u32::MAX).1, u32::MAX);
    let all = Rect {
        x0: i64::MIN,
        x1: i64::MAX,
        y0: 0,
        y1: 4,
    };
    draw_bar(
        &mut img,
        all,
        BarAxis::Horizontal,
        0.5,
        Rgb([0, 255, 0]),
        Rgb([9, 9, 9]),
    );
}
