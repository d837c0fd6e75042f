//! The one digest of the determinism tests: 64-bit FNV-1a over the little-endian bytes of the
//! values fed to it, so two runs that produce the same bits give the same number and a pinned
//! number changes whenever any bit does.
//!
//! Why it exists: five tests and states each carried their own copy of the same loop. What it
//! must never do: change its algorithm (every pinned digest in the workspace would change), or be
//! used where an attacker chooses the input (FNV is not a cryptographic hash).

use glam::DVec3;

/// A running FNV-1a digest.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Digest(u64);

impl Default for Digest {
    fn default() -> Digest {
        Digest::new()
    }
}

impl Digest {
    /// FNV-1a's offset basis.
    pub const fn new() -> Digest {
        Digest(0xcbf2_9ce4_8422_2325)
    }

    /// Feeds bytes.
    pub fn bytes(&mut self, bytes: &[u8]) -> &mut Digest {
        for b in bytes {
            self.0 ^= u64::from(*b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    /// Feeds a `u64`'s little-endian bytes.
    pub fn u64(&mut self, x: u64) -> &mut Digest {
        self.bytes(&x.to_le_bytes())
    }

    /// Feeds an `f64`'s exact bits (`-0.0` and `0.0` differ, as do NaNs of other payloads).
    pub fn f64(&mut self, x: f64) -> &mut Digest {
        self.u64(x.to_bits())
    }

    /// Feeds a vector's components, x first.
    pub fn vec3(&mut self, v: DVec3) -> &mut Digest {
        self.f64(v.x).f64(v.y).f64(v.z)
    }

    /// The digest of everything fed so far.
    pub fn value(&self) -> u64 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn it_is_64_bit_fnv_1a() {
        // The published test vectors of FNV-1a 64: "" and "a".
        assert_eq!(Digest::new().value(), 0xcbf2_9ce4_8422_2325);
        assert_eq!(Digest::new().bytes(b"a").value(), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(Digest::new().bytes(b"foobar").value(), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn every_bit_counts() {
        let d = |x: f64| Digest::new().f64(x).value();
        assert_ne!(d(0.0), d(-0.0));
        assert_ne!(d(1.0), d(f64::from_bits(1.0f64.to_bits() + 1)));
        assert_eq!(
            Digest::new().vec3(DVec3::new(1.0, 2.0, 3.0)).value(),
            Digest::new().f64(1.0).f64(2.0).f64(3.0).value()
        );
        assert_eq!(Digest::new().u64(7).value(), Digest::new().bytes(&7u64.to_le_bytes()).value());
    }
}
