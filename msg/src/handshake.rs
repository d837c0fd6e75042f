//! The messages that open, refuse and close a rig-world link (see `docs/link.md`).
//!
//! A rig sends [`Hello`] until a world answers with [`Welcome`] (or [`Refuse`], saying why);
//! either side sends [`Bye`] when it leaves on purpose. Everything the two must agree on is in
//! these: the protocol version (in every datagram's header), the counts that fix the size of the
//! other messages, the rig's period and geometry, and the scene.

use crate::RigInfo;

/// A short UTF-8 text of at most `N` bytes, stored inline so the messages stay `Copy` and the
/// rig never allocates for one. Longer texts are cut at a character boundary; a text ends at its
/// first NUL character (the wire pads with zeros).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Text<const N: usize> {
    bytes: [u8; N],
    len: u16,
}

impl<const N: usize> Text<N> {
    pub const CAPACITY: usize = N;

    pub fn new(s: &str) -> Text<N> {
        let s = s.split('\0').next().unwrap_or("");
        let mut end = s.len().min(N);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        let mut bytes = [0u8; N];
        bytes[..end].copy_from_slice(&s.as_bytes()[..end]);
        Text { bytes, len: end as u16 }
    }

    pub fn as_str(&self) -> &str {
        // Built from a &str cut at a boundary, or checked when decoded.
        std::str::from_utf8(&self.bytes[..self.len as usize]).unwrap_or("")
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The text as stored on the wire: `N` bytes, zero-padded.
    pub fn raw(&self) -> &[u8; N] {
        &self.bytes
    }

    /// Reads the wire form back: up to the first zero byte, which must be valid UTF-8.
    pub fn from_raw(raw: &[u8; N]) -> Option<Text<N>> {
        let len = raw.iter().position(|b| *b == 0).unwrap_or(N);
        std::str::from_utf8(&raw[..len]).ok()?;
        if raw[len..].iter().any(|b| *b != 0) {
            return None; // text after the terminator: not something we wrote
        }
        Some(Text { bytes: *raw, len: len as u16 })
    }
}

impl<const N: usize> Default for Text<N> {
    fn default() -> Self {
        Text { bytes: [0; N], len: 0 }
    }
}

impl<const N: usize> std::fmt::Debug for Text<N> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl<const N: usize> std::fmt::Display for Text<N> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A scene's name as it crosses the link.
pub type Name = Text<64>;
/// A sentence saying why something was refused.
pub type Reason = Text<160>;

/// Rig to world, repeated until answered: who the rig is and what it needs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Hello {
    /// Chosen at random when the rig starts: a world tells a rig that reconnects (same session)
    /// from a new one (its clock starts again at zero).
    pub rig_session: u64,
    /// The rig's `HANDS`, `STRINGS` and `MAX_PROXIES`: they fix the size of every other message.
    pub hands: u8,
    pub strings: u8,
    pub max_proxies: u8,
    /// The scene the rig asks for (as the world names it); empty: whatever the world runs.
    pub scene: Name,
    /// The rig's geometry and period (world frame).
    pub rig: RigInfo,
}

/// World to rig: the rig is served.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Welcome {
    /// The `rig_session` of the `Hello` this answers.
    pub rig_session: u64,
    /// Chosen at random when the world starts: a rig sees that its world was replaced.
    pub world_session: u64,
    pub hands: u8,
    pub strings: u8,
    pub max_proxies: u8,
    /// Time between two world steps (one contact model each).
    pub step_s: f64,
    /// The scene the world runs.
    pub scene: Name,
}

/// Why a world refused a rig.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum RefuseCode {
    #[default]
    Other = 0,
    /// `hands`, `strings` or `max_proxies` differ: the two were built from different sources.
    Shape = 1,
    /// The rig asked for a scene the world does not run.
    Scene = 2,
    /// The world already serves another rig.
    Busy = 3,
    /// The rig's period or geometry cannot be used.
    Rig = 4,
}

impl RefuseCode {
    pub fn from_u8(b: u8) -> Option<RefuseCode> {
        Some(match b {
            0 => RefuseCode::Other,
            1 => RefuseCode::Shape,
            2 => RefuseCode::Scene,
            3 => RefuseCode::Busy,
            4 => RefuseCode::Rig,
            _ => return None,
        })
    }
}

/// World to rig: the rig is not served, and why (naming both sides' values).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Refuse {
    pub rig_session: u64,
    pub code: RefuseCode,
    pub reason: Reason,
}

/// Either way: the sender leaves on purpose (a rig stopping, a world ending).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Bye {
    /// The sender's session (`rig_session` or `world_session`).
    pub session: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_cuts_at_a_character_boundary_and_reads_back() {
        let t: Text<4> = Text::new("aéé"); // a (1) + é (2) + é (2): the second é does not fit
        assert_eq!(t.as_str(), "aé");
        assert_eq!(Text::from_raw(t.raw()), Some(t));
        assert_eq!(Text::<4>::from_raw(&[b'a', 0, b'b', 0]), None, "bytes after the terminator");
        assert_eq!(Text::<2>::from_raw(&[0xff, 0]), None, "not UTF-8");
    }
}
