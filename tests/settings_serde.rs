//! The tracker's settings, starts and estimates go through serde (here JSON) and come back
//! the same; a partial file fills the rest with the defaults, a misspelt name is refused.

use pftrack::geometry::{Ellipse, Euler};
use pftrack::synth::{Renderer, Scenario, SynthConfig};
use pftrack::tracker::{Estimate, Init, Mode, Tracker, TrackerConfig};

#[test]
fn the_default_configuration_round_trips() {
    let cfg = TrackerConfig::default();
    let text = serde_json::to_string_pretty(&cfg).unwrap();
    let back: TrackerConfig = serde_json::from_str(&text).unwrap();
    assert_eq!(back, cfg);
    // Every optional part is written, so a file shows what is on.
    for key in [
        "\"bundle\"",
        "\"template\"",
        "\"camera_hfov_deg\": null",
        "\"relief_sigma\": null",
        "\"mode\": \"sea\"",
    ] {
        assert!(text.contains(key), "{key} missing from {text}");
    }
}

#[test]
fn a_partial_configuration_takes_the_defaults_for_the_rest() {
    let text = r#"{
        "seed": 7,
        "mode": "tpe",
        "filter": { "particles": 500 },
        "bundle": null,
        "camera_hfov_deg": 50.0
    }"#;
    let cfg: TrackerConfig = serde_json::from_str(text).unwrap();
    let mut want = TrackerConfig {
        seed: 7,
        mode: Mode::Tpe,
        bundle: None,
        camera_hfov_deg: Some(50.0),
        ..TrackerConfig::default()
    };
    want.filter.particles = 500;
    assert_eq!(cfg, want);
    assert!(cfg.check().is_ok());
    // The relief factor of the keyframes' adjustment, off by default, read from a file; the
    // rest of a part given in part takes serde's defaults for that part (`BundleParams`'s own
    // rotation σ here: the CLI's --config lays a file over the tracker's defaults field by
    // field instead).
    let relief: TrackerConfig =
        serde_json::from_str(r#"{"bundle": {"params": {"relief_sigma": 1.0}}}"#).unwrap();
    let mut want = TrackerConfig::default();
    if let Some(b) = want.bundle.as_mut() {
        b.params = pftrack::pose::bundle::BundleParams {
            relief_sigma: Some(1.0),
            ..Default::default()
        };
    }
    assert_eq!(relief, want);
    assert!(relief.check().is_ok());
    // Read values are still checked before a tracker is built from them, the object model's
    // depth and the edge threshold whatever terms are on (1e30 made every confidence 0).
    for (text, named) in [
        (r#"{"filter": {"particles": 0}}"#, "particles 0"),
        (r#"{"likelihood": {"depth_ratio": 1e30}}"#, "depth_ratio"),
        (
            r#"{"likelihood": {"depth_ratio": -100, "terms": 3}}"#,
            "depth_ratio",
        ),
        (
            r#"{"likelihood": {"edge_threshold": -50}}"#,
            "edge_threshold",
        ),
        (r#"{"likelihood": {"edge_threshold": 2}}"#, "edge_threshold"),
        (r#"{"bundle": {"params": {"relief_sigma": 0}}}"#, "relief 0"),
        (
            r#"{"bundle": {"params": {"relief_sigma": 1e200}}}"#,
            "from 0.001 to 1000",
        ),
    ] {
        let bad: TrackerConfig = serde_json::from_str(text).unwrap();
        let err = bad.check().unwrap_err().to_string();
        assert!(err.contains(named), "{text}: {err}");
    }
}

/// A mode's name is read in any case, as the command line reads it, and written lowercase.
#[test]
fn a_mode_is_read_in_any_case() {
    for (text, mode) in [
        (r#"{"mode": "TPE"}"#, Mode::Tpe),
        (r#"{"mode": "Optimal"}"#, Mode::Optimal),
        (r#"{"mode": "rls"}"#, Mode::Rls),
        (r#"{"mode": "SeA"}"#, Mode::Sea),
    ] {
        let cfg: TrackerConfig = serde_json::from_str(text).unwrap();
        assert_eq!(cfg.mode, mode, "{text}");
    }
    let written = serde_json::to_string(&Mode::Tpe).unwrap();
    assert_eq!(written, "\"tpe\"");
    // A name in an escaped string (not borrowed from the input) is read too.
    let cfg: TrackerConfig = serde_json::from_str(r#"{"mode": "\u0074pe"}"#).unwrap();
    assert_eq!(cfg.mode, Mode::Tpe);
}

#[test]
fn a_misspelt_or_mistyped_setting_is_refused_by_name() {
    for (text, named) in [
        (r#"{"sead": 7}"#, "sead"),
        (r#"{"filter": {"particle": 500}}"#, "particle"),
        (
            r#"{"mode": "fast"}"#,
            "unknown variant `fast`, expected one of `sea`",
        ),
        (r#"{"seed": "seven"}"#, "seven"),
    ] {
        let err = serde_json::from_str::<TrackerConfig>(text).unwrap_err();
        assert!(err.to_string().contains(named), "{text}: {err}");
    }
}

#[test]
fn starts_and_estimates_round_trip() {
    let init = Init {
        ellipse: Ellipse {
            theta: 0.25,
            ..Ellipse::new(80.0, 60.0, 20.0, 24.0)
        },
        pose: Euler::new(0.1, -0.2, 0.05),
    };
    let back: Init = serde_json::from_str(&serde_json::to_string(&init).unwrap()).unwrap();
    assert_eq!(back, init);
    // The pose and the ellipse's angle may be left out: a frontal, unturned start.
    let short: Init =
        serde_json::from_str(r#"{"ellipse": {"cx": 80, "cy": 60, "a": 20, "b": 24}}"#).unwrap();
    assert_eq!(short, Init::frontal(Ellipse::new(80.0, 60.0, 20.0, 24.0)));
    // But not a semi-axis.
    assert!(serde_json::from_str::<Init>(r#"{"ellipse": {"cx": 80, "cy": 60, "a": 20}}"#).is_err());

    let r = Renderer::new(&SynthConfig::new(Scenario::Nod)).unwrap();
    let mut t = Tracker::new(
        TrackerConfig::default(),
        &r.render(0).0,
        Init::frontal(r.init_ellipse()),
    )
    .unwrap();
    let est = t.step(&r.render(1).0).unwrap();
    let back: Estimate = serde_json::from_str(&serde_json::to_string(&est).unwrap()).unwrap();
    assert_eq!(back, est);
}
