//! The words the control side and the loop exchange: the rig's lifecycle states, why it faulted,
//! the commands it takes and the events it reports.
//!
//! Why it exists apart: the tick core (`tick/`) acts on these, the telemetry records carry them
//! and the loop around the core passes them on; keeping them here means none of those files
//! imports another in a circle. Plain `Copy` data only: this file must never hold behaviour
//! that runs in the tick, allocate, or depend on another file of this crate.

use spidar_device::ErrorKind;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Lifecycle {
    #[default]
    Unconfigured,
    Inactive,
    Active,
    Faulted,
}

impl Lifecycle {
    pub fn name(self) -> &'static str {
        match self {
            Lifecycle::Unconfigured => "unconfigured",
            Lifecycle::Inactive => "inactive",
            Lifecycle::Active => "active",
            Lifecycle::Faulted => "faulted",
        }
    }
}

/// Why the rig went to `Faulted`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FaultReason {
    /// The device exchange failed.
    Device(ErrorKind),
    /// The pose of this hand could not be computed (non-finite lengths or result).
    PoseInvalid { hand: u8 },
    /// The string lengths of this hand disagree beyond the residual limit for too long
    /// (slack string, slipped encoder, wrong anchors).
    Residual { hand: u8 },
    /// This hand's counts jumped further than the hand can move, tick after tick (corrupt
    /// replies, or an encoder that slipped).
    CountJump { hand: u8 },
}

impl FaultReason {
    /// Transient faults clear themselves after enough good ticks.
    pub fn is_transient(self) -> bool {
        matches!(
            self,
            FaultReason::Device(ErrorKind::Timeout | ErrorKind::Corrupt) | FaultReason::CountJump { .. }
        )
    }
}

impl std::fmt::Display for FaultReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FaultReason::Device(k) => write!(f, "device error ({k:?})"),
            FaultReason::PoseInvalid { hand } => write!(f, "hand {hand}: pose could not be computed"),
            FaultReason::Residual { hand } => {
                write!(
                    f,
                    "hand {hand}: string lengths disagree (slack string, slipped encoder or wrong anchors)"
                )
            }
            FaultReason::CountJump { hand } => {
                write!(
                    f,
                    "hand {hand}: counts jumped beyond any hand motion, tick after tick (corrupt replies?)"
                )
            }
        }
    }
}

/// What the control side may ask of the loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command {
    /// Preset the counters' zero lengths so each grip reads its home point (Inactive; while
    /// Faulted it is kept and done when the fault clears). Done after the strings have been held
    /// at minimum tension for `HOMING_SETTLE_S`, so no string is still slack (a slack string reads
    /// long and would bake its sag into the zero length).
    Home,
    /// Start rendering forces (Inactive and homed only); force ramps in.
    Activate,
    /// Ramp force out and return to Inactive.
    Deactivate,
    /// Leave Faulted for Inactive.
    ClearFault,
    /// Ramp out, hold minimum tension briefly, switch the device off and end the loop.
    Stop,
}

/// What the loop tells the control side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    State(Lifecycle),
    Fault(FaultReason),
    Homed,
    Refused {
        command: Command,
        why: &'static str,
    },
    /// The device came back after a disconnect; the rig returns to Inactive and must be homed.
    DeviceReopened,
    /// Homing was lost (a fault during homing, a reopened device): hold both grips still at
    /// their home points and the rig homes itself after `rehome_still_s`, or send `Home`.
    HomeNeeded,
    Stopped,
}
