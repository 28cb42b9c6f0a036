//! Angles written in degrees (SPEC section 1: degrees in every file and on the command line,
//! radians inside the code): serde adapters for the settings' angle fields, whose names in a
//! file end in `_deg` (`#[serde(rename = "..._deg", with = "crate::io::degrees::one")]`).
//!
//! A setting is read back as the radians it was written from, bit for bit, wherever a double
//! in degrees maps to them exactly (every default does; about nine in ten of all doubles),
//! and otherwise to within one unit in the last place: so a settings file printed by
//! `pftrack settings` gives the defaults' very track.

use serde::{Deserialize, Deserializer, Serializer};

/// The degrees to write for `rad` radians: of the doubles next to `rad.to_degrees()`, the
/// one whose [`f64::to_radians`] gives `rad` back exactly, where there is one.
pub fn for_file(rad: f64) -> f64 {
    let deg = rad.to_degrees();
    if !deg.is_finite() || deg.to_radians() == rad {
        return deg;
    }
    // Each step is one unit in the last place, outwards from the nearest.
    let step = |x: f64, up: bool| {
        let bits = x.to_bits() as i64;
        // For a negative double the bits order the other way.
        let k = if (x >= 0.0) == up { 1 } else { -1 };
        f64::from_bits((bits + k) as u64)
    };
    let (mut up, mut down) = (deg, deg);
    for _ in 0..4 {
        up = step(up, true);
        down = step(down, false);
        for d in [down, up] {
            if d.to_radians() == rad {
                return d;
            }
        }
    }
    deg
}

/// One angle.
pub mod one {
    use super::*;

    /// Writes radians as degrees.
    pub fn serialize<S: Serializer>(rad: &f64, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(for_file(*rad))
    }

    /// Reads degrees as radians.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(f64::deserialize(d)?.to_radians())
    }
}

/// Three angles, one per camera axis.
pub mod three {
    use super::*;

    /// Writes radians as degrees.
    pub fn serialize<S: Serializer>(rad: &[f64; 3], s: S) -> Result<S::Ok, S::Error> {
        use serde::Serialize;
        rad.map(for_file).serialize(s)
    }

    /// Reads degrees as radians.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
        Ok(<[f64; 3]>::deserialize(d)?.map(f64::to_radians))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn degrees_read_back_as_the_radians_written() {
        // The settings' defaults, and values either side of zero over a turn and beyond.
        let mut exact = 0;
        let mut n = 0;
        let defaults = [0.03, 0.02, 0.05, 0.07, 20f64.to_radians(), 0.0, -0.0];
        let spread = (0..20_000).map(|i| {
            let t = i as f64 * 0.6180339887498949;
            (t.fract() - 0.5) * 14.0 * (1.0 + (i % 7) as f64)
        });
        for (i, rad) in defaults.into_iter().chain(spread).enumerate() {
            let back = for_file(rad).to_radians();
            if i < defaults.len() {
                assert_eq!(back.to_bits(), rad.to_bits(), "default {rad}");
            }
            let ulp = (rad.abs() * f64::EPSILON).max(f64::MIN_POSITIVE);
            assert!((back - rad).abs() <= ulp, "{rad}: {back}");
            exact += usize::from(back == rad);
            n += 1;
        }
        assert!(exact * 10 >= n * 8, "{exact} of {n} exact");
        assert_eq!(for_file(std::f64::consts::PI), 180.0);
        assert!(for_file(f64::NAN).is_nan());
    }
}
