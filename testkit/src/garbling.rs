//! A device that garbles replies as a UART board's reply without a checksum is garbled: one count
//! of a reply changed silently (the exchange reports success). Must never: garble
//! nondeterministically (its generator is seeded), or touch the commands the host writes.

use spidar_device::{Device, DeviceError, DeviceInfo, Input, Output};

/// Any device with a fraction of its replies garbled: one count of the rig's eight string
/// channels (0 .. 7) changed by `min_step_counts ..= 4096` either way. Deterministic for its seed.
pub struct Garbling<D> {
    pub inner: D,
    /// Fraction of the replies garbled.
    pub rate: f64,
    /// The smallest change of a garbled count (the largest is 4096).
    pub min_step_counts: i64,
    rng: u64,
    /// Replies garbled so far.
    pub garbled: u64,
    /// The last reply as the inner device gave it, before garbling.
    pub clean: Input,
    /// What was garbled in the last reply: the channel and the change.
    pub last: Option<(usize, i64)>,
}

impl<D: Device> Garbling<D> {
    /// `inner` with `rate` of its replies garbled, the generator seeded with `seed` (not 0).
    pub fn new(inner: D, rate: f64, min_step_counts: i64, seed: u64) -> Garbling<D> {
        assert!(seed != 0 && (1..=4096).contains(&min_step_counts), "a seed, and a step in 1 ..= 4096");
        Garbling { inner, rate, min_step_counts, rng: seed, garbled: 0, clean: Input::default(), last: None }
    }

    fn next(&mut self) -> u64 {
        // xorshift64*: enough for picking replies and offsets.
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        self.rng.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn uniform(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

impl<D: Device> Device for Garbling<D> {
    fn open(&mut self) -> Result<(), DeviceError> {
        self.inner.open()
    }
    fn activate(&mut self) -> Result<(), DeviceError> {
        self.inner.activate()
    }
    fn deactivate(&mut self) -> Result<(), DeviceError> {
        self.inner.deactivate()
    }
    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        self.inner.exchange(out, inp)?;
        self.clean = *inp;
        self.last = None;
        if self.uniform() < self.rate {
            let ch = (self.next() % 8) as usize;
            let span = (4097 - self.min_step_counts) as u64;
            let mag = self.min_step_counts + (self.next() % span) as i64;
            let by = if self.next().is_multiple_of(2) { mag } else { -mag };
            inp.counts[ch] += by;
            self.garbled += 1;
            self.last = Some((ch, by));
        }
        Ok(())
    }
    fn info(&self) -> &DeviceInfo {
        self.inner.info()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A board whose counters never move.
    struct Still(DeviceInfo);

    impl Device for Still {
        fn open(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
        fn activate(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
        fn deactivate(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
        fn exchange(&mut self, _: &Output, inp: &mut Input) -> Result<(), DeviceError> {
            inp.counts = [1000; spidar_device::MAX_CHANNELS];
            Ok(())
        }
        fn info(&self) -> &DeviceInfo {
            &self.0
        }
    }

    fn still() -> Still {
        Still(DeviceInfo {
            board: spidar_device::short_string("still"),
            identity: spidar_device::short_string("0"),
            channels: 8,
            volts_min: -1.0,
            volts_max: 1.0,
        })
    }

    #[test]
    fn a_garbled_reply_changes_one_string_count_within_the_steps_and_says_so() {
        let mut g = Garbling::new(still(), 0.2, 64, 7);
        let (mut seen, mut inp) = (0, Input::default());
        for _ in 0..10_000 {
            g.exchange(&Output::default(), &mut inp).unwrap();
            assert_eq!(g.clean.counts, [1000; spidar_device::MAX_CHANNELS]);
            let changed: Vec<usize> =
                (0..spidar_device::MAX_CHANNELS).filter(|&c| inp.counts[c] != 1000).collect();
            match g.last {
                None => assert!(changed.is_empty()),
                Some((ch, by)) => {
                    assert_eq!(changed, [ch]);
                    assert!(ch < 8 && (64..=4096).contains(&by.abs()), "{ch} {by}");
                    assert_eq!(inp.counts[ch], 1000 + by);
                    seen += 1;
                }
            }
        }
        assert_eq!(seen, g.garbled);
        assert!((1800..2200).contains(&seen), "about a fifth: {seen}");
    }

    #[test]
    fn the_same_seed_garbles_the_same_replies() {
        let run = |seed| {
            let mut g = Garbling::new(still(), 0.05, 1, seed);
            let mut inp = Input::default();
            (0..2000)
                .map(|_| g.exchange(&Output::default(), &mut inp).map(|()| g.last).unwrap())
                .collect::<Vec<_>>()
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
    }
}
