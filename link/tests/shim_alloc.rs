//! The shim allocates nothing once built: a rig's tick may run through it (its own test binary,
//! for its counting allocator).

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use spidar_link::shim::{ShimParams, ShimRigLink};
use spidar_link::{channel, RigLink};
use spidar_msg::{ContactModel, HandSample};

struct Counting;
static COUNT: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if COUNT.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
}

#[global_allocator]
static A: Counting = Counting;

#[test]
fn a_rig_link_behind_the_shim_allocates_nothing_per_tick() {
    let (rig, world) = channel::pair();
    let down = ShimParams::round_trip(0.2, 0.1, 0.01, 1);
    let up = ShimParams::round_trip(0.2, 0.1, 0.01, 2);
    let mut link = ShimRigLink::new(rig, up, down);
    let mut models = 0;
    // This test is the only one in its binary: nothing else allocates while it counts.
    COUNT.store(true, Ordering::Relaxed);
    for ms in 0..5000u64 {
        let now = ms as f64 * 1e-3;
        if ms % 3 == 0 {
            let _ = world.models.try_send(ContactModel { seq: ms, stamp_s: now, ..Default::default() });
        }
        models += link.poll(now).is_some() as u64;
        link.send_sample(&HandSample { tick: ms, t_s: now, ..Default::default() });
        while world.samples.try_recv().is_ok() {}
    }
    COUNT.store(false, Ordering::Relaxed);
    assert_eq!(ALLOCS.load(Ordering::Relaxed), 0, "allocations in the ticks");
    assert!(models > 500, "{models} models reached the rig");
}
