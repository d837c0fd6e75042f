//! What each channel of a recording carries: the [`Field`] implementations of the rig's plain
//! data (the rt-loop's tick record, the link messages, the device's input and output), and the
//! channels' topics and message names.
//!
//! Enumerations travel as `uint8` codes listed in the schema's comments. Changing a list here
//! changes the schema text, which a reader compares with its own: a recording made by a spidar
//! with other schemas is refused by name instead of being misread.

use glam::DVec3;
use spidar_device::{ErrorKind, Input, Output, MAX_CHANNELS};
use spidar_msg::{
    Blow, ContactModel, HandContact, HandSample, HandState, Proxy, ProxyId, ProxyShape, HANDS, MAX_PROXIES,
};
use spidar_rt::telemetry::{CommandLog, HandRecord, TickRecord, RECORD_COMMANDS};
use spidar_rt::tension::Method;
use spidar_rt::{Command, Event, FaultReason, Lifecycle};

use crate::cdr::{DecodeError, Field, Reader, Writer};
use crate::message;

/// Every tick of the rt-loop: timing, lifecycle, hands, forces, tensions, safety flags, device
/// input and output, commands ([`TickRecord`] without the parts on the channels below).
pub const TOPIC_TICK: &str = "/rig/tick";
/// Every hand sample the rig sent to the world, as sent.
pub const TOPIC_SAMPLE: &str = "/rig/hand_sample";
/// Every contact model the rig took, as received, with the tick that took it.
pub const TOPIC_MODEL: &str = "/rig/contact_model";
/// Lifecycle changes, faults, refusals, homing, reopens, the stop.
pub const TOPIC_EVENT: &str = "/rig/event";

impl Field for DVec3 {
    fn ros_type() -> String {
        "spidar/Vec3".into()
    }
    fn definition() -> Option<String> {
        Some("float64 x\nfloat64 y\nfloat64 z\n".into())
    }
    fn write(&self, w: &mut Writer<'_>) {
        w.f64(self.x);
        w.f64(self.y);
        w.f64(self.z);
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(DVec3::new(r.f64()?, r.f64()?, r.f64()?))
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        for c in ["x", "y", "z"] {
            out.push(format!("{prefix}.{c}"));
        }
    }
    fn csv(&self, out: &mut String) {
        self.x.csv(out);
        self.y.csv(out);
        self.z.csv(out);
    }
}

/// A field-less enumeration's `uint8` code and its name (for CSV cells).
pub trait Code: Sized {
    fn code(&self) -> u8;
    fn from_code(c: u8) -> Option<Self>;
    fn name(&self) -> &'static str;
}

/// Implements [`Code`] and [`Field`] for an enumeration from one list of (value, code, name).
macro_rules! code_enum {
    ($t:ty, $what:literal, [$($v:pat => $c:literal, $n:literal, $e:expr);* $(;)?]) => {
        impl Code for $t {
            fn code(&self) -> u8 {
                match *self { $( $v => $c, )* }
            }
            fn from_code(c: u8) -> Option<Self> {
                match c { $( $c => Some($e), )* _ => None }
            }
            fn name(&self) -> &'static str {
                match *self { $( $v => $n, )* }
            }
        }
        impl Field for $t {
            fn ros_type() -> String {
                "uint8".into()
            }
            fn write(&self, w: &mut Writer<'_>) {
                w.u8(self.code());
            }
            fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
                let c = r.u8()?;
                Self::from_code(c).ok_or_else(|| DecodeError { what: format!("unknown {} code {c}", $what), at: 0 })
            }
            fn columns(prefix: &str, out: &mut Vec<String>) {
                out.push(prefix.to_string());
            }
            fn csv(&self, out: &mut String) {
                // Names, not codes: a spreadsheet reads `active`, not `2`.
                out.push(',');
                out.push_str(self.name());
            }
        }
    };
}

code_enum!(Lifecycle, "lifecycle", [
    Lifecycle::Unconfigured => 0, "unconfigured", Lifecycle::Unconfigured;
    Lifecycle::Inactive => 1, "inactive", Lifecycle::Inactive;
    Lifecycle::Active => 2, "active", Lifecycle::Active;
    Lifecycle::Faulted => 3, "faulted", Lifecycle::Faulted;
]);
code_enum!(Method, "allocation method", [
    Method::Exact => 0, "exact", Method::Exact;
    Method::Scaled => 1, "scaled", Method::Scaled;
    Method::Fallback => 2, "fallback", Method::Fallback;
]);
code_enum!(Command, "command", [
    Command::Home => 1, "home", Command::Home;
    Command::Activate => 2, "activate", Command::Activate;
    Command::Deactivate => 3, "deactivate", Command::Deactivate;
    Command::ClearFault => 4, "clear_fault", Command::ClearFault;
    Command::Stop => 5, "stop", Command::Stop;
]);
code_enum!(Option<ErrorKind>, "device error kind", [
    None => 0, "none", None;
    Some(ErrorKind::Timeout) => 1, "timeout", Some(ErrorKind::Timeout);
    Some(ErrorKind::Corrupt) => 2, "corrupt", Some(ErrorKind::Corrupt);
    Some(ErrorKind::Disconnected) => 3, "disconnected", Some(ErrorKind::Disconnected);
    Some(ErrorKind::Protocol) => 4, "protocol", Some(ErrorKind::Protocol);
    Some(ErrorKind::Other) => 5, "other", Some(ErrorKind::Other);
]);

/// Why the rig faulted: `kind` 0 none, 1 device error (`detail`: the error kind, as in
/// `io_error`), 2 pose invalid, 3 residual too high (`detail`: the hand).
impl Field for Option<FaultReason> {
    fn ros_type() -> String {
        "spidar/Fault".into()
    }
    fn definition() -> Option<String> {
        Some(
            "# 0 none, 1 device error, 2 pose could not be computed, 3 string lengths disagree, 4 counts jumped\nuint8 kind\n\
             # device error: 1 timeout, 2 corrupt, 3 disconnected, 4 protocol, 5 other; else the hand\nuint8 detail\n"
                .into(),
        )
    }
    fn write(&self, w: &mut Writer<'_>) {
        let (k, d) = match *self {
            None => (0, 0),
            Some(FaultReason::Device(e)) => (1, Some(e).code()),
            Some(FaultReason::PoseInvalid { hand }) => (2, hand),
            Some(FaultReason::Residual { hand }) => (3, hand),
            Some(FaultReason::CountJump { hand }) => (4, hand),
        };
        w.u8(k);
        w.u8(d);
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let k = r.u8()?;
        let d = r.u8()?;
        match k {
            0 => Ok(None),
            1 => match Option::<ErrorKind>::from_code(d) {
                Some(Some(e)) => Ok(Some(FaultReason::Device(e))),
                _ => Err(DecodeError { what: format!("device fault of unknown error kind {d}"), at: 0 }),
            },
            2 => Ok(Some(FaultReason::PoseInvalid { hand: d })),
            3 => Ok(Some(FaultReason::Residual { hand: d })),
            4 => Ok(Some(FaultReason::CountJump { hand: d })),
            _ => Err(DecodeError { what: format!("unknown fault kind {k}"), at: 0 }),
        }
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        out.push(prefix.to_string());
    }
    fn csv(&self, out: &mut String) {
        out.push(',');
        match *self {
            None => out.push_str("none"),
            Some(FaultReason::Device(e)) => {
                out.push_str("device_");
                out.push_str(Some(e).name());
            }
            Some(FaultReason::PoseInvalid { hand }) => out.push_str(&format!("pose_invalid_hand{hand}")),
            Some(FaultReason::Residual { hand }) => out.push_str(&format!("residual_hand{hand}")),
            Some(FaultReason::CountJump { hand }) => out.push_str(&format!("count_jump_hand{hand}")),
        }
    }
}

/// Commands in order; `lost`: commands that did not fit in the record.
impl Field for CommandLog {
    fn ros_type() -> String {
        "spidar/Commands".into()
    }
    fn definition() -> Option<String> {
        Some(format!(
            "# 1 home, 2 activate, 3 deactivate, 4 clear fault, 5 stop (at most {RECORD_COMMANDS})\nuint8[] codes\nuint8 lost\n"
        ))
    }
    fn write(&self, w: &mut Writer<'_>) {
        w.u32(self.len() as u32);
        for c in self.iter() {
            c.write(w);
        }
        w.u8(self.lost());
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let n = r.count(1)?;
        if n > RECORD_COMMANDS {
            return Err(DecodeError {
                what: format!("{n} commands in one tick (at most {RECORD_COMMANDS})"),
                at: 0,
            });
        }
        let mut log = CommandLog::default();
        for _ in 0..n {
            log.push(Command::read(r)?);
        }
        log.set_lost(r.u8()?);
        Ok(log)
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        out.push(prefix.to_string());
    }
    fn csv(&self, out: &mut String) {
        out.push(',');
        for (i, c) in self.iter().enumerate() {
            if i > 0 {
                out.push(';');
            }
            out.push_str(c.name());
        }
    }
}

/// A proxy's geometry: `kind` 0 plane (through `a_m`, outward normal `b_m`), 1 sphere (centre
/// `a_m`), 2 capsule (segment `a_m`..`b_m`); `radius_m` for spheres and capsules.
impl Field for ProxyShape {
    fn ros_type() -> String {
        "spidar/ProxyShape".into()
    }
    fn definition() -> Option<String> {
        Some(
            "# 0 plane (through a_m, outward normal b_m), 1 sphere (centre a_m), 2 capsule (a_m..b_m)\nuint8 kind\n\
             spidar/Vec3 a_m\nspidar/Vec3 b_m\nfloat64 radius_m\n"
                .into(),
        )
    }
    fn collect(out: &mut Vec<(String, String)>) {
        crate::cdr::add_definition::<Self>(out);
        DVec3::collect(out);
    }
    fn write(&self, w: &mut Writer<'_>) {
        let (k, a, b, r) = shape_parts(self);
        w.u8(k);
        a.write(w);
        b.write(w);
        w.f64(r);
    }
    fn read(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let k = r.u8()?;
        let (a, b, radius_m) = (DVec3::read(r)?, DVec3::read(r)?, r.f64()?);
        match k {
            0 => Ok(ProxyShape::Plane { point_m: a, normal: b }),
            1 => Ok(ProxyShape::Sphere { centre_m: a, radius_m }),
            2 => Ok(ProxyShape::Capsule { a_m: a, b_m: b, radius_m }),
            _ => Err(DecodeError { what: format!("unknown proxy shape {k}"), at: 0 }),
        }
    }
    fn columns(prefix: &str, out: &mut Vec<String>) {
        out.push(format!("{prefix}.kind"));
        DVec3::columns(&format!("{prefix}.a_m"), out);
        DVec3::columns(&format!("{prefix}.b_m"), out);
        out.push(format!("{prefix}.radius_m"));
    }
    fn csv(&self, out: &mut String) {
        let (k, a, b, r) = shape_parts(self);
        out.push(',');
        out.push_str(["plane", "sphere", "capsule"][k as usize]);
        a.csv(out);
        b.csv(out);
        r.csv(out);
    }
}

/// (kind, a_m, b_m, radius_m) of a shape, as encoded.
fn shape_parts(s: &ProxyShape) -> (u8, DVec3, DVec3, f64) {
    match *s {
        ProxyShape::Plane { point_m, normal } => (0, point_m, normal, 0.0),
        ProxyShape::Sphere { centre_m, radius_m } => (1, centre_m, DVec3::ZERO, radius_m),
        ProxyShape::Capsule { a_m, b_m, radius_m } => (2, a_m, b_m, radius_m),
    }
}

message!(ProxyId = "spidar/ProxyId" {
    body: u16,
    part: u16,
});

message!(Proxy = "spidar/Proxy" {
    id: ProxyId,
    shape: ProxyShape,
    k_n_per_m: f64,
    d_n_s_per_m: f64,
    vel_m_per_s: DVec3,
    /// bit 0: hand 0 may touch it; bit 1: hand 1
    hand_mask: u8,
});

message!(HandContact = "spidar/HandContact" {
    /// contact force on the avatar's hand, world frame; zero: no contact
    force_n: DVec3,
    /// out of what the hand touches, toward the hand
    normal: DVec3,
    /// how fast the force grows as the user's hand goes in along -normal
    k_n_per_m: f64,
    /// the user's hand position the force was computed for, world frame
    at_m: DVec3,
    /// power the touched body puts into the contact
    source_w: f64,
});

message!(Blow = "spidar/Blow" {
    /// +1 per blow landed on the avatar; 0: none yet
    seq: u64,
    /// where the fist met the avatar, world frame
    point_m: DVec3,
    /// unit direction of the blow: the fist's velocity relative to the struck part
    dir: DVec3,
    /// the fist's speed relative to the struck part at impact
    speed_m_per_s: f64,
    /// striking hand and forearm's mass times the impact speed
    momentum_n_s: f64,
    /// the fist still touches the avatar
    in_contact: bool,
});

message!(ContactModel = "spidar/ContactModel" {
    seq: u64,
    /// loop-clock time the geometry is valid at
    stamp_s: f64,
    /// world frame; only the first proxy_count are in use
    proxies: [Proxy; MAX_PROXIES],
    proxy_count: u8,
    /// per hand: the contact on the avatar's hand (boxing)
    hand_contacts: [HandContact; HANDS],
    extra_force_n: [DVec3; HANDS],
    /// the newest blow landed on the avatar (boxing)
    blow: Blow,
});

/// A contact model and the tick that took it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TakenModel {
    pub tick: u64,
    pub model: ContactModel,
}

message!(TakenModel = "spidar/TakenModel" {
    /// the rt-loop tick that took this model
    tick: u64,
    model: ContactModel,
});

message!(HandState = "spidar/HandState" {
    pos_world_m as "pos_m": DVec3,
    vel_world_m_per_s as "vel_m_per_s": DVec3,
    force_n: DVec3,
    valid: bool,
});

message!(HandSample = "spidar/HandSample" {
    tick: u64,
    t_s: f64,
    /// world frame
    hands: [HandState; HANDS],
    model_seq: u64,
    proxy_impulse_n_s: [DVec3; MAX_PROXIES],
    proxy_contact_impulse_n_s: [DVec3; MAX_PROXIES],
});

message!(Input = "spidar/DeviceInput" {
    /// counters per channel, extended to 64 bits
    counts: [i64; MAX_CHANNELS],
    status: u32,
});

message!(Output = "spidar/DeviceOutput" {
    /// DA volts per channel
    volts: [f64; MAX_CHANNELS],
});

message!(HandRecord = "spidar/HandTick" {
    /// rig frame
    pos_rig_m as "pos_m": DVec3,
    vel_rig_m_per_s as "vel_m_per_s": DVec3,
    residual_m: f64,
    valid: bool,
    /// force asked by rendering (and the scene's extra force), before safety
    rendered_n: DVec3,
    /// after safety (gains, clamp)
    commanded_n: DVec3,
    /// what the allocated tensions produce
    output_n: DVec3,
    tensions_n: [f64; 4],
    scale: f64,
    /// 0 exact, 1 scaled back along its direction, 2 box-QP fallback
    method: Method,
    contacts: u8,
    clamped: bool,
    stiffness_limited: bool,
    non_finite: bool,
    /// energy reserve of the avatar-hand contact
    reserve_j: f64,
    /// the command was scaled down to stay within the reserve
    passivity_limited: bool,
    /// the landed blow's share of output_n (boxing)
    blow_n: DVec3,
    /// the output repeats the last tick's (a late, missing or rejected reply, or a high residual)
    held: bool,
});

message!(TickRecord = "spidar/Tick" {
    tick: u64,
    /// loop-clock time of the wake-up
    t_s: f64,
    lateness_s: f64,
    compute_s: f64,
    io_s: f64,
    /// 0 unconfigured, 1 inactive, 2 active, 3 faulted
    state: Lifecycle,
    fault: Option<FaultReason>,
    /// ramp x staleness (0 when not active)
    gain: f64,
    contact_age_s: f64,
    hands: [HandRecord; 2],
    commands: CommandLog,
    reopened: bool,
    /// 0 none, 1 timeout, 2 corrupt, 3 disconnected, 4 protocol, 5 other
    io_error: Option<ErrorKind>,
    input: Input,
    output: Output,
    /// homing was lost: waiting for the grips to be held still at home (or for Home)
    awaiting_home: bool,
} skip { model, sample, events });

/// One event of the rig, with the tick it happened in.
#[derive(Clone, Debug, PartialEq)]
pub struct EventMsg {
    pub tick: u64,
    pub t_s: f64,
    /// 1 state, 2 fault, 3 homed, 4 refused, 5 device reopened, 6 stopped, 7 homing lost
    pub kind: u8,
    pub state: Lifecycle,
    pub fault: Option<FaultReason>,
    /// The refused command (0: none).
    pub command: u8,
    /// What happened, in words.
    pub text: String,
}

message!(EventMsg = "spidar/Event" {
    tick: u64,
    t_s: f64,
    /// 1 lifecycle state, 2 fault, 3 homed, 4 command refused, 5 device reopened, 6 stopped, 7 homing lost
    kind: u8,
    state: Lifecycle,
    fault: Option<FaultReason>,
    /// the refused command: 1 home, 2 activate, 3 deactivate, 4 clear fault, 5 stop
    command: u8,
    text: String,
});

impl EventMsg {
    pub fn new(tick: u64, t_s: f64, e: &Event) -> EventMsg {
        let mut m = EventMsg {
            tick,
            t_s,
            kind: 0,
            state: Lifecycle::Unconfigured,
            fault: None,
            command: 0,
            text: String::new(),
        };
        match *e {
            Event::State(s) => {
                m.kind = 1;
                m.state = s;
                m.text = format!("state {}", s.name());
            }
            Event::Fault(f) => {
                m.kind = 2;
                m.fault = Some(f);
                m.text = format!("fault: {f}");
            }
            Event::Homed => {
                m.kind = 3;
                m.text = "homed".into();
            }
            Event::Refused { command, why } => {
                m.kind = 4;
                m.command = command.code();
                m.text = format!("{command:?} refused: {why}");
            }
            Event::DeviceReopened => {
                m.kind = 5;
                m.text = "device reopened after a disconnect".into();
            }
            Event::Stopped => {
                m.kind = 6;
                m.text = "stopped".into();
            }
            Event::HomeNeeded => {
                m.kind = 7;
                m.text = "homing lost: hold both grips still at their home points, or send Home".into();
            }
        }
        m
    }

    pub fn is_fault(&self) -> bool {
        self.kind == 2
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::{decode, encode, schema_text};

    #[test]
    fn a_tick_record_round_trips_bit_for_bit() {
        let mut r = TickRecord {
            tick: 42,
            t_s: 0.1 + 0.2,
            lateness_s: 3.3e-5,
            state: Lifecycle::Faulted,
            fault: Some(FaultReason::Device(ErrorKind::Corrupt)),
            contact_age_s: f64::INFINITY,
            io_error: Some(ErrorKind::Disconnected),
            reopened: true,
            ..Default::default()
        };
        r.hands[1].tensions_n = [1.0, f64::MIN_POSITIVE, -0.0, 9.75];
        r.hands[0].method = Method::Fallback;
        r.hands[0].pos_rig_m = DVec3::new(0.1, -0.2, 1e-300);
        r.commands.push(Command::Home);
        r.commands.push(Command::Stop);
        r.input.counts[3] = -123_456_789_012;
        r.output.volts[7] = 0.7;
        let mut buf = Vec::new();
        encode(&r, &mut buf);
        let back: TickRecord = decode(&buf).unwrap();
        assert_eq!(back, r);
        assert_eq!(back.hands[1].tensions_n[2].to_bits(), (-0.0f64).to_bits());
    }

    #[test]
    fn models_samples_and_events_round_trip() {
        let mut m = ContactModel { seq: 9, stamp_s: 1.25, ..Default::default() };
        m.push(Proxy {
            id: ProxyId { body: 3, part: 1 },
            shape: ProxyShape::Capsule { a_m: DVec3::X, b_m: DVec3::Y, radius_m: 0.05 },
            k_n_per_m: 2000.0,
            d_n_s_per_m: 3.0,
            vel_m_per_s: DVec3::Z,
            hand_mask: 2,
        });
        m.push(Proxy { shape: ProxyShape::Plane { point_m: DVec3::ONE, normal: DVec3::Z }, ..m.proxies[0] });
        let t = TakenModel { tick: 5, model: m };
        let mut buf = Vec::new();
        encode(&t, &mut buf);
        assert_eq!(decode::<TakenModel>(&buf).unwrap(), t);

        let mut s = HandSample { tick: 3, t_s: 0.003, model_seq: 9, ..Default::default() };
        s.hands[0].valid = true;
        s.proxy_impulse_n_s[15] = DVec3::new(1.0, 2.0, 3.0);
        encode(&s, &mut buf);
        assert_eq!(decode::<HandSample>(&buf).unwrap(), s);

        for e in [
            Event::State(Lifecycle::Active),
            Event::Fault(FaultReason::Residual { hand: 1 }),
            Event::Refused { command: Command::Activate, why: "not homed" },
            Event::Stopped,
        ] {
            let msg = EventMsg::new(7, 0.007, &e);
            encode(&msg, &mut buf);
            assert_eq!(decode::<EventMsg>(&buf).unwrap(), msg);
        }
    }

    #[test]
    fn unknown_codes_are_errors() {
        let r = TickRecord::default();
        let mut buf = Vec::new();
        encode(&r, &mut buf);
        // `state` is the byte after tick (8) and four float64 (32), right after the header.
        buf[4 + 40] = 9;
        let e = decode::<TickRecord>(&buf).unwrap_err();
        assert!(e.what.contains("lifecycle code 9"), "{e}");
    }

    #[test]
    fn schemas_name_every_nested_type_once() {
        let s = schema_text::<TickRecord>();
        assert!(s.starts_with("uint64 tick\n"));
        for t in ["spidar/HandTick", "spidar/Vec3", "spidar/Fault", "spidar/Commands", "spidar/DeviceInput"] {
            assert_eq!(s.matches(&format!("MSG: {t}\n")).count(), 1, "{t} in\n{s}");
        }
        let m = schema_text::<TakenModel>();
        for t in ["spidar/ContactModel", "spidar/Proxy", "spidar/ProxyShape", "spidar/ProxyId", "spidar/Vec3"]
        {
            assert_eq!(m.matches(&format!("MSG: {t}\n")).count(), 1, "{t} in\n{m}");
        }
    }
}
