//! Checks that an output does not overwrite an input: `track -o` onto a frame, `--render`
//! into the folder of frames, `pose --draw` onto one of its images.

use std::path::{Path, PathBuf};

use anyhow::bail;

/// `p` made absolute with its links resolved; for a path that does not exist yet, its
/// folder's so resolved, with its name. `None` when not even the folder exists.
fn resolved(p: &Path) -> Option<PathBuf> {
    if let Ok(c) = std::fs::canonicalize(p) {
        return Some(c);
    }
    let name = p.file_name()?;
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::canonicalize(dir).ok().map(|d| d.join(name))
}

/// Whether `a` and `b` name the same file or folder (through links and relative paths).
pub fn same(a: &Path, b: &Path) -> bool {
    matches!((resolved(a), resolved(b)), (Some(x), Some(y)) if x == y)
}

/// Refuses an output `out` (given by `flag`) that is one of `inputs`.
pub fn not_an_input(flag: &str, out: &Path, inputs: &[&Path]) -> anyhow::Result<()> {
    if let Some(i) = inputs.iter().find(|i| same(out, i)) {
        bail!(
            "{flag} {} is an input ({}): it would be overwritten",
            out.display(),
            i.display()
        );
    }
    Ok(())
}

/// Refuses outputs of a track of `input` that would overwrite or join its frames: the pose
/// CSV (`-o`) as the input file itself or as an image in the input folder (it would be read
/// as a frame), and the rendered frames (`--render`) into the input folder.
pub fn track_outputs(
    input: &Path,
    out: Option<&Path>,
    render: Option<&Path>,
) -> anyhow::Result<()> {
    if let Some(o) = out {
        not_an_input("--out", o, &[input])?;
        let in_folder = o.parent().is_some_and(|d| {
            same(
                if d.as_os_str().is_empty() {
                    Path::new(".")
                } else {
                    d
                },
                input,
            )
        });
        if in_folder && pftrack::frames::dir::is_image_file(o) {
            bail!(
                "--out {} is an image in the input folder {}: it would be read as a frame",
                o.display(),
                input.display()
            );
        }
    }
    if let Some(r) = render
        && same(r, input)
    {
        bail!(
            "--render {} is the input folder: its frames would be overwritten",
            r.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inputs_are_found_through_other_spellings() {
        let d = std::env::temp_dir().join(format!("pftrack-paths-{}", std::process::id()));
        std::fs::create_dir_all(d.join("frames")).unwrap();
        std::fs::write(d.join("frames/00000.png"), b"x").unwrap();
        let frames = d.join("frames");
        assert!(same(
            &d.join("frames/../frames/00000.png"),
            &frames.join("00000.png")
        ));
        assert!(!same(
            &d.join("frames/00001.png"),
            &frames.join("00000.png")
        ));
        assert!(track_outputs(&frames, Some(&frames.join("00000.png")), None).is_err());
        assert!(track_outputs(&frames, Some(&frames.join("new.png")), None).is_err());
        assert!(track_outputs(&frames, Some(&frames.join("poses.csv")), None).is_ok());
        assert!(track_outputs(&frames, None, Some(&d.join("frames/."))).is_err());
        assert!(track_outputs(&frames, None, Some(&d.join("render"))).is_ok());
        let video = frames.join("00000.png");
        assert!(track_outputs(&video, Some(&video), None).is_err());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
