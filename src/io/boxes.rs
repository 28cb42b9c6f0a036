//! OTB-style ground-truth boxes: one `x,y,w,h` per frame, separated by commas, tabs or spaces,
//! CRLF or LF line ends (as in `../shared/data`).
//!
//! OTB boxes are 1-based: the box covers pixels `x ..= x + w - 1` in 1-based indices. In the
//! project's convention (origin at the centre of the top-left pixel) those pixel centres are
//! `x - 1 ..= x + w - 2`, so the box's edges are at `x - 1.5` and `x + w - 1.5`:
//! [`otb_to_pixel`] shifts by `-1.5` and keeps the size.

use std::path::Path;

use super::{FormatError, parse_f64};
use crate::geometry::BoxRect;

/// Converts a 1-based OTB box to the project's pixel convention.
pub fn otb_to_pixel(x: f64, y: f64, w: f64, h: f64) -> BoxRect {
    BoxRect::new(x - 1.5, y - 1.5, w, h)
}

/// Converts a box in the project's pixel convention back to OTB's 1-based form.
pub fn pixel_to_otb(b: &BoxRect) -> [f64; 4] {
    [b.x + 1.5, b.y + 1.5, b.w, b.h]
}

/// Reads an OTB box file, converting every box with [`otb_to_pixel`]. Blank lines before the
/// first box and after the last are ignored; one between boxes is an error, since the box of
/// line k is frame k's and a skipped line would move every later box onto the wrong frame.
/// Any other line must hold exactly four finite numbers.
pub fn read_otb_boxes(path: &Path) -> Result<Vec<BoxRect>, FormatError> {
    let text = super::read_text(path).map_err(|e| FormatError::io(path, e))?;
    parse_otb_boxes(&text, path)
}

/// Parses the text of an OTB box file; `path` only names the source in errors.
pub fn parse_otb_boxes(text: &str, path: &Path) -> Result<Vec<BoxRect>, FormatError> {
    let mut out = Vec::new();
    let mut blank_after_box = None;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() {
            if !out.is_empty() && blank_after_box.is_none() {
                blank_after_box = Some(i + 1);
            }
            continue;
        }
        if let Some(at) = blank_after_box {
            return Err(FormatError::parse(
                path,
                at,
                format!(
                    "a blank line after box {}: the boxes are one per frame, so every \
                     frame before the last needs its box",
                    out.len()
                ),
            ));
        }
        // Commas, tabs or spaces between the values; a comma at the end is passed over, but
        // an empty field between two commas (`25,,18,14`) is a value missing, not a
        // separator twice.
        let mut parts: Vec<&str> = line.split(',').map(str::trim).collect();
        if parts.len() > 1 && parts.last() == Some(&"") {
            parts.pop();
        }
        if parts.iter().any(|p| p.is_empty()) {
            return Err(FormatError::parse(
                path,
                i + 1,
                format!("an empty field in '{line}'"),
            ));
        }
        let f: Vec<&str> = parts.iter().flat_map(|p| p.split_whitespace()).collect();
        if f.len() != 4 {
            return Err(FormatError::parse(
                path,
                i + 1,
                format!("expected x,y,w,h, found '{line}'"),
            ));
        }
        let mut v = [0.0; 4];
        for (k, name) in ["x", "y", "w", "h"].iter().enumerate() {
            v[k] = parse_f64(f[k], name).map_err(|m| FormatError::parse(path, i + 1, m))?;
        }
        // A zero size is how some OTB sequences mark a frame without the target; a negative
        // one is no box.
        if let Some((name, x)) = [("w", v[2]), ("h", v[3])]
            .into_iter()
            .find(|(_, x)| *x < 0.0)
        {
            return Err(FormatError::parse(
                path,
                i + 1,
                format!("{name} {x} is negative"),
            ));
        }
        out.push(otb_to_pixel(v[0], v[1], v[2], v[3]));
    }
    if out.is_empty() {
        return Err(FormatError::Empty {
            path: path.display().to_string(),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tabs_commas_crlf() {
        let b = parse_otb_boxes("57\t21\t31\t45\r\n58\t22\t31\t45\r\n", Path::new("g")).unwrap();
        assert_eq!(b.len(), 2);
        assert_eq!(b[0], BoxRect::new(55.5, 19.5, 31.0, 45.0));
        let c = parse_otb_boxes("70,202,83,36\r\n\r\n", Path::new("c")).unwrap();
        assert_eq!(pixel_to_otb(&c[0]), [70.0, 202.0, 83.0, 36.0]);
        assert!(parse_otb_boxes("1,2,3\n", Path::new("x")).is_err());
        assert!(parse_otb_boxes("1,2,3,x\n", Path::new("x")).is_err());
        assert!(parse_otb_boxes("\n\n", Path::new("x")).is_err());
        // Blank lines before and after the boxes are fine; between them, each later box
        // would be read as the frame before its own.
        let b = parse_otb_boxes("\n1,2,3,4\n5,6,7,8\n\n\n", Path::new("x")).unwrap();
        assert_eq!(b.len(), 2);
        let e = parse_otb_boxes("1,2,3,4\r\n\r\n5,6,7,8\r\n", Path::new("gap.txt"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("gap.txt:2") && e.contains("after box 1"), "{e}");
        let e = parse_otb_boxes("1,2,3,4\n60,40,-40,50\n", Path::new("n")).unwrap_err();
        assert_eq!(e.to_string(), "n:2: w -40 is negative");
        assert!(parse_otb_boxes("0,0,0,0\n", Path::new("z")).is_ok());
        // A trailing comma and spaces beside commas are fine; an empty field is not.
        let b = parse_otb_boxes("1, 2, 3, 4,\n5 ,6,7,8\n", Path::new("x")).unwrap();
        assert_eq!(pixel_to_otb(&b[1]), [5.0, 6.0, 7.0, 8.0]);
        let e = parse_otb_boxes("25,,18,14,18\n", Path::new("e")).unwrap_err();
        assert_eq!(e.to_string(), "e:1: an empty field in '25,,18,14,18'");
        assert!(parse_otb_boxes(",1,2,3,4\n", Path::new("e")).is_err());
        assert!(parse_otb_boxes("1,2,3,4,,\n", Path::new("e")).is_err());
    }
}
