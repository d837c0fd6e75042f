//! Output that behaves in a terminal and in a log: the live status line is redrawn in place
//! (`\r`, erase to the end of the line) only when stderr is a terminal; redirected to a file or a
//! pipe it becomes a plain line every few seconds. Writes never panic: a closed pipe
//! (`spidar ... | head`) ends the output, not the program (a rig must still ramp out and switch
//! its boards off when nobody reads its summary).

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// `println!` that never panics (a closed stdout is ignored).
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout().lock(), $($arg)*);
    }};
}

/// `eprintln!` that never panics (a closed stderr is ignored).
#[macro_export]
macro_rules! errln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr().lock(), $($arg)*);
    }};
}

/// A progress line redrawn in place in a terminal; nothing in a log (the result follows).
pub fn progress(line: &str) {
    if std::io::stderr().is_terminal() {
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r{line}\x1b[K");
        let _ = err.flush();
    }
}

/// Ends the progress line.
pub fn progress_done() {
    if std::io::stderr().is_terminal() {
        let _ = std::io::stderr().lock().write_all(b"\n");
    }
}

/// Between plain status lines when stderr is not a terminal.
pub const PLAIN_EVERY: Duration = Duration::from_secs(5);

/// The live status line and the lines said around it, on stderr.
pub struct StatusOut {
    tty: bool,
    every: Duration,
    last: Option<Instant>,
    /// A status line is on screen without its newline.
    open: bool,
}

impl StatusOut {
    /// Redraws every `every` in a terminal, prints a plain line every [`PLAIN_EVERY`] (or `every`
    /// if longer) otherwise.
    pub fn new(every: Duration) -> StatusOut {
        StatusOut::with_terminal(every, std::io::stderr().is_terminal())
    }

    pub fn with_terminal(every: Duration, tty: bool) -> StatusOut {
        StatusOut { tty, every: if tty { every } else { every.max(PLAIN_EVERY) }, last: None, open: false }
    }

    pub fn is_terminal(&self) -> bool {
        self.tty
    }

    /// Time for a new status line?
    pub fn due(&self) -> bool {
        self.last.is_none_or(|t| t.elapsed() >= self.every)
    }

    /// Shows the status line (call when `due`).
    pub fn status(&mut self, line: &str) {
        self.last = Some(Instant::now());
        let mut err = std::io::stderr().lock();
        let _ = err.write_all(self.render_status(line).as_bytes());
        let _ = err.flush();
        self.open = self.tty;
    }

    /// A line of its own (a message between status lines).
    pub fn say(&mut self, line: &str) {
        let text = self.render_say(line);
        self.open = false;
        let mut err = std::io::stderr().lock();
        let _ = err.write_all(text.as_bytes());
        let _ = err.flush();
    }

    /// Ends the status line (before the summary).
    pub fn finish(&mut self) {
        if self.open {
            let _ = std::io::stderr().lock().write_all(b"\n");
            self.open = false;
        }
    }

    /// The bytes of a status line.
    pub fn render_status(&self, line: &str) -> String {
        if self.tty {
            format!("\r{line}\x1b[K")
        } else {
            format!("{line}\n")
        }
    }

    /// The bytes of a line said between status lines.
    pub fn render_say(&self, line: &str) -> String {
        if self.tty {
            format!("\r\x1b[K{line}\n")
        } else {
            format!("{line}\n")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_gets_plain_lines_and_a_terminal_the_redrawn_line() {
        let plain = StatusOut::with_terminal(Duration::from_millis(500), false);
        for s in [plain.render_status("t 1.0 s  active"), plain.render_say("world: lost")] {
            assert!(!s.contains('\r') && !s.contains('\x1b'), "{s:?}");
            assert!(s.ends_with('\n'));
        }
        assert_eq!(plain.every, PLAIN_EVERY);
        let tty = StatusOut::with_terminal(Duration::from_millis(500), true);
        assert_eq!(tty.render_status("x"), "\rx\x1b[K");
        assert_eq!(tty.every, Duration::from_millis(500));
    }
}
