//! The `usb_simple` and `usb_sh4` backends: the USB 2.0 amplifier boards of the original
//! SPIDAR-H rigs (`docs/protocols.md`), 8 DA channels and 8 counters each.
//!
//! Why it exists: labs still run rigs on these boards. The byte layouts are in [`protocol`]; this
//! module identifies the board (by USB id and rotary switch), moves one OUT and one IN transfer
//! per tick through a [`BulkTransport`], and extends the counters (24-bit on Simple, 16-bit on SH-4)
//! to i64. Tests run it against fake boards behind the same trait; [`rusb_transport`] is the real
//! transport. What it must never do: allocate in its own code, lock or panic in `exchange`, or
//! block past the deadline (libusb's timeouts have a 1 ms resolution, so a transfer may take up
//! to 1 ms). libusb's synchronous transfers allocate inside C; a lost USB board is not reopened
//! from the tick (finding it again means enumerating the bus, which allocates): restart spidar.
//!
//! At open the IN endpoint is reset (clear halt) and any packet still waiting in it is read away,
//! on both boards: a reply left by a process that was killed between its request and its read
//! would otherwise shift every later reply by one tick.
//!
//! Counter signs: this driver reports both boards' counters as they come off the wire. The lab's
//! SH-4 host code stored the count negated and its Simple-board code did not, so a rig file
//! ported from the lab's code for an SH-4 rig needs the sign of each string's `metres_per_count`
//! flipped (one written for the Simple board needs nothing).

pub mod protocol;
pub mod rusb_transport;

use std::time::{Duration, Instant};

use crate::frame::Unwrap;
use crate::transport::BulkTransport;
use crate::{short_string, Device, DeviceError, DeviceInfo, Input, OpenError, Output, MAX_CHANNELS};
use protocol::{CHANNELS, EP_IN, EP_OUT, SH4_LEN, SIMPLE_LEN};

/// `Input::status`: bit 0 = outputs enabled, bits 8..23 = the board's PIO inputs.
pub const STATUS_ACTIVE: u32 = 1;
pub const STATUS_PIO_SHIFT: u32 = 8;

/// Which USB board.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum UsbKind {
    Simple,
    Sh4,
}

impl UsbKind {
    pub fn product_id(self) -> u16 {
        match self {
            UsbKind::Simple => protocol::SIMPLE_PRODUCT_ID,
            UsbKind::Sh4 => protocol::SH4_PRODUCT_ID,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            UsbKind::Simple => "USB Simple amplifier",
            UsbKind::Sh4 => "USB SH-4 amplifier",
        }
    }
    pub fn from_product_id(pid: u16) -> Option<UsbKind> {
        match pid {
            protocol::SIMPLE_PRODUCT_ID => Some(UsbKind::Simple),
            protocol::SH4_PRODUCT_ID => Some(UsbKind::Sh4),
            _ => None,
        }
    }
}

/// Finds and opens boards on the bus (set-up time: may allocate).
pub trait UsbOpener: Send {
    type Link: BulkTransport;
    /// Every attached device with these ids, opened and claimed, with where it is ("bus 1 addr 4").
    fn candidates(&mut self, vid: u16, pid: u16) -> Result<Vec<(String, Self::Link)>, OpenError>;
    /// A one-line list of the USB devices seen, for "not found" messages.
    fn seen(&mut self) -> String;
}

/// Default DA limit: what the lab's SPIDAR-H needs (20 N at 0.2 V/N is 4 V; the lab never
/// commanded more than about 3.65 V). The tools take the limit from the rig file.
pub const DEFAULT_DA_LIMIT_V: f64 = 4.0;

/// Most stale packets read away from the IN endpoint at open.
const STALE_PACKETS_MAX: usize = 8;

/// Settings of a USB board driver.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UsbOptions {
    /// The board's rotary switch (0..15); None: the only board attached.
    pub switch: Option<u8>,
    /// DA scale: digits per volt (415 as measured on the lab's amplifiers).
    pub digits_per_volt: f64,
    /// DA commands are clamped to +-this many volts.
    pub volts_max: f64,
    /// Deadline of one exchange (rounded up to libusb's 1 ms per transfer).
    pub reply_timeout: Duration,
    /// Largest counter step in one tick that is believed.
    pub max_step_counts: i64,
}

impl Default for UsbOptions {
    fn default() -> Self {
        UsbOptions {
            switch: None,
            digits_per_volt: protocol::DEFAULT_DIGITS_PER_VOLT,
            volts_max: DEFAULT_DA_LIMIT_V,
            reply_timeout: Duration::from_micros(800),
            max_step_counts: 4096,
        }
    }
}

/// A USB Simple or SH-4 board; see the module doc.
pub struct UsbBoard<O: UsbOpener> {
    kind: UsbKind,
    opener: O,
    link: Option<O::Link>,
    opts: UsbOptions,
    wrap24: [Unwrap<24>; CHANNELS],
    wrap16: [Unwrap<16>; CHANNELS],
    info: DeviceInfo,
    opened: bool,
    active: bool,
    pio: u16,
    adc: [u16; CHANNELS],
    unknown: u32,
    /// Packets found waiting in the IN endpoint at open (left by an earlier process).
    stale_packets: u32,
    small: [u8; SIMPLE_LEN],
    big: [u8; SH4_LEN],
}

impl<O: UsbOpener> UsbBoard<O> {
    pub fn new(kind: UsbKind, opener: O, opts: UsbOptions) -> Self {
        UsbBoard {
            kind,
            opener,
            link: None,
            opts,
            wrap24: [Unwrap::new(); CHANNELS],
            wrap16: [Unwrap::new(); CHANNELS],
            info: DeviceInfo {
                board: short_string(kind.name()),
                identity: heapless::String::new(),
                channels: CHANNELS,
                volts_min: 0.0,
                volts_max: 0.0,
            },
            opened: false,
            active: false,
            pio: 0,
            adc: [0; CHANNELS],
            unknown: 0,
            stale_packets: 0,
            small: [0; SIMPLE_LEN],
            big: [0; SH4_LEN],
        }
    }

    pub fn kind(&self) -> UsbKind {
        self.kind
    }
    /// The rotary switch read at open.
    pub fn switch(&self) -> u8 {
        protocol::switch_of_pio(self.pio)
    }
    /// SH-4 A/D readings in volts (motor supply / voltage sense); zeros on the Simple board.
    pub fn adc_volts(&self) -> [f64; CHANNELS] {
        self.adc.map(|d| f64::from(d) * protocol::SH4_ADC_VOLTS_PER_DIGIT)
    }
    /// Packets that were waiting in the IN endpoint at open and were read away.
    pub fn stale_packets(&self) -> u32 {
        self.stale_packets
    }
    /// SH-4: the last value of the IN packet's field of unknown meaning (bytes 50..53), for logs.
    pub fn unknown_field(&self) -> u32 {
        self.unknown
    }

    /// Finds the board (by switch when given), resets it, with errors that say what was found.
    pub fn open_detailed(&mut self) -> Result<(), OpenError> {
        self.link = None;
        self.opened = false;
        self.active = false;
        let vid = protocol::VENDOR_ID;
        let pid = self.kind.product_id();
        let cands = self.opener.candidates(vid, pid)?;
        if cands.is_empty() {
            return Err(OpenError::NoUsbBoard {
                board: self.kind.name(),
                vid,
                pid,
                found: self.opener.seen(),
            });
        }
        let mut switches = Vec::new();
        let mut chosen = None;
        let n = cands.len();
        for (place, mut link) in cands {
            let switch = match self.identify(&mut link) {
                Ok(s) => s,
                Err(e) => {
                    switches.push(format!("{place}: no valid answer ({e})"));
                    continue;
                }
            };
            switches.push(format!("{place}: switch {switch}"));
            let wanted = match self.opts.switch {
                Some(s) => s == switch,
                None => n == 1,
            };
            if wanted && chosen.is_none() {
                chosen = Some((place, link));
            }
        }
        let Some((place, link)) = chosen else {
            return Err(OpenError::WrongBoard {
                what: match self.opts.switch {
                    Some(s) => {
                        format!("no {} with switch {s}; found {}", self.kind.name(), switches.join(", "))
                    }
                    None => format!(
                        "{n} boards of kind {} and none chosen; found {}: choose one with --switch",
                        self.kind.name(),
                        switches.join(", ")
                    ),
                },
            });
        };
        let switch = protocol::switch_of_pio(self.pio);
        self.info = DeviceInfo {
            board: short_string(self.kind.name()),
            identity: short_string(&format!("switch {switch}, {place}")),
            channels: CHANNELS,
            volts_min: -self.opts.volts_max,
            volts_max: self.opts.volts_max,
        };
        self.link = Some(link);
        self.opened = true;
        Ok(())
    }

    /// Resets the IN endpoint and reads away stale packets, resets the board, reads its counters
    /// once (restarting the wrap extension) and returns the switch. Leaves the DA at zero.
    fn identify(&mut self, link: &mut O::Link) -> Result<u8, DeviceError> {
        let t = Duration::from_millis(100);
        self.wrap24 = [Unwrap::new(); CHANNELS];
        self.wrap16 = [Unwrap::new(); CHANNELS];
        link.reset_in(EP_IN)?;
        self.stale_packets = 0;
        for _ in 0..STALE_PACKETS_MAX {
            match link.bulk_read(EP_IN, &mut self.big[..], Duration::from_millis(1)) {
                Ok(_) => self.stale_packets += 1,
                Err(DeviceError::Timeout { .. }) => break,
                Err(e) => return Err(e),
            }
        }
        match self.kind {
            UsbKind::Simple => {
                protocol::simple_reset(&mut self.small);
                link.bulk_write(EP_OUT, &self.small, t)?;
                protocol::simple_clear_counters(&mut self.small);
                link.bulk_write(EP_OUT, &self.small, t)?;
            }
            UsbKind::Sh4 => {}
        }
        let mut inp = Input::default();
        let deadline = Instant::now() + t;
        let (kind, opts) = (self.kind, self.opts);
        transfer(kind, link, &opts, false, &Output::default(), &mut inp, deadline, self.state())?;
        Ok(protocol::switch_of_pio(self.pio))
    }

    fn state(&mut self) -> State<'_> {
        State {
            wrap24: &mut self.wrap24,
            wrap16: &mut self.wrap16,
            pio: &mut self.pio,
            adc: &mut self.adc,
            unknown: &mut self.unknown,
            small: &mut self.small,
            big: &mut self.big,
        }
    }
}

/// The driver state one transfer updates (split from `UsbBoard` so the link can be borrowed apart).
struct State<'a> {
    wrap24: &'a mut [Unwrap<24>; CHANNELS],
    wrap16: &'a mut [Unwrap<16>; CHANNELS],
    pio: &'a mut u16,
    adc: &'a mut [u16; CHANNELS],
    unknown: &'a mut u32,
    small: &'a mut [u8; SIMPLE_LEN],
    big: &'a mut [u8; SH4_LEN],
}

/// The time left to `deadline` as a libusb timeout (at least 1 ms: 0 would mean "forever").
fn usb_timeout(deadline: Instant, waited_from: Instant) -> Result<Duration, DeviceError> {
    let now = Instant::now();
    if now >= deadline {
        return Err(DeviceError::Timeout { waited_us: now.duration_since(waited_from).as_micros() as u32 });
    }
    Ok((deadline - now).max(Duration::from_millis(1)))
}

/// One servo exchange on `link`: DA out, counters in. Decodes fully before committing anything.
#[allow(clippy::too_many_arguments)]
fn transfer<L: BulkTransport>(
    kind: UsbKind,
    link: &mut L,
    opts: &UsbOptions,
    active: bool,
    out: &Output,
    inp: &mut Input,
    deadline: Instant,
    st: State<'_>,
) -> Result<(), DeviceError> {
    let from = Instant::now();
    let mut da = [0i16; CHANNELS];
    if active {
        for (d, v) in da.iter_mut().zip(out.volts.iter()) {
            *d = protocol::volts_to_da(*v, opts.digits_per_volt, opts.volts_max);
        }
    }
    let mut counts = [0i64; MAX_CHANNELS];
    let pio;
    match kind {
        UsbKind::Simple => {
            protocol::simple_set_da(&da, st.small);
            link.bulk_write(EP_OUT, &st.small[..], usb_timeout(deadline, from)?)?;
            protocol::simple_request_counters(st.small);
            link.bulk_write(EP_OUT, &st.small[..], usb_timeout(deadline, from)?)?;
            let n = link.bulk_read(EP_IN, &mut st.small[..], usb_timeout(deadline, from)?)?;
            let r = protocol::simple_decode_counters(&st.small[..n])?;
            let mut w = *st.wrap24;
            for i in 0..CHANNELS {
                counts[i] = w[i].update(i64::from(r.counts[i]), opts.max_step_counts)?;
            }
            *st.wrap24 = w;
            pio = u16::from(r.pio);
        }
        UsbKind::Sh4 => {
            protocol::sh4_encode_out(&da, st.big);
            link.bulk_write(EP_OUT, &st.big[..], usb_timeout(deadline, from)?)?;
            let n = link.bulk_read(EP_IN, &mut st.big[..], usb_timeout(deadline, from)?)?;
            let r = protocol::sh4_decode_in(&st.big[..n])?;
            let mut w = *st.wrap16;
            for i in 0..CHANNELS {
                counts[i] = w[i].update(i64::from(r.counts[i]), opts.max_step_counts)?;
            }
            *st.wrap16 = w;
            *st.adc = r.adc;
            *st.unknown = r.unknown;
            pio = r.pio;
        }
    }
    *st.pio = pio;
    inp.counts = counts;
    inp.status = (u32::from(active) * STATUS_ACTIVE) | (u32::from(pio) << STATUS_PIO_SHIFT);
    Ok(())
}

impl<O: UsbOpener> Device for UsbBoard<O> {
    fn open(&mut self) -> Result<(), DeviceError> {
        self.open_detailed().map_err(|e| e.kind_error())
    }

    fn activate(&mut self) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "activate before open")?;
        self.active = true;
        Ok(())
    }

    fn deactivate(&mut self) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "deactivate before open")?;
        self.active = false;
        let mut scratch = Input::default();
        self.exchange(&Output::default(), &mut scratch)
    }

    fn exchange(&mut self, out: &Output, inp: &mut Input) -> Result<(), DeviceError> {
        crate::require_open(self.opened, "exchange before open")?;
        let deadline = Instant::now() + self.opts.reply_timeout;
        let Some(mut link) = self.link.take() else {
            return Err(DeviceError::Disconnected {
                what: "USB board gone: reconnect it and restart spidar",
            });
        };
        let (kind, active) = (self.kind, self.active);
        let opts = self.opts;
        let r = transfer(kind, &mut link, &opts, active, out, inp, deadline, self.state());
        if !matches!(r, Err(DeviceError::Disconnected { .. })) {
            self.link = Some(link);
        }
        r
    }

    fn info(&self) -> &DeviceInfo {
        &self.info
    }
}

#[cfg(test)]
mod tests;
