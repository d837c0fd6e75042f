//! Where the emulator publishes its pseudo-terminal: a symlink (a stable path, as udev gives a
//! USB serial adapter) in a directory private to the user, never a fixed shared path that
//! another user could have planted.
//!
//! Rules: the link is only ever created where nothing is, or where a dangling link to a
//! pseudo-terminal is (left by an emulator that was killed: its pty is gone). Anything else at
//! that path (a file, a link to something else, the live link of another emulator) is refused
//! and left alone. The emulator removes its link on every way out it can see (stop, drop,
//! disconnect, a panic that unwinds); after `kill -9` the dangling link is replaced by the next
//! emulator.

use std::io;
use std::os::unix::fs::{DirBuilderExt, MetadataExt};
use std::path::{Path, PathBuf};

use super::EmulatorError;

/// Where a pty slave lives on Linux.
const PTY_DIR: &str = "/dev/pts/";

/// A directory only this user can use: `$XDG_RUNTIME_DIR/spidar` when the runtime directory is
/// there and ours, else `<tmp>/spidar-<uid>`. Created with mode 0700; refused when it exists but
/// is not a directory owned by this user with no access for others.
pub fn private_dir() -> Result<PathBuf, EmulatorError> {
    // SAFETY: getuid has no preconditions.
    let uid = unsafe { libc::getuid() };
    let runtime = std::env::var_os("XDG_RUNTIME_DIR")
        .map(PathBuf::from)
        .filter(|p| p.is_absolute() && std::fs::metadata(p).is_ok_and(|m| m.is_dir() && m.uid() == uid));
    let dir = match runtime {
        Some(r) => r.join("spidar"),
        None => std::env::temp_dir().join(format!("spidar-{uid}")),
    };
    match std::fs::DirBuilder::new().mode(0o700).create(&dir) {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {}
        Err(e) => {
            return Err(EmulatorError::PrivateDir { path: dir.display().to_string(), why: e.to_string() })
        }
    }
    let m = std::fs::symlink_metadata(&dir)
        .map_err(|e| EmulatorError::PrivateDir { path: dir.display().to_string(), why: e.to_string() })?;
    if !m.is_dir() || m.uid() != uid || m.mode() & 0o077 != 0 {
        return Err(EmulatorError::PrivateDir {
            path: dir.display().to_string(),
            why: format!(
                "it exists but is not a directory of yours with mode 0700 (owner uid {}, mode {:o}): remove it \
                 or give --symlink",
                m.uid(),
                m.mode() & 0o7777
            ),
        });
    }
    Ok(dir)
}

/// The default link of `spidar emulate`: `uart` in [`private_dir`].
pub fn default_symlink() -> Result<PathBuf, EmulatorError> {
    Ok(private_dir()?.join("uart"))
}

/// Makes `link` free for a new emulator link: nothing there, or a dangling link to a pty (whose
/// emulator is gone), which is removed. Anything else is refused.
pub fn claim(link: &Path) -> Result<(), EmulatorError> {
    let m = match std::fs::symlink_metadata(link) {
        Ok(m) => m,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(EmulatorError::Link { path: link.display().to_string(), source: e }),
    };
    let refuse = |why: String| EmulatorError::LinkTaken { path: link.display().to_string(), why };
    if !m.file_type().is_symlink() {
        return Err(refuse("it exists and is not a symlink (not replaced)".into()));
    }
    let target = std::fs::read_link(link).map_err(|e| refuse(e.to_string()))?;
    if !target.starts_with(PTY_DIR) {
        return Err(refuse(format!(
            "it points at {} (not a pseudo-terminal): not an emulator's link",
            target.display()
        )));
    }
    if target.exists() {
        return Err(refuse(format!(
            "it points at {}, which is live: another emulator serves there (stop it, or give --symlink)",
            target.display()
        )));
    }
    std::fs::remove_file(link)
        .map_err(|e| EmulatorError::Link { path: link.display().to_string(), source: e })
}

/// Creates `link` pointing at `pty` (after [`claim`]).
pub fn publish(link: &Path, pty: &Path) -> Result<(), EmulatorError> {
    std::os::unix::fs::symlink(pty, link)
        .map_err(|e| EmulatorError::Link { path: link.display().to_string(), source: e })
}

/// Removes `link` if it still points at `pty` (never another program's link).
pub fn remove_if_ours(link: &Path, pty: &Path) {
    if std::fs::read_link(link).is_ok_and(|t| t == pty) {
        let _ = std::fs::remove_file(link);
    }
}
