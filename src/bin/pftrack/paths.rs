//! Checks that an output does not overwrite an input: `track -o` onto a frame, `--render`
//! into the folder of frames, `pose --draw` onto one of its images.

use std::path::{Path, PathBuf};

use anyhow::bail;

/// `p` made absolute with its links resolved; for a path that does not exist yet, its
/// folder's so resolved, with its name (a link to nothing yet followed to the name it gives,
/// where a writer through it puts the file). `None` when not even the folder exists.
fn resolved(p: &Path) -> Option<PathBuf> {
    if let Ok(c) = std::fs::canonicalize(p) {
        return Some(c);
    }
    let p = pftrack::io::atomic::resolve_links(p).ok()?;
    let name = p.file_name()?;
    let dir = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::canonicalize(dir).ok().map(|d| d.join(name))
}

/// `p` made absolute with the links of its longest existing part resolved and the rest
/// appended (`.` dropped, `..` taking off the part before): where a file will be, in folders
/// that may not exist yet. `None` only when the working folder cannot be read.
fn resolved_ahead(p: &Path) -> Option<PathBuf> {
    let abs = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir().ok()?.join(p)
    };
    let mut base = abs.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(mut out) = std::fs::canonicalize(base) {
            for c in rest.iter().rev() {
                match c {
                    std::path::Component::ParentDir => {
                        out.pop();
                    }
                    std::path::Component::Normal(n) => out.push(n),
                    _ => {}
                }
            }
            return Some(out);
        }
        rest.push(base.components().next_back()?);
        base = base.parent()?;
    }
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

/// Refuses an image output (given by `flag`) whose name does not end in `.png`, the one
/// format it is written in: a `.jpg` name holding PNG data would mislead what opens it.
pub fn png_name(flag: &str, path: &Path) -> anyhow::Result<()> {
    if !path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        bail!(
            "{flag} {}: the image is a PNG; give a .png name",
            path.display()
        );
    }
    Ok(())
}

/// The folder whose images a track of `input` reads: the input itself when it is a folder,
/// the folder of an input image, `None` for a video or a stream.
fn frames_folder(input: &Path) -> Option<PathBuf> {
    if input.is_dir() {
        resolved(input)
    } else if pftrack::frames::dir::is_image_file(input) {
        resolved(input).and_then(|p| p.parent().map(Path::to_path_buf))
    } else {
        None
    }
}

/// Refuses outputs of a track of `input` (with the init or truth files it reads, `others`)
/// that would overwrite or join what it reads: the pose CSV (`-o`) as any of them, or as an
/// image in the frames' folder (it would be read as a frame), however it is spelled or
/// linked; the rendered frames (`--render`) into the frames' folder. Nor may the two outputs
/// clash: the pose CSV under a name the render writes or trims in its folder (a frame's,
/// `NNNNN.png`, or its mark).
pub fn track_outputs(
    input: &Path,
    others: &[&Path],
    out: Option<&Path>,
    render: Option<&Path>,
) -> anyhow::Result<()> {
    let folder = frames_folder(input);
    if let (Some(o), Some(r)) = (out, render)
        && same(o, r)
    {
        bail!(
            "--out and --render both name {}: the poses and the rendered frames need places of their own",
            o.display()
        );
    }
    if let (Some(o), Some(r)) = (out, render)
        && let (Some(real), Some(folder)) = (resolved_ahead(o), resolved_ahead(r))
        && real.parent() == Some(folder.as_path())
        && real
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| crate::track::is_frame_name(n) || n == crate::track::RENDER_MARK)
    {
        bail!(
            "--out {} is a name the render writes or removes in {}: give the poses another \
             name or place",
            o.display(),
            r.display()
        );
    }
    if let Some(o) = out {
        let mut inputs = vec![input];
        inputs.extend(others);
        not_an_input("--out", o, &inputs)?;
        // Where the file will land: through a link, the file it names.
        let real = resolved(o);
        let image = pftrack::frames::dir::is_image_file(o)
            || real
                .as_deref()
                .is_some_and(pftrack::frames::dir::is_image_file);
        if let (Some(real), Some(folder)) = (&real, &folder)
            && real.parent() == Some(folder.as_path())
            && image
        {
            bail!(
                "--out {} is an image in the input folder {}: it would be read as a frame",
                o.display(),
                folder.display()
            );
        }
    }
    if let (Some(r), Some(folder)) = (render, &folder)
        && resolved(r).as_ref() == Some(folder)
    {
        bail!(
            "--render {} is the input folder: its frames would be overwritten",
            r.display()
        );
    }
    Ok(())
}

/// The room left on a file system to an unprivileged writer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Room {
    /// Bytes free.
    pub bytes: u64,
    /// The size of the blocks files take their space in (at least 1).
    pub block: u64,
    /// Files that can still be made, where the file system counts them.
    pub files: Option<u64>,
}

/// The room on the file system that `p` will be written to (its nearest existing folder's,
/// through links); `None` where that cannot be read (or off Unix).
pub fn room(p: &Path) -> Option<Room> {
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let at = resolved_ahead(p)?;
        let existing = at.ancestors().find(|a| a.is_dir())?;
        let name = std::ffi::CString::new(existing.as_os_str().as_bytes()).ok()?;
        // SAFETY: `name` is a NUL-terminated path, and `stat` a plain struct statvfs fills.
        let stat = unsafe {
            let mut stat: libc::statvfs = std::mem::zeroed();
            (libc::statvfs(name.as_ptr(), &mut stat) == 0).then_some(stat)?
        };
        // The fields' widths differ between platforms (u32 on some 32-bit ones).
        #[allow(clippy::useless_conversion)]
        let (blocks, size, files, favail) = (
            u64::from(stat.f_bavail),
            u64::from(stat.f_frsize),
            u64::from(stat.f_files),
            u64::from(stat.f_favail),
        );
        Some(Room {
            bytes: blocks.saturating_mul(size),
            block: size.max(1),
            // A file system that keeps no count of files gives 0 for all of them.
            files: (files > 0).then_some(favail),
        })
    }
    #[cfg(not(unix))]
    {
        let _ = p;
        None
    }
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
        let first = frames.join("00000.png");
        let out = |o: &Path| track_outputs(&frames, &[], Some(o), None);
        assert!(out(&first).is_err());
        assert!(out(&frames.join("new.png")).is_err());
        assert!(out(&frames.join("poses.csv")).is_ok());
        assert!(track_outputs(&frames, &[], None, Some(&d.join("frames/."))).is_err());
        assert!(track_outputs(&frames, &[], None, Some(&d.join("render"))).is_ok());
        // The poses under a rendered frame's name or the render's mark, however spelled;
        // another name in the render folder is fine.
        let render = d.join("render");
        let both = |o: &Path| track_outputs(&frames, &[], Some(o), Some(&render));
        assert!(both(&render.join("00005.png")).is_err());
        assert!(both(&d.join("render/../render/.pftrack-render")).is_err());
        assert!(both(&render.join("poses.csv")).is_ok());
        assert!(both(&render.join("000005.png")).is_ok());
        assert!(both(&d.join("render/new/../00001.png")).is_err());
        assert!(both(&d.join("elsewhere/00001.png")).is_ok());
        // A single image: itself, and its folder for the rendered frames.
        assert!(track_outputs(&first, &[], Some(&first), None).is_err());
        assert!(track_outputs(&first, &[], None, Some(&frames)).is_err());
        // The init or truth file read.
        let init = d.join("init.txt");
        std::fs::write(&init, b"1,2,3,4").unwrap();
        assert!(track_outputs(&frames, &[&init], Some(&d.join("./init.txt")), None).is_err());
        #[cfg(unix)]
        {
            // Two names of one file yet to be written: a link to nothing yet, and its target.
            let dangling = d.join("dangling.csv");
            std::os::unix::fs::symlink("later.csv", &dangling).unwrap();
            assert!(same(&dangling, &d.join("later.csv")));
            assert!(!same(&dangling, &d.join("other.csv")));
            // Through a link to a frame, or to the init file.
            let link = d.join("link.csv");
            std::os::unix::fs::symlink(&first, &link).unwrap();
            assert!(out(&link).is_err());
            let to_init = d.join("to-init.csv");
            std::os::unix::fs::symlink(&init, &to_init).unwrap();
            assert!(track_outputs(&frames, &[&init], Some(&to_init), None).is_err());
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn free_space_is_read_where_a_path_will_be() {
        let d = std::env::temp_dir().join(format!("pftrack-room-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        let here = room(&d).unwrap();
        assert!(here.bytes > 0 && here.block > 0, "{here:?}");
        // A folder not made yet is on its nearest existing folder's file system.
        let ahead = room(&d.join("not-made/a/../b")).unwrap();
        assert!(
            here.bytes.abs_diff(ahead.bytes) < 64 << 20,
            "{here:?} {ahead:?}"
        );
        assert_eq!(here.block, ahead.block);
        // Through a link, the file system it leads to: /dev/shm (a tmpfs) where it is one
        // with another amount free.
        let shm = Path::new("/dev/shm");
        if let Some(there) = room(shm).filter(|r| r.bytes.abs_diff(here.bytes) > 1 << 30) {
            let link = d.join("to-shm");
            std::os::unix::fs::symlink(shm, &link).unwrap();
            let through = room(&link.join("frames")).unwrap();
            assert!(
                through.bytes.abs_diff(there.bytes) < 64 << 20,
                "{through:?} {there:?}"
            );
        } else {
            eprintln!("skipped the link case: no /dev/shm apart from the temporary folder");
        }
        // Relative paths are taken from the working folder.
        assert!(room(Path::new("not-made-either")).is_some());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
