//! Replacing a file (the rig file, a session) so that nothing is lost and nothing planted is
//! followed.
//!
//! Why it exists: the rig file is the user's own, possibly kept private (mode 0600), possibly a
//! symlink into a dotfiles repository, and its earlier versions are what an operator falls back
//! to after a bad calibration. A crash, a full disk or a file planted by someone else in the same
//! folder must never cost any of that.
//!
//! How: the path is resolved first (a symlinked file has its target updated, the link stays a
//! link). The new text goes into a temporary file created exclusively (`O_CREAT | O_EXCL |
//! O_NOFOLLOW`, a name not used before) in the target's own folder, gets the old file's mode and
//! owner, is flushed to disk, and is renamed over the target (atomic on POSIX file systems); then
//! the folder is flushed. A backup of the old file is a hard link (or, where links are not
//! possible, an exclusive copy) named by the date, `<name>.<UTC time>.bak`, never replacing an
//! earlier backup: every version stays.
//!
//! What it must never do: write through a symlink planted at a temporary or backup name, leave a
//! half-written file where the target was, or change who may read the file.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::{MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use crate::CalibError;

/// What a replacement did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Replaced {
    /// The file that was written: the path given, or the target of the symlink it was.
    pub target: PathBuf,
    /// The backup of the previous version, if one was asked for and there was one.
    pub backup: Option<PathBuf>,
}

fn io_err<'a>(path: &'a Path, what: &'static str) -> impl FnOnce(std::io::Error) -> CalibError + 'a {
    move |source| CalibError::Io { file: path.display().to_string(), what, source }
}

fn bad(path: &Path, message: String) -> CalibError {
    CalibError::BadFile { file: path.display().to_string(), message }
}

/// The file a write to `path` updates: `path` itself, or the final target of the symlink it is.
/// Fails when `path` is something other than a regular file, or a symlink to nothing.
pub fn resolve(path: &Path) -> Result<PathBuf, CalibError> {
    let target = match std::fs::symlink_metadata(path) {
        Ok(m) if m.file_type().is_symlink() => std::fs::canonicalize(path).map_err(|e| {
            bad(path, format!("is a symlink whose target cannot be reached ({e}): fix or remove the link"))
        })?,
        Ok(_) => path.to_path_buf(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => path.to_path_buf(),
        Err(e) => return Err(io_err(path, "cannot inspect the file")(e)),
    };
    match std::fs::metadata(&target) {
        Ok(m) if !m.is_file() => Err(bad(path, "exists and is not a regular file: give a file path".into())),
        _ => Ok(target),
    }
}

/// The folder of `path` (`.` for a bare name).
fn folder(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Numbers the temporary names of this process.
static TEMP_SERIAL: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);

/// The `n`-th temporary name next to `near`: predictable on purpose (nothing depends on it being
/// secret: the file is created exclusively, so a name someone planted is skipped).
fn temp_name(near: &Path, n: u32, suffix: &str) -> PathBuf {
    let name = near.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    folder(near).join(format!(".{name}.{}.{n}.{suffix}", std::process::id()))
}

/// Creates a new file next to `near` exclusively (never an existing name, never through a
/// symlink), named `.<name>.<pid>.<n>.<suffix>`.
fn create_exclusive(near: &Path, suffix: &str, mode: u32) -> Result<(File, PathBuf), CalibError> {
    let dir = folder(near);
    for _ in 0..64u32 {
        let p = temp_name(near, TEMP_SERIAL.fetch_add(1, std::sync::atomic::Ordering::Relaxed), suffix);
        match OpenOptions::new()
            .write(true)
            .create_new(true)
            .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
            .mode(mode)
            .open(&p)
        {
            Ok(f) => return Ok((f, p)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => {
                return Err(CalibError::Io {
                    file: dir.display().to_string(),
                    what: "cannot create a file in this folder (does it exist, may you write there?)",
                    source: e,
                })
            }
        }
    }
    Err(bad(
        &dir,
        "could not find a free temporary name in 64 tries: remove the folder's stray .*.tmp files".into(),
    ))
}

/// Checks, before any work is done, that `path` can be written later: its folder exists and
/// takes new files, and it is not something other than a file.
pub fn check_writable(path: &Path) -> Result<(), CalibError> {
    let target = resolve(path)?;
    let dir = folder(&target);
    if !dir.is_dir() {
        return Err(bad(
            path,
            format!("the folder {} does not exist: create it or choose another path", dir.display()),
        ));
    }
    let (f, p) = create_exclusive(&target, "probe", 0o600)?;
    drop(f);
    let _ = std::fs::remove_file(&p);
    Ok(())
}

/// Gives `f` the mode and owner of `like`.
fn copy_mode_and_owner(f: &File, file: &Path, like: &std::fs::Metadata) -> Result<(), CalibError> {
    f.set_permissions(std::fs::Permissions::from_mode(like.mode() & 0o7777))
        .map_err(io_err(file, "cannot set the file's mode"))?;
    let mine = f.metadata().map_err(io_err(file, "cannot inspect the new file"))?;
    if (mine.uid(), mine.gid()) != (like.uid(), like.gid()) {
        std::os::unix::fs::fchown(f, Some(like.uid()), Some(like.gid())).map_err(|source| CalibError::Io {
            file: file.display().to_string(),
            what: "cannot give the new version the old file's owner (run as that user, or as root); nothing was \
                   written",
            source,
        })?;
        // chown clears set-id bits: set the mode again.
        f.set_permissions(std::fs::Permissions::from_mode(like.mode() & 0o7777))
            .map_err(io_err(file, "cannot set the file's mode"))?;
    }
    Ok(())
}

/// The name of a dated backup of `target` (not yet existing when this is called; the link or
/// copy that creates it is exclusive anyway).
fn backup_name(target: &Path, n: u32) -> PathBuf {
    let stamp = crate::utc_now().replace(':', "-");
    let mut name = target.file_name().map(|n| n.to_os_string()).unwrap_or_default();
    if n == 0 {
        name.push(format!(".{stamp}.bak"));
    } else {
        name.push(format!(".{stamp}-{n}.bak"));
    }
    target.with_file_name(name)
}

/// Keeps the current version of `target` (a regular file, resolved) as a dated backup next to it.
fn keep_backup(target: &Path, meta: &std::fs::Metadata) -> Result<PathBuf, CalibError> {
    for n in 0..1000 {
        let bak = backup_name(target, n);
        // A hard link is atomic, exclusive (fails if the name exists, even as a symlink) and
        // keeps the old version's mode and owner.
        match std::fs::hard_link(target, &bak) {
            Ok(()) => return Ok(bak),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(_) => {}
        }
        // No links on this file system: an exclusive copy.
        let mut f = match OpenOptions::new()
            .write(true)
            .create_new(true)
            .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
            .mode(0o600)
            .open(&bak)
        {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(io_err(&bak, "cannot keep a backup of the old file")(e)),
        };
        let old = std::fs::read(target).map_err(io_err(target, "cannot read the old file for its backup"))?;
        let r = f
            .write_all(&old)
            .and_then(|_| f.sync_all())
            .map_err(io_err(&bak, "cannot write the backup"))
            .and_then(|_| copy_mode_and_owner(&f, &bak, meta));
        if let Err(e) = r {
            let _ = std::fs::remove_file(&bak);
            return Err(e);
        }
        return Ok(bak);
    }
    Err(bad(target, "1000 backups in one second: not writing".into()))
}

/// Keeps the file at `path` (if any) as a dated backup without changing it.
pub fn keep_dated_copy(path: &Path) -> Result<Option<PathBuf>, CalibError> {
    let target = resolve(path)?;
    match std::fs::metadata(&target) {
        Ok(meta) => Ok(Some(keep_backup(&target, &meta)?)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io_err(path, "cannot inspect the file")(e)),
    }
}

/// Replaces the file at `path` with `text` (see the module doc); with `backup`, the previous
/// version is kept as `<name>.<UTC time>.bak`. On error the old file is untouched.
pub fn replace(path: &Path, text: &str, backup: bool) -> Result<Replaced, CalibError> {
    let target = resolve(path)?;
    let old = match std::fs::metadata(&target) {
        Ok(m) => Some(m),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(io_err(path, "cannot inspect the file")(e)),
    };
    // A new file gets what the umask leaves of 0666, like any file the user creates.
    let (mut f, tmp) = create_exclusive(&target, "tmp", 0o666)?;
    let result = (|| {
        f.write_all(text.as_bytes()).map_err(io_err(&tmp, "cannot write the temporary file"))?;
        if let Some(m) = &old {
            copy_mode_and_owner(&f, &target, m)?;
        }
        f.sync_all().map_err(io_err(&tmp, "cannot flush the temporary file to disk"))?;
        let backup = match (&old, backup) {
            (Some(m), true) => Some(keep_backup(&target, m)?),
            _ => None,
        };
        std::fs::rename(&tmp, &target)
            .map_err(io_err(&target, "cannot rename the temporary file over the old one"))?;
        // The rename itself is durable only once the folder is flushed.
        if let Ok(d) = File::open(folder(&target)) {
            let _ = d.sync_all();
        }
        Ok(Replaced { target: target.clone(), backup })
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    fn dir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("spidar-safefile-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn names(d: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn mode_is_kept_and_every_version_stays_in_a_dated_backup() {
        let d = dir("mode");
        let p = d.join("rig.ron");
        std::fs::write(&p, "v1").unwrap();
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
        let a = replace(&p, "v2", true).unwrap();
        let b = replace(&p, "v3", true).unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "v3");
        assert_eq!(std::fs::metadata(&p).unwrap().mode() & 0o777, 0o600, "mode kept");
        // Two writes, two backups: the original is still there.
        let (a, b) = (a.backup.unwrap(), b.backup.unwrap());
        assert_ne!(a, b);
        assert_eq!(std::fs::read_to_string(&a).unwrap(), "v1");
        assert_eq!(std::fs::read_to_string(&b).unwrap(), "v2");
        assert!(a.file_name().unwrap().to_string_lossy().starts_with("rig.ron.20"), "{a:?}");
        assert!(a.to_string_lossy().ends_with(".bak"));
        // Nothing else is left in the folder (no temporary file).
        assert_eq!(names(&d).len(), 3, "{:?}", names(&d));
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_symlinked_file_has_its_target_updated_and_stays_a_link() {
        let d = dir("link");
        std::fs::create_dir_all(d.join("dotfiles")).unwrap();
        let real = d.join("dotfiles/rig.ron");
        std::fs::write(&real, "old").unwrap();
        let link = d.join("rig.ron");
        symlink(&real, &link).unwrap();
        let r = replace(&link, "new", true).unwrap();
        assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink(), "still a link");
        assert_eq!(std::fs::read_to_string(&real).unwrap(), "new");
        assert_eq!(r.target, std::fs::canonicalize(&real).unwrap());
        assert_eq!(std::fs::read_to_string(r.backup.unwrap()).unwrap(), "old");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn symlinks_planted_at_temporary_and_backup_names_are_never_followed() {
        let d = dir("planted");
        let p = d.join("rig.ron");
        std::fs::write(&p, "mine").unwrap();
        let victim = d.join("victim");
        std::fs::write(&victim, "victim").unwrap();
        // The next temporary names of this process (and the old fixed one), and the backup
        // names of this second.
        let next = TEMP_SERIAL.load(std::sync::atomic::Ordering::Relaxed);
        let planted: Vec<PathBuf> = (0..4)
            .map(|s| backup_name(&p, s))
            .chain((next..next + 8).map(|n| temp_name(&p, n, "tmp")))
            .chain([d.join(format!(".rig.ron.tmp-{}", std::process::id())), d.join("rig.ron.bak")])
            .collect();
        for s in &planted {
            symlink(&victim, s).unwrap();
        }
        replace(&p, "new", true).unwrap();
        replace(&p, "newer", true).unwrap();
        assert_eq!(
            std::fs::read_to_string(&victim).unwrap(),
            "victim",
            "the planted links' target is untouched"
        );
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "newer");
        for s in &planted {
            assert!(std::fs::symlink_metadata(s).unwrap().file_type().is_symlink(), "{s:?} replaced");
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn the_owner_is_kept() {
        let d = dir("owner");
        let p = d.join("rig.ron");
        std::fs::write(&p, "v1").unwrap();
        let me = std::fs::metadata(&p).unwrap();
        // As root the file can belong to someone else; the new version must too.
        let other = std::os::unix::fs::chown(&p, Some(4242), Some(4343)).is_ok();
        replace(&p, "v2", false).unwrap();
        let m = std::fs::metadata(&p).unwrap();
        if other {
            assert_eq!((m.uid(), m.gid()), (4242, 4343));
        } else {
            assert_eq!((m.uid(), m.gid()), (me.uid(), me.gid()));
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn an_unwritable_place_is_refused_before_any_work() {
        let d = dir("check");
        let e = check_writable(&d.join("no-such-folder/session.ron")).unwrap_err();
        assert!(e.to_string().contains("does not exist"), "{e}");
        let e = check_writable(&d).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        check_writable(&d.join("session.ron")).unwrap();
        assert!(names(&d).is_empty(), "the probe is removed: {:?}", names(&d));
        std::fs::remove_dir_all(&d).unwrap();
    }
}
