//! Mutated inputs (bytes changed, cut out, repeated, and words such as `nan`, `1e309` or
//! `FRAME` put in) through the parsers of the files a user hands over and through the
//! tracker's settings: each is refused with an error or read, never a panic, and a tracker
//! that accepts its settings gives finite estimates. A fixed seed, so a failure repeats.

use std::io::Cursor;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use pftrack::frames::{FrameSource, SourceOptions};
use pftrack::geometry::{Ellipse, Euler};
use pftrack::synth::{Renderer, Scenario, SynthConfig};
use pftrack::tracker::{Init, Tracker, TrackerConfig};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Words put into the inputs.
const WORDS: &[&str] = &[
    "-",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e309",
    "0",
    "-0",
    ",",
    "\n",
    "\r\n",
    "\t",
    " ",
    "1e-320",
    "99999999999999999999",
    "4294967296",
    "18446744073709551616",
    "#",
    "hfov",
    "W",
    "H",
    "F",
    "C",
    "FRAME",
    "x",
    "I",
    "A",
    "0:0",
    "1:0",
    "444",
    "420",
    "mono",
    "\u{0}",
    "é",
    ";",
    "e",
];

/// `seed` with one to four random edits.
fn mutate(rng: &mut StdRng, seed: &[u8]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..rng.random_range(1..5) {
        let n = v.len();
        match rng.random_range(0..5) {
            0 if n > 0 => {
                let i = rng.random_range(0..n);
                v[i] = rng.random();
            }
            1 if n > 0 => {
                let i = rng.random_range(0..n);
                let j = rng.random_range(i..=n.min(i + 8));
                v.drain(i..j);
            }
            2 => {
                let i = rng.random_range(0..=n);
                let w = WORDS[rng.random_range(0..WORDS.len())];
                v.splice(i..i, w.bytes());
            }
            3 if n > 0 => {
                let i = rng.random_range(0..n);
                let j = rng.random_range(i..=n.min(i + 16));
                let chunk = v[i..j].to_vec();
                let k = rng.random_range(0..=n);
                v.splice(k..k, chunk);
            }
            _ => {
                let i = rng.random_range(0..=n);
                v.insert(i, b"0123456789.-,e"[rng.random_range(0..14)]);
            }
        }
    }
    v
}

/// Some of the settings' numbers set to extremes, switches flipped, absent parts given
/// (the particle count kept small, so that a run stays short).
fn mutate_json(rng: &mut StdRng, v: &mut serde_json::Value) {
    use serde_json::Value;
    match v {
        Value::Object(m) => {
            for (k, x) in m.iter_mut() {
                if k == "particles" {
                    if rng.random_bool(0.1) {
                        *x = serde_json::json!([0, 1, 2, 3, 5, 50][rng.random_range(0..6)]);
                    }
                    continue;
                }
                mutate_json(rng, x);
            }
        }
        Value::Array(a) => a.iter_mut().for_each(|x| mutate_json(rng, x)),
        // A whole number stays one (a float there would only be refused as JSON).
        Value::Number(n) if n.is_u64() && rng.random_bool(0.03) => {
            let c = [0u64, 1, 2, 3, 7, 100, 1 << 20, 1 << 32, u64::MAX];
            *v = serde_json::json!(c[rng.random_range(0..c.len())]);
        }
        Value::Number(_) if rng.random_bool(0.03) => {
            let c = [
                0.0, -1.0, 1e308, -1e308, 1e-300, 0.5, 2.0, 1e6, 1e9, 3.0, 100.0,
            ];
            *v = serde_json::json!(c[rng.random_range(0..c.len())]);
        }
        Value::Bool(b) if rng.random_bool(0.1) => *b = !*b,
        Value::Null if rng.random_bool(0.05) => *v = serde_json::json!({}),
        _ => {}
    }
}

/// The panic's message, for the report.
fn message(e: &(dyn std::any::Any + Send)) -> String {
    e.downcast_ref::<String>()
        .cloned()
        .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_default()
}

#[test]
fn mutated_init_pose_and_box_files_are_read_or_refused() {
    let mut rng = StdRng::seed_from_u64(7);
    let p = Path::new("mutated");
    let seeds: [(&str, &[u8]); 4] = [
        ("init", b"12.5,30,10,14\nhfov,50\n"),
        ("init", b"12.5,30,10,14,20\n"),
        (
            "pose",
            b"frame,cx,cy,a,b,rx,ry,rz,score,lost\n0,10.5,20,5,6,1,2,3,0.9,0\n1,11,21,5,6,1.5,2,3,0.8,1\n",
        ),
        ("otb", b"1\t2\t30\t40\r\n5,6,7,8\r\n0,0,0,0\n"),
    ];
    let mut read = [0; 3];
    for k in 0..40_000 {
        let (kind, seed) = seeds[k % seeds.len()];
        let input = mutate(&mut rng, seed);
        let text = String::from_utf8_lossy(&input).into_owned();
        let r = catch_unwind(|| match kind {
            "init" => pftrack::io::init::parse_init(&text, p).is_ok(),
            "pose" => pftrack::io::pose_csv::parse_pose_csv(&text, p).is_ok(),
            _ => pftrack::io::boxes::parse_otb_boxes(&text, p).is_ok(),
        });
        match r {
            Ok(ok) => read[(k % seeds.len()).saturating_sub(1)] += usize::from(ok),
            Err(e) => panic!("{kind} {text:?}: {}", message(&*e)),
        }
    }
    // Some of each kind are still files of their kind.
    assert!(read.iter().all(|&n| n > 500), "{read:?}");
}

#[test]
fn mutated_y4m_streams_are_read_or_refused() {
    let mut seeds: Vec<Vec<u8>> = Vec::new();
    for (hdr, bytes) in [
        ("YUV4MPEG2 W4 H4 F25:1 Ip A1:1 C420jpeg\n", 24),
        ("YUV4MPEG2 W4 H2 F25:1 C444\n", 24),
        ("YUV4MPEG2 W3 H3 Cmono\n", 9),
        ("YUV4MPEG2 W4 H4 C422p10\n", 64),
    ] {
        let mut s = hdr.as_bytes().to_vec();
        for f in 0..3u8 {
            s.extend_from_slice(b"FRAME\n");
            s.extend((0..bytes).map(|i| (i as u8).wrapping_mul(7).wrapping_add(f * 40)));
        }
        seeds.push(s);
    }
    let mut rng = StdRng::seed_from_u64(8);
    let mut frames = 0;
    for k in 0..20_000 {
        let input = mutate(&mut rng, &seeds[k % seeds.len()]);
        let data = input.clone();
        let r = catch_unwind(move || {
            let opts = SourceOptions::default();
            let Ok(src) = FrameSource::from_y4m_reader(Box::new(Cursor::new(data)), "m", &opts)
            else {
                return 0;
            };
            src.take(10).take_while(|f| f.is_ok()).count()
        });
        match r {
            Ok(n) => frames += n,
            Err(e) => panic!("{:?}: {}", String::from_utf8_lossy(&input), message(&*e)),
        }
    }
    assert!(frames > 5000, "{frames}");
}

#[test]
fn mutated_settings_are_refused_or_track_finitely() {
    let cfg = SynthConfig {
        scenario: Scenario::Nod,
        frames: 4,
        width: 80,
        height: 60,
        seed: 1,
    };
    let r = Renderer::new(&cfg).unwrap();
    let frames: Vec<_> = (0..4).map(|k| r.render(k)).collect();
    let s0 = frames[0].1;
    let init = Init {
        ellipse: Ellipse::new(s0.cx, s0.cy, s0.a, s0.b),
        pose: Euler::default(),
    };
    let base = serde_json::to_value(TrackerConfig::default()).unwrap();
    let mut rng = StdRng::seed_from_u64(9);
    let mut started = 0;
    for _ in 0..400 {
        let mut v = base.clone();
        mutate_json(&mut rng, &mut v);
        let text = v.to_string();
        let Ok(tc) = serde_json::from_value::<TrackerConfig>(v) else {
            continue;
        };
        let res = catch_unwind(AssertUnwindSafe(|| {
            let Ok(mut t) = Tracker::new(tc, &frames[0].0, init) else {
                return false;
            };
            for (img, _) in &frames[1..] {
                let est = t.step(img).unwrap_or_else(|e| panic!("step: {e}"));
                let s = est.state;
                let all = [s.cx, s.cy, s.a, s.b, s.rx, s.ry, s.rz, est.confidence];
                assert!(all.iter().all(|x| x.is_finite()), "{est:?}");
            }
            true
        }));
        match res {
            Ok(s) => started += usize::from(s),
            Err(e) => panic!("{text}: {}", message(&*e)),
        }
    }
    assert!(started > 30, "{started}");
}
