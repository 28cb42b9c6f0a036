//! clap's checks of the values the commands take as text (lists of numbers, names from a
//! fixed set, sizes): a malformed value is a usage error, exit status 2, reported by clap
//! with the flag, as for an unknown option. A name comes back as what it names; the others
//! return the text they checked, which the command reads with the same rules.

use pftrack::pose::SolverKind;
use pftrack::synth::Scenario;
use pftrack::tracker::Mode;

/// `s` as comma-separated finite numbers, as many as one of `counts`.
pub fn numbers(s: &str, counts: &[usize]) -> Result<Vec<f64>, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not a list of numbers"))?;
    if !counts.contains(&v.len()) || v.iter().any(|x| !x.is_finite()) {
        let counts: Vec<String> = counts.iter().map(|k| k.to_string()).collect();
        return Err(format!(
            "expected {} finite numbers, got '{s}'",
            counts.join(" or ")
        ));
    }
    Ok(v)
}

/// Three numbers (`--init-pose`).
pub fn three(s: &str) -> Result<String, String> {
    numbers(s, &[3]).map(|_| s.to_string())
}

/// Four numbers (`--init-box`).
pub fn four(s: &str) -> Result<String, String> {
    numbers(s, &[4]).map(|_| s.to_string())
}

/// Four or five numbers (an ellipse with its optional angle).
pub fn four_or_five(s: &str) -> Result<String, String> {
    numbers(s, &[4, 5]).map(|_| s.to_string())
}

/// Points `x1,y1;x2,y2;...` (`--init-points`; how many are needed is the fit's to say).
pub fn points(s: &str) -> Result<String, String> {
    for p in s.split(';').filter(|t| !t.trim().is_empty()) {
        numbers(p, &[2])?;
    }
    Ok(s.to_string())
}

/// A tracker mode (`--mode`).
pub fn mode(s: &str) -> Result<Mode, String> {
    Mode::from_name(s).ok_or_else(|| "expected sea, optimal, tpe or rls".to_string())
}

/// A rotation solver of `pose` (`--solver`): the block solvers or `essential`.
pub fn solver(s: &str) -> Result<String, String> {
    if s.eq_ignore_ascii_case("essential") || SolverKind::from_name(s).is_ok() {
        Ok(s.to_string())
    } else {
        Err("expected sea, optimal, lsm, rls or essential".to_string())
    }
}

/// A synthetic scenario (`--scenario`).
pub fn scenario(s: &str) -> Result<Scenario, String> {
    Scenario::from_name(s).map_err(|e| e.to_string())
}

/// A frame size `WxH` as a source resizes to (`--resize`).
pub fn size(s: &str) -> Result<String, String> {
    pftrack::frames::parse_size(s)
        .map(|_| s.to_string())
        .map_err(|e| e.to_string())
}

/// A synthetic frame size `WxH` (`synth --size`), each side in `synth::MIN_SIDE..=MAX_SIDE`.
pub fn synth_size(s: &str) -> Result<String, String> {
    pftrack::synth::parse_size(s)
        .map(|_| s.to_string())
        .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_are_checked() {
        assert_eq!(numbers(" 1, -2.5,3 ", &[3]), Ok(vec![1.0, -2.5, 3.0]));
        assert!(numbers("1,2", &[3]).unwrap_err().contains("expected 3"));
        assert!(numbers("1,2,inf", &[3]).is_err());
        assert!(numbers("1,x,3", &[3]).unwrap_err().contains("not a list"));
        assert!(four_or_five("1,2,3,4,5").is_ok() && four_or_five("1,2,3").is_err());
        assert!(points("1,2;3,4;").is_ok() && points("1,2;3").is_err());
        assert_eq!(mode("TPE"), Ok(Mode::Tpe));
        assert!(mode("foo").is_err());
        assert!(solver("essential").is_ok() && solver("lsm").is_ok() && solver("x").is_err());
        assert_eq!(scenario("car"), Ok(Scenario::Car));
        assert!(scenario("spin").unwrap_err().contains("nod, pan"));
        assert!(size("80x60").is_ok() && size("80").is_err());
    }
}
