//! Output files written so that a failed write never destroys what was there: the bytes go to a
//! temporary file beside the target, which is flushed to disk and then renamed over it (a rename
//! within one folder is atomic on POSIX filesystems and replaces the target on Windows). A full
//! disk, a quota or a file-size limit (`ulimit -f`) therefore leaves an existing file
//! byte-identical, where writing in place left a truncated file whose header promised more.
//!
//! [`check_output`] is the same path checked up front, so the CLI refuses a missing folder, a
//! directory or an unwritable place before minutes of reconstruction rather than after.
//!
//! Targets that are not regular files (devices such as `/dev/null` or `/dev/full`, named pipes)
//! are written directly: renaming onto them would replace the device node or the pipe with a
//! plain file (and as root it would succeed), which is never what `-o /dev/…` means, and their
//! content cannot be "kept" anyway. Writing to `/dev/full` thus fails with "No space left on
//! device". A symbolic link is followed: the file it points to is replaced, the link stays.
//!
//! An interrupted process (killed, power cut) can leave a `.NAME.nkrr-tmp-*` file beside the
//! target; the target itself is either the old file or the whole new one.

use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

/// The folder a path lives in ("." for a bare file name).
fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Where the bytes really go: a symbolic link's target (so the link is kept), else the path.
fn resolve(path: &Path) -> PathBuf {
    match fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()),
        _ => path.to_path_buf(),
    }
}

/// A new, empty temporary file beside `target`, created exclusively (never an existing file).
fn temp_beside(target: &Path) -> std::io::Result<(PathBuf, File)> {
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    let name = target.file_name().map_or_else(|| "out".into(), |n| n.to_string_lossy().into_owned());
    loop {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = folder_of(target).join(format!(".{name}.nkrr-tmp-{}-{n}", std::process::id()));
        match OpenOptions::new().write(true).create_new(true).open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
}

/// Checks, without changing anything, that [`write_atomic`] can put a file at `path`: its
/// folder exists and is a folder we can create files in, and `path` is not a folder. The error
/// says what is wrong, in words that follow the path (e.g. "the folder out does not exist").
pub fn check_output(path: &Path) -> Result<(), String> {
    let target = resolve(path);
    let folder = folder_of(&target);
    match fs::metadata(folder) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(format!("the folder {} does not exist", folder.display()))
        }
        Err(e) => return Err(format!("cannot use the folder {}: {e}", folder.display())),
        Ok(m) if !m.is_dir() => return Err(format!("{} is not a folder", folder.display())),
        Ok(_) => {}
    }
    match fs::metadata(&target) {
        Ok(m) if m.is_dir() => return Err("is a folder; give a file name".into()),
        // A device or pipe is written directly: it must open for writing (without truncating).
        Ok(m) if !m.is_file() => {
            return OpenOptions::new().write(true).open(&target).map(drop).map_err(|e| format!("cannot write: {e}"))
        }
        // An existing file that we may not write stays as it is (rename would replace it).
        Ok(m) if m.permissions().readonly() => return Err("is read-only".into()),
        _ => {}
    }
    // Creating (and removing) a file is the one honest test: permissions, read-only mounts,
    // ACLs and root's exemptions all apply as they will for the real write.
    let (tmp, file) = temp_beside(&target).map_err(|e| format!("cannot create files in {}: {e}", folder.display()))?;
    drop(file);
    let _ = fs::remove_file(tmp);
    Ok(())
}

/// Whether `a` and `b` name the same existing file, by any path: the same file reached through
/// `./`, `..`, a symbolic link or a hard link. Compared by device and inode where the platform
/// has them (a hard link has no other common trait), else by canonical path. A path that does
/// not exist names no file, so it is never the same as another.
pub fn same_file(a: &Path, b: &Path) -> bool {
    let (Ok(ma), Ok(mb)) = (fs::metadata(a), fs::metadata(b)) else { return false };
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        ma.dev() == mb.dev() && ma.ino() == mb.ino()
    }
    #[cfg(not(unix))]
    {
        let _ = (ma, mb);
        matches!((fs::canonicalize(a), fs::canonicalize(b)), (Ok(x), Ok(y)) if x == y)
    }
}

/// Refuses an output path that names one of `inputs` (see [`same_file`]): writing there would
/// replace the user's data with ours. The error names both paths.
pub fn check_not_input(output: &Path, inputs: &[&Path]) -> Result<(), String> {
    match inputs.iter().find(|i| same_file(output, i)) {
        Some(i) if Path::new(i) == output => Err(format!("{} is the input: writing there would destroy it; choose another output name", output.display())),
        Some(i) => Err(format!(
            "{} is the same file as the input {} (a link or another path to it): writing there would destroy it; choose another output name",
            output.display(),
            i.display()
        )),
        None => Ok(()),
    }
}

/// Writes `bytes` to `path` through a temporary file beside it, renamed into place once all of
/// it is on disk; on any failure the temporary file is removed and `path` is as it was.
/// Existing files keep their permissions. See the module documentation for devices and links.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let target = resolve(path);
    let existing = fs::metadata(&target).ok();
    if let Some(m) = &existing {
        if !m.is_file() && !m.is_dir() {
            let mut f = OpenOptions::new().write(true).truncate(true).open(&target)?;
            f.write_all(bytes)?;
            return f.flush();
        }
    }
    let (tmp, mut file) = temp_beside(&target)?;
    let result = (|| {
        file.write_all(bytes)?;
        // Quotas and network filesystems may report a full disk only here.
        file.sync_all()?;
        if let Some(m) = &existing {
            fs::set_permissions(&tmp, m.permissions())?;
        }
        drop(file);
        fs::rename(&tmp, &target)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("nkrr-atomic-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn replaces_and_leaves_no_temporary_file() {
        let d = dir("replace");
        let p = d.join("a.glb");
        fs::write(&p, b"old").unwrap();
        write_atomic(&p, b"new bytes").unwrap();
        assert_eq!(fs::read(&p).unwrap(), b"new bytes");
        assert_eq!(fs::read_dir(&d).unwrap().count(), 1);
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn checks_folder_and_directory() {
        let d = dir("check");
        assert!(check_output(&d.join("a.glb")).is_ok());
        assert!(check_output(&d.join("missing/a.glb")).unwrap_err().contains("does not exist"));
        fs::create_dir(d.join("x.glb")).unwrap();
        assert!(check_output(&d.join("x.glb")).unwrap_err().contains("is a folder"));
        assert_eq!(fs::read_dir(&d).unwrap().count(), 1);
        let _ = fs::remove_dir_all(&d);
    }

    #[cfg(unix)]
    #[test]
    fn the_same_file_by_any_path() {
        let d = dir("same");
        let a = d.join("cloud.ply");
        fs::write(&a, b"ply").unwrap();
        std::os::unix::fs::symlink(&a, d.join("link.ply")).unwrap();
        fs::hard_link(&a, d.join("hard.ply")).unwrap();
        fs::write(d.join("other.ply"), b"ply").unwrap();
        for same in ["cloud.ply", "link.ply", "hard.ply", "./cloud.ply"] {
            assert!(same_file(&d.join(same), &a), "{same}");
            assert!(check_not_input(&d.join(same), &[Path::new("x"), &a]).is_err(), "{same}");
        }
        assert!(!same_file(&d.join("other.ply"), &a));
        assert!(!same_file(&d.join("missing.ply"), &d.join("missing.ply")));
        assert!(check_not_input(&d.join("new.glb"), &[&a]).is_ok());
        let _ = fs::remove_dir_all(&d);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn dev_full_fails_with_no_space() {
        let e = write_atomic(Path::new("/dev/full"), b"x").unwrap_err();
        assert!(e.to_string().contains("No space left"), "{e}");
    }
}
