//! The shim allocates nothing once built: a rig's tick may run through it (its own test binary,
//! for its counting allocator).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use spidar_link::shim::{ShimParams, ShimRigLink};
use spidar_link::{channel, RigLink};
use spidar_msg::{ContactModel, HandSample};

struct Counting;

// Counted per thread: the test harness's own thread prints and allocates while the test runs
// (a CI run with both cores busy counted 4 of its allocations here when this was one global flag).
thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.realloc(p, l, new_size) }
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
    let before = ALLOCS.with(|c| c.get());
    for ms in 0..5000u64 {
        let now = ms as f64 * 1e-3;
        if ms % 3 == 0 {
            let _ = world.models.try_send(ContactModel { seq: ms, stamp_s: now, ..Default::default() });
        }
        models += link.poll(now).is_some() as u64;
        link.send_sample(&HandSample { tick: ms, t_s: now, ..Default::default() });
        while world.samples.try_recv().is_ok() {}
    }
    let allocs = ALLOCS.with(|c| c.get()) - before;
    assert_eq!(allocs, 0, "allocations in the ticks");
    assert!(models > 500, "{models} models reached the rig");
}
