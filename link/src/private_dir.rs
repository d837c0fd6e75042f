//! Where the link's Unix sockets live: a directory only this user can reach, never a fixed name
//! in a shared directory, never through a symbolic link someone planted.
//!
//! - [`PrivateDir::for_process`]: a fresh directory `spidar-<pid>-<random>` in
//!   `$XDG_RUNTIME_DIR` (the user's runtime directory, already private) or else in the temporary
//!   directory. Created exclusively with mode 0700; removed when dropped. `spidar run` puts its
//!   child world's socket and its own there.
//! - [`PrivateDir::user_default`]: `$XDG_RUNTIME_DIR/spidar`, kept: the default address of a
//!   world started by hand, so a rig can find it. Without `XDG_RUNTIME_DIR` a fresh random one.
//!
//! Every directory is checked with `lstat` (never followed): a directory, owned by this user, no
//! access for group or others.

use std::hash::{BuildHasher, Hasher};
use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

use crate::LinkError;

/// A private directory for sockets.
#[derive(Debug)]
pub struct PrivateDir {
    path: PathBuf,
    remove_on_drop: bool,
}

/// A random 64-bit number from the standard library's per-process random hash keys (no extra
/// dependency; used for unguessable names and session ids, not for cryptography).
pub fn random_u64() -> u64 {
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(std::process::id() as u64);
    h.write_u128(
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos()),
    );
    h.finish()
}

fn euid() -> u32 {
    // SAFETY: geteuid cannot fail.
    unsafe { libc::geteuid() }
}

/// The user's runtime directory, if set and private.
fn runtime_dir() -> Option<PathBuf> {
    let d = PathBuf::from(std::env::var_os("XDG_RUNTIME_DIR")?);
    (d.is_absolute() && check_private(&d).is_ok()).then_some(d)
}

/// `dir` is a real directory (not a symlink), owned by this user, with no access for others.
pub fn check_private(dir: &Path) -> Result<(), LinkError> {
    check_dir(dir, 0o077, "has access for group or others (chmod 700 it)")
}

/// `dir` is a real directory owned by this user that nobody else can write to: a socket in it
/// cannot be replaced by someone else.
pub fn check_socket_dir(dir: &Path) -> Result<(), LinkError> {
    check_dir(
        dir,
        0o022,
        "can be written by group or others, so a socket in it could be replaced: use a private directory \
         (the default is in $XDG_RUNTIME_DIR)",
    )
}

fn check_dir(dir: &Path, forbidden_mode: u32, why_mode: &str) -> Result<(), LinkError> {
    let unsafe_dir = |why: String| LinkError::Unsafe { what: "directory", path: dir.to_path_buf(), why };
    let m = std::fs::symlink_metadata(dir).map_err(|e| LinkError::io("checking", dir, e))?;
    if m.file_type().is_symlink() {
        return Err(unsafe_dir("is a symbolic link: refusing to follow it".into()));
    }
    if !m.is_dir() {
        return Err(unsafe_dir("is not a directory".into()));
    }
    if m.uid() != euid() {
        return Err(unsafe_dir(format!("belongs to user {}, not to you ({})", m.uid(), euid())));
    }
    if m.permissions().mode() & forbidden_mode != 0 {
        return Err(unsafe_dir(format!("(mode {:o}) {why_mode}", m.permissions().mode() & 0o7777)));
    }
    Ok(())
}

/// Creates `path` with mode 0700; an existing one is accepted only if it passes [`check_private`].
fn create_or_check(path: &Path) -> Result<(), LinkError> {
    match std::fs::DirBuilder::new().mode(0o700).create(path) {
        Ok(()) => check_private(path),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => check_private(path),
        Err(e) => Err(LinkError::io("creating the directory", path, e)),
    }
}

/// A new directory with a random name under `base` (exclusive create: an existing name, planted
/// or not, is never used).
fn fresh_in(base: PathBuf, prefix: &str) -> Result<PathBuf, LinkError> {
    let mut last = None;
    for _ in 0..16 {
        let p = base.join(format!("{prefix}-{}-{:016x}", std::process::id(), random_u64()));
        match std::fs::DirBuilder::new().mode(0o700).create(&p) {
            Ok(()) => {
                check_private(&p)?;
                return Ok(p);
            }
            Err(e) => last = Some(e),
        }
    }
    Err(LinkError::io(
        "creating a private directory in",
        &base,
        last.unwrap_or_else(|| std::io::Error::other("?")),
    ))
}

impl PrivateDir {
    /// A fresh directory for this process (or one of its sessions): `spidar-<pid>-<random>` in
    /// `$XDG_RUNTIME_DIR` or the temporary directory. Removed (with what is in it) when dropped.
    pub fn for_process() -> Result<PrivateDir, LinkError> {
        let base = runtime_dir().unwrap_or_else(std::env::temp_dir);
        Ok(PrivateDir { path: fresh_in(base, "spidar")?, remove_on_drop: true })
    }

    /// The user's directory for a world started by hand: `$XDG_RUNTIME_DIR/spidar` (kept), or a
    /// fresh one in the temporary directory (removed when dropped).
    pub fn user_default() -> Result<PrivateDir, LinkError> {
        match runtime_dir() {
            Some(rt) => {
                let p = rt.join("spidar");
                create_or_check(&p)?;
                Ok(PrivateDir { path: p, remove_on_drop: false })
            }
            None => {
                Ok(PrivateDir { path: fresh_in(std::env::temp_dir(), "spidar-world")?, remove_on_drop: true })
            }
        }
    }

    /// Uses an existing directory after checking that it is private (tests, callers with their own).
    pub fn existing(path: &Path) -> Result<PrivateDir, LinkError> {
        check_private(path)?;
        Ok(PrivateDir { path: path.to_path_buf(), remove_on_drop: false })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn join(&self, name: &str) -> PathBuf {
        self.path.join(name)
    }
}

impl Drop for PrivateDir {
    fn drop(&mut self) {
        if self.remove_on_drop {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    #[test]
    fn a_process_directory_is_private_and_goes_away() {
        let d = PrivateDir::for_process().unwrap();
        let p = d.path().to_path_buf();
        let m = std::fs::symlink_metadata(&p).unwrap();
        assert!(m.is_dir());
        assert_eq!(m.permissions().mode() & 0o777, 0o700);
        drop(d);
        assert!(!p.exists());
    }

    #[test]
    fn planted_symlinks_and_shared_directories_are_refused() {
        let d = PrivateDir::for_process().unwrap();
        let target = d.join("target");
        std::fs::create_dir(&target).unwrap();
        std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o700)).unwrap();
        let link = d.join("link");
        symlink(&target, &link).unwrap();
        let e = check_private(&link).unwrap_err().to_string();
        assert!(e.contains("symbolic link"), "{e}");
        assert!(PrivateDir::existing(&target).is_ok());
        std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o777)).unwrap();
        let e = check_socket_dir(&target).unwrap_err().to_string();
        assert!(e.contains("written by group or others"), "{e}");
        let e = check_private(&std::env::temp_dir()).unwrap_err().to_string();
        assert!(e.contains("group or others") || e.contains("belongs to"), "{e}");
    }

    #[test]
    fn random_names_differ() {
        assert_ne!(random_u64(), random_u64());
    }
}
