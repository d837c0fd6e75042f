//! Which rig file a command uses when none is given: the user's own, once it exists.
//!
//! Why it exists: the rig file shipped in `configs/` (and compiled into the binary as the built-in
//! rig) is a template, the lab's rig as drawn, never a calibration target: calibrating it would
//! overwrite the repository's file and leave `spidar run` on the compiled-in copy. So the first
//! `spidar calib home` on a new machine creates the user's rig file,
//! `$XDG_CONFIG_HOME/spidar/rig.ron` (or `~/.config/spidar/rig.ron`), from the template, and from
//! then on `spidar calib` and `spidar run` use it when no `--rig` is given.
//!
//! What it must never do: write the shipped file, or pick a rig file silently: every command
//! that resolves one says which (and whether it is the built-in template).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use spidar_rt::rig::{DEFAULT_RIG_NAME, DEFAULT_RIG_RON};
use spidar_rt::Rig;

/// The rig file shipped with the sources (the built-in rig is compiled from it).
pub const SHIPPED_RIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/rig-spidar-h.ron");

/// Where the user's rig file lives: `$XDG_CONFIG_HOME/spidar/rig.ron`, else
/// `$HOME/.config/spidar/rig.ron`; `None` when neither variable is set (or they are not absolute).
pub fn user_rig_file() -> Option<PathBuf> {
    let abs = |v: std::ffi::OsString| Some(PathBuf::from(v)).filter(|p| p.is_absolute());
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .and_then(abs)
        .or_else(|| std::env::var_os("HOME").and_then(abs).map(|h| h.join(".config")))?;
    Some(base.join("spidar").join("rig.ron"))
}

/// The rig file a command uses.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RigSource {
    /// Given with `--rig`.
    Given(PathBuf),
    /// The user's rig file (it exists).
    User(PathBuf),
    /// None yet: the built-in template; `create` is where the user's would go.
    BuiltIn { create: Option<PathBuf> },
}

impl RigSource {
    /// The rig file for `given`: itself, else the user's if it exists, else the built-in rig.
    pub fn resolve(given: Option<&Path>) -> RigSource {
        match given {
            Some(p) => RigSource::Given(p.to_path_buf()),
            None => match user_rig_file() {
                Some(u) if u.exists() => RigSource::User(u),
                other => RigSource::BuiltIn { create: other },
            },
        }
    }

    /// The file, if there is one.
    pub fn path(&self) -> Option<&Path> {
        match self {
            RigSource::Given(p) | RigSource::User(p) => Some(p),
            RigSource::BuiltIn { .. } => None,
        }
    }

    /// What a summary says about it.
    pub fn describe(&self) -> String {
        match self {
            RigSource::Given(p) => format!("{} (--rig)", p.display()),
            RigSource::User(p) => format!("{} (yours)", p.display()),
            RigSource::BuiltIn { create: Some(p) } => format!(
                "the built-in template configs/rig-spidar-h.ron (no rig file of yours yet: `spidar calib home` creates {})",
                p.display()
            ),
            RigSource::BuiltIn { create: None } => {
                "the built-in template configs/rig-spidar-h.ron (HOME is not set: give --rig)".into()
            }
        }
    }

    /// Loads the rig (and its text, for a rig file).
    pub fn load(&self) -> anyhow::Result<(Rig, String)> {
        self.load_with_overrides(&[])
    }

    /// [`RigSource::load`] with more overrides than the file lists (`--override KEY`).
    pub fn load_with_overrides(&self, overrides: &[String]) -> anyhow::Result<(Rig, String)> {
        match self.path() {
            Some(p) => {
                let text =
                    spidar_config::read_capped(p, spidar_config::MAX_FILE_BYTES).with_context(|| {
                        format!("reading the rig file {} (give another with --rig)", p.display())
                    })?;
                Ok((Rig::from_str_with_overrides(&text, &p.display().to_string(), overrides)?, text))
            }
            None => Ok((
                Rig::from_str_with_overrides(DEFAULT_RIG_RON, DEFAULT_RIG_NAME, overrides)?,
                DEFAULT_RIG_RON.to_string(),
            )),
        }
    }
}

/// The rig `spidar run` (and the benchmarks) use: `--rig`, else the user's rig file, else the
/// built-in rig, with the command line's `--override` keys. Says which on stderr.
pub fn load_rig(given: Option<&Path>, overrides: &[String]) -> anyhow::Result<Rig> {
    let src = RigSource::resolve(given);
    crate::errln!("rig file: {}", src.describe());
    Ok(src.load_with_overrides(overrides)?.0)
}

/// True when `path` is the rig file shipped in the sources (the template).
pub fn is_shipped(path: &Path) -> bool {
    match (std::fs::canonicalize(path), std::fs::canonicalize(SHIPPED_RIG)) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

/// Refuses to write the shipped template.
pub fn check_writable_rig(path: &Path) -> anyhow::Result<()> {
    if is_shipped(path) {
        bail!(
            "{} is the rig file shipped with spidar, the template of the built-in rig: it is never calibrated. \
             Leave out --rig to calibrate your own rig file ({}), or copy the template and give the copy with --rig",
            path.display(),
            user_rig_file().map_or("~/.config/spidar/rig.ron".into(), |p| p.display().to_string())
        );
    }
    Ok(())
}

/// Creates the user's rig file at `path` from the built-in template (never over an existing
/// file). Returns the new source.
pub fn create_user_rig(path: &Path) -> anyhow::Result<RigSource> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating the folder {}", dir.display()))?;
    }
    let text = format!(
        "// Your rig file: created by `spidar calib` on {} from the built-in template (the lab's rig as\n\
         // drawn). `spidar calib` calibrates it and `spidar run` uses it when no --rig is given.\n{DEFAULT_RIG_RON}",
        spidar_calib::utc_now()
    );
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .with_context(|| format!("creating your rig file {}", path.display()))?;
    f.write_all(text.as_bytes())
        .and_then(|_| f.sync_all())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(RigSource::User(path.to_path_buf()))
}

/// The rig file a calibration command writes: `--rig` (never the shipped template), else the
/// user's, created from the template when there is none yet (and `create`).
pub fn calibration_target(given: Option<&Path>, create: bool) -> anyhow::Result<RigSource> {
    let src = RigSource::resolve(given);
    match &src {
        RigSource::Given(p) => {
            check_writable_rig(p)?;
            Ok(src)
        }
        RigSource::User(_) => Ok(src),
        RigSource::BuiltIn { create: Some(p) } if create => {
            let new = create_user_rig(p)?;
            crate::errln!("created your rig file {} from the built-in template", p.display());
            Ok(new)
        }
        RigSource::BuiltIn { create: Some(_) } => Ok(src),
        RigSource::BuiltIn { create: None } => {
            bail!("no rig file to calibrate: neither XDG_CONFIG_HOME nor HOME is set; give one with --rig")
        }
    }
}

/// `path` quoted for a shell when it needs it (hints are copied and pasted).
pub fn shell_quote(path: &Path) -> String {
    let s = path.display().to_string();
    if s.chars().all(|c| c.is_ascii_alphanumeric() || "/._-+:,@%=".contains(c)) {
        s
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_file_is_recognised_and_refused_and_a_copy_is_not() {
        assert!(is_shipped(Path::new(SHIPPED_RIG)));
        let e = check_writable_rig(Path::new(SHIPPED_RIG)).unwrap_err().to_string();
        assert!(e.contains("never calibrated"), "{e}");
        let copy = std::env::temp_dir().join(format!("spidar-rigpath-{}.ron", std::process::id()));
        std::fs::copy(SHIPPED_RIG, &copy).unwrap();
        assert!(!is_shipped(&copy));
        check_writable_rig(&copy).unwrap();
        std::fs::remove_file(&copy).unwrap();
    }

    #[test]
    fn quoting_leaves_plain_paths_alone() {
        assert_eq!(shell_quote(Path::new("/tmp/a-b/rig.ron")), "/tmp/a-b/rig.ron");
        assert_eq!(shell_quote(Path::new("/tmp/my rig's.ron")), r"'/tmp/my rig'\''s.ron'");
    }
}
