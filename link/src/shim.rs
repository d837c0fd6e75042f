//! A network you can make bad on purpose: delay, jitter and loss, seeded and deterministic on
//! whatever clock the caller gives (the virtual clock in tests, the rig's clock in `spidar run`).
//!
//! [`DelayLine`] is one direction of a link: each item handed to it is lost (with the loss
//! probability), or arrives after the one-way delay times `1 + jitter * u`, `u` uniform in
//! [-1, 1], drawn per item. Items are independent, so jitter reorders them as UDP may (a late
//! item arrives after a newer one); what to do with a reordered item is the receiver's rule, as
//! on a real link. A line holds at most its capacity in flight: one more is dropped and counted
//! (a full queue). [`ShimRigLink`] puts one line each way around a rig's end of a link
//! ([`RigLink`]): the models it takes, and the samples it sends, go through them.
//!
//! The same seed and the same calls give the same arrivals, bit for bit.
//!
//! Must never: allocate, lock or block after construction (the rig's tick calls it); deliver an
//! item before its time; deliver an item twice.

use rand::{Rng, SeedableRng};
use spidar_msg::{ContactModel, HandSample, RigStatus};

use crate::{LinkStats, RigLink, Sent};

/// How bad one direction of the network is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShimParams {
    /// One-way delay (s).
    pub delay_s: f64,
    /// Each item's delay varies by up to this fraction of `delay_s`, either way (0.1: 10 %).
    pub jitter: f64,
    /// Probability that an item is lost (0.01: 1 %).
    pub loss: f64,
    pub seed: u64,
}

impl ShimParams {
    /// A perfect network: no delay, no jitter, no loss.
    pub fn none() -> ShimParams {
        ShimParams { delay_s: 0.0, jitter: 0.0, loss: 0.0, seed: 0 }
    }

    /// One direction of a network with round trip `round_trip_s` (half of it each way).
    pub fn round_trip(round_trip_s: f64, jitter: f64, loss: f64, seed: u64) -> ShimParams {
        ShimParams { delay_s: round_trip_s / 2.0, jitter, loss, seed }
    }

    /// Checks the numbers; the error says which one and what it must be.
    pub fn check(&self) -> Result<(), String> {
        if !(self.delay_s.is_finite() && (0.0..=10.0).contains(&self.delay_s)) {
            return Err(format!("delay {} s: give a delay between 0 and 10 s", self.delay_s));
        }
        if !(0.0..=1.0).contains(&self.jitter) {
            return Err(format!("jitter {}: give a fraction of the delay between 0 and 1", self.jitter));
        }
        if !(0.0..=1.0).contains(&self.loss) {
            return Err(format!("loss {}: give a probability between 0 and 1", self.loss));
        }
        Ok(())
    }
}

/// What a line did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShimStats {
    /// Items handed to the line.
    pub sent: u64,
    /// Items lost on purpose (the loss probability).
    pub lost: u64,
    /// Items dropped because the line held its capacity in flight.
    pub overflow: u64,
    pub delivered: u64,
    /// Items delivered after an item handed to the line later than them.
    pub reordered: u64,
}

#[derive(Clone, Copy)]
struct InFlight<T> {
    due_s: f64,
    order: u64,
    item: T,
}

/// One direction of a bad network (see the module's doc).
pub struct DelayLine<T: Copy> {
    params: ShimParams,
    rng: rand_pcg::Pcg64Mcg,
    flight: Vec<InFlight<T>>,
    capacity: usize,
    next_order: u64,
    newest_delivered: Option<u64>,
    stats: ShimStats,
}

impl<T: Copy> DelayLine<T> {
    /// A line holding at most `capacity` items in flight (allocated now, never again).
    pub fn new(params: ShimParams, capacity: usize) -> DelayLine<T> {
        DelayLine {
            params,
            rng: rand_pcg::Pcg64Mcg::seed_from_u64(params.seed),
            flight: Vec::with_capacity(capacity.max(1)),
            capacity: capacity.max(1),
            next_order: 0,
            newest_delivered: None,
            stats: ShimStats::default(),
        }
    }

    pub fn params(&self) -> &ShimParams {
        &self.params
    }

    pub fn stats(&self) -> &ShimStats {
        &self.stats
    }

    /// Items in flight.
    pub fn in_flight(&self) -> usize {
        self.flight.len()
    }

    /// Hands `item` to the line at `now_s`. Both random draws are made for every item, lost or
    /// not, so a change of the loss probability leaves the other items' delays as they were.
    pub fn push(&mut self, now_s: f64, item: T) {
        let lose: f64 = self.rng.random();
        let u: f64 = self.rng.random_range(-1.0..=1.0);
        let order = self.next_order;
        self.next_order += 1;
        self.stats.sent += 1;
        if lose < self.params.loss {
            self.stats.lost += 1;
            return;
        }
        if self.flight.len() >= self.capacity {
            self.stats.overflow += 1;
            return;
        }
        let delay = (self.params.delay_s * (1.0 + self.params.jitter * u)).max(0.0);
        self.flight.push(InFlight { due_s: now_s + delay, order, item });
    }

    /// The item due at `now_s` that arrives first (the earliest due; of equal ones, the first
    /// handed in), taken out of the line; None if nothing is due yet.
    pub fn pop_due(&mut self, now_s: f64) -> Option<T> {
        let mut best: Option<usize> = None;
        for (i, f) in self.flight.iter().enumerate() {
            // A nanosecond of slack: a due time one rounding past the tick is due at it.
            if f.due_s > now_s + 1e-9 {
                continue;
            }
            let better = best.is_none_or(|b| {
                let o = &self.flight[b];
                f.due_s < o.due_s || (f.due_s == o.due_s && f.order < o.order)
            });
            if better {
                best = Some(i);
            }
        }
        let f = self.flight.swap_remove(best?);
        self.stats.delivered += 1;
        if self.newest_delivered.is_some_and(|n| f.order < n) {
            self.stats.reordered += 1;
        }
        self.newest_delivered = Some(self.newest_delivered.map_or(f.order, |n| n.max(f.order)));
        Some(f.item)
    }

    /// Drops everything in flight (a link that dies).
    pub fn clear(&mut self) {
        self.flight.clear();
    }
}

/// Items a [`ShimRigLink`] holds in flight each way: a second of samples at 1 kHz, and
/// of models at 333 Hz (a round trip of 2 s).
pub const SAMPLES_IN_FLIGHT: usize = 1024;
pub const MODELS_IN_FLIGHT: usize = 512;

/// A rig's end of a link behind a bad network: the models the inner link receives reach the
/// rig `down`'s delay later (or never), the samples the rig sends reach the inner link `up`'s
/// delay later (or never). A model stamped older than the newest one the rig took is dropped and
/// counted, the rule of the socket link (`rig.rs`), which reordering here would otherwise escape.
/// Statuses pass unchanged (a summary, not part of the loop).
pub struct ShimRigLink<L: RigLink> {
    inner: L,
    up: DelayLine<HandSample>,
    down: DelayLine<ContactModel>,
    newest_stamp_s: f64,
    now_s: f64,
    /// Models dropped for arriving after a newer one.
    pub models_out_of_order: u64,
    /// Samples the inner link did not take (full or no peer) when they arrived.
    pub samples_refused: u64,
}

impl<L: RigLink> ShimRigLink<L> {
    /// `up` shapes the samples (rig to world), `down` the models (world to rig); give them
    /// different seeds.
    pub fn new(inner: L, up: ShimParams, down: ShimParams) -> ShimRigLink<L> {
        ShimRigLink {
            inner,
            up: DelayLine::new(up, SAMPLES_IN_FLIGHT),
            down: DelayLine::new(down, MODELS_IN_FLIGHT),
            newest_stamp_s: f64::NEG_INFINITY,
            now_s: 0.0,
            models_out_of_order: 0,
            samples_refused: 0,
        }
    }

    pub fn inner(&self) -> &L {
        &self.inner
    }

    pub fn inner_mut(&mut self) -> &mut L {
        &mut self.inner
    }

    /// The two lines' counts: (samples up, models down).
    pub fn shim_stats(&self) -> (ShimStats, ShimStats) {
        (*self.up.stats(), *self.down.stats())
    }
}

impl<L: RigLink> RigLink for ShimRigLink<L> {
    fn poll(&mut self, now_s: f64) -> Option<ContactModel> {
        self.now_s = now_s;
        while let Some(s) = self.up.pop_due(now_s) {
            if self.inner.send_sample(&s) != Sent::Queued {
                self.samples_refused += 1;
            }
        }
        if let Some(m) = self.inner.poll(now_s) {
            self.down.push(now_s, m);
        }
        let mut newest = None;
        while let Some(m) = self.down.pop_due(now_s) {
            if m.stamp_s < self.newest_stamp_s {
                self.models_out_of_order += 1;
                continue;
            }
            self.newest_stamp_s = m.stamp_s;
            newest = Some(m);
        }
        newest
    }

    /// Always queued: the sample is on the (bad) network; whether it arrives is the network's.
    fn send_sample(&mut self, s: &HandSample) -> Sent {
        self.up.push(self.now_s, *s);
        Sent::Queued
    }

    fn send_status(&mut self, s: &RigStatus) {
        self.inner.send_status(s)
    }

    fn close(&mut self) {
        self.inner.close()
    }

    fn stats(&self) -> Option<&LinkStats> {
        self.inner.stats()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(delay_s: f64, jitter: f64, loss: f64, seed: u64) -> DelayLine<u64> {
        DelayLine::new(ShimParams { delay_s, jitter, loss, seed }, 4096)
    }

    /// Pushes one item a millisecond for `n` ms and collects (arrival ms, item) until all are in.
    fn run(l: &mut DelayLine<u64>, n: u64) -> Vec<(u64, u64)> {
        let mut got = Vec::new();
        for ms in 0..n + 2000 {
            let now = ms as f64 * 1e-3;
            if ms < n {
                l.push(now, ms);
            }
            while let Some(x) = l.pop_due(now) {
                got.push((ms, x));
            }
        }
        got
    }

    #[test]
    fn no_delay_delivers_everything_at_once_in_order() {
        let mut l = line(0.0, 0.0, 0.0, 1);
        let got = run(&mut l, 100);
        assert_eq!(got, (0..100).map(|i| (i, i)).collect::<Vec<_>>());
        assert_eq!(l.stats().reordered, 0);
    }

    #[test]
    fn a_fixed_delay_delivers_every_item_that_much_later_in_order() {
        let mut l = line(0.050, 0.0, 0.0, 1);
        let got = run(&mut l, 500);
        assert_eq!(got.len(), 500);
        for (at, x) in &got {
            assert_eq!(*at, x + 50, "item {x} arrived at {at} ms");
        }
        assert_eq!(*l.stats(), ShimStats { sent: 500, delivered: 500, ..Default::default() });
    }

    #[test]
    fn jitter_stays_within_its_fraction_and_reorders_some() {
        let mut l = line(0.100, 0.1, 0.0, 7);
        let got = run(&mut l, 2000);
        assert_eq!(got.len(), 2000);
        let delays: Vec<i64> = got.iter().map(|(at, x)| *at as i64 - *x as i64).collect();
        // 90..110 ms, rounded up to the next millisecond the line is read at.
        assert!(delays.iter().all(|d| (90..=111).contains(d)), "{:?}", delays.iter().minmax());
        let spread = delays.iter().max().unwrap() - delays.iter().min().unwrap();
        assert!(spread >= 15, "the delays barely vary: {spread} ms");
        assert!(l.stats().reordered > 100, "{:?}", l.stats());
        let mut items: Vec<u64> = got.iter().map(|g| g.1).collect();
        items.sort();
        assert_eq!(items, (0..2000).collect::<Vec<_>>(), "every item once");
    }

    trait MinMax {
        fn minmax(self) -> (i64, i64);
    }
    impl<'a, I: Iterator<Item = &'a i64>> MinMax for I {
        fn minmax(self) -> (i64, i64) {
            self.fold((i64::MAX, i64::MIN), |(a, b), x| (a.min(*x), b.max(*x)))
        }
    }

    #[test]
    fn loss_drops_about_its_share_and_the_same_seed_gives_the_same_run() {
        let mut a = line(0.020, 0.1, 0.01, 42);
        let got = run(&mut a, 20_000);
        let lost = a.stats().lost;
        assert!((120..=280).contains(&lost), "1 % of 20000 lost: {lost}");
        assert_eq!(got.len() as u64 + lost, 20_000);
        let mut b = line(0.020, 0.1, 0.01, 42);
        assert_eq!(run(&mut b, 20_000), got, "same seed, same arrivals");
        let mut c = line(0.020, 0.1, 0.01, 43);
        assert_ne!(run(&mut c, 20_000), got, "another seed, other arrivals");
    }

    #[test]
    fn a_full_line_drops_and_counts_and_clear_empties_it() {
        let mut l = DelayLine::new(ShimParams { delay_s: 1.0, ..ShimParams::none() }, 3);
        for i in 0..5u64 {
            l.push(0.0, i);
        }
        assert_eq!((l.in_flight(), l.stats().overflow), (3, 2));
        assert_eq!(l.pop_due(0.5), None, "nothing before its time");
        assert_eq!(l.pop_due(1.0), Some(0));
        l.clear();
        assert_eq!(l.pop_due(2.0), None);
    }

    #[test]
    fn bad_numbers_are_named() {
        assert!(ShimParams::round_trip(0.2, 0.1, 0.01, 1).check().is_ok());
        let e = ShimParams { delay_s: -1.0, ..ShimParams::none() }.check().unwrap_err();
        assert!(e.contains("delay"), "{e}");
        let e = ShimParams { jitter: 2.0, ..ShimParams::none() }.check().unwrap_err();
        assert!(e.contains("jitter"), "{e}");
        let e = ShimParams { loss: f64::NAN, ..ShimParams::none() }.check().unwrap_err();
        assert!(e.contains("loss"), "{e}");
    }

    #[test]
    fn the_rig_link_behind_the_shim_gets_models_late_and_never_an_older_one() {
        let (rig, world) = crate::channel::pair();
        let down = ShimParams { delay_s: 0.010, jitter: 0.5, loss: 0.0, seed: 3 };
        let up = ShimParams { delay_s: 0.005, ..ShimParams::none() };
        let mut link = ShimRigLink::new(rig, up, down);
        let (mut taken, mut ticks) = (Vec::new(), Vec::new());
        for ms in 0..200u64 {
            let now = ms as f64 * 1e-3;
            if ms % 3 == 0 {
                world.models.send(ContactModel { seq: ms, stamp_s: now, ..Default::default() }).unwrap();
            }
            if let Some(m) = link.poll(now) {
                assert!(now - m.stamp_s >= 0.005 - 1e-12, "model {} at {now}: earlier than its delay", m.seq);
                taken.push(m.stamp_s);
            }
            assert_eq!(
                link.send_sample(&HandSample { tick: ms, t_s: now, ..Default::default() }),
                Sent::Queued
            );
            ticks.extend(world.samples.try_iter().map(|s| (ms, s.tick)));
        }
        assert!(taken.windows(2).all(|w| w[0] < w[1]), "stamps only go forward: {taken:?}");
        assert!(link.models_out_of_order > 0, "a 50 % jitter on a 3 ms stream reorders");
        // Each sample reaches the world 5 ms after it was sent (released at that tick's poll).
        assert_eq!(ticks, (0..195).map(|t| (t + 5, t)).collect::<Vec<_>>());
        assert_eq!(link.samples_refused, 0);
    }
}
