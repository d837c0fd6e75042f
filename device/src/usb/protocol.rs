//! The USB boards' transfer layouts (`docs/protocols.md`) as pure,
//! allocation-free encode/decode functions: the host side for the drivers, the board side for
//! the fake boards of the tests.
//!
//! What it must never do: touch USB, allocate, or panic on any input. A reply of the wrong length
//! is rejected; the protocols have no header or checksum in their replies, so that is the only
//! malformed frame a decoder can see (counter plausibility is the driver's check).

use crate::frame::exact_len;
pub use crate::frame::FrameError;

/// Vendor id of both boards.
pub const VENDOR_ID: u16 = 0x0CEC;
/// USB 2.0 "Simple" amplifier (8 DA + 8 counters).
pub const SIMPLE_PRODUCT_ID: u16 = 0x0203;
/// USB 2.0 SH-4 amplifier (8 DA + 8 counters + 8 A/D).
pub const SH4_PRODUCT_ID: u16 = 0x0205;
/// Bulk OUT endpoint of both boards.
pub const EP_OUT: u8 = 0x02;
/// Bulk IN endpoint of both boards.
pub const EP_IN: u8 = 0x86;
/// DA and counter channels of both boards.
pub const CHANNELS: usize = 8;
/// Default DA scale of both boards (measured per amplifier: configurable).
pub const DEFAULT_DIGITS_PER_VOLT: f64 = 415.0;

/// Transfer size of the Simple board, each way.
pub const SIMPLE_LEN: usize = 32;
/// Transfer size of the SH-4 board, each way.
pub const SH4_LEN: usize = 512;

/// Volts to a DA value: `volts x digits_per_volt`, rounded, clamped to `+-volts_max` and to i16;
/// NaN is 0. Never panics, for any input or range: a NaN or negative `volts_max` allows only 0.
pub fn volts_to_da(volts: f64, digits_per_volt: f64, volts_max: f64) -> i16 {
    let v = crate::clamp_symmetric(volts, volts_max);
    crate::clamp_symmetric((v * digits_per_volt).round(), f64::from(i16::MAX)) as i16
}

/// The board's rotary switch: bits 4..7 of the PIO input.
pub const fn switch_of_pio(pio: u16) -> u8 {
    ((pio >> 4) & 0x0F) as u8
}

// ---------------------------------------------------------------------------------------------
// USB Simple.

/// Simple: reset (`A2 1A FF`; byte 2 was described as a per-channel direction mask).
pub fn simple_reset(buf: &mut [u8; SIMPLE_LEN]) {
    buf.fill(0);
    buf[..3].copy_from_slice(&[0xA2, 0x1A, 0xFF]);
}

/// Simple: clear all counters (`A2 19 FF`).
pub fn simple_clear_counters(buf: &mut [u8; SIMPLE_LEN]) {
    buf.fill(0);
    buf[..3].copy_from_slice(&[0xA2, 0x19, 0xFF]);
}

/// Simple: set DA (`52` then 8 x i16 little-endian).
pub fn simple_set_da(da: &[i16; CHANNELS], buf: &mut [u8; SIMPLE_LEN]) {
    buf.fill(0);
    buf[0] = 0x52;
    for (i, v) in da.iter().enumerate() {
        buf[1 + 2 * i..3 + 2 * i].copy_from_slice(&v.to_le_bytes());
    }
}

/// Simple: request the counters (`51`); the board answers on the IN endpoint.
pub fn simple_request_counters(buf: &mut [u8; SIMPLE_LEN]) {
    buf.fill(0);
    buf[0] = 0x51;
}

/// The Simple board's answer to `51`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SimpleCounters {
    /// 24-bit signed counters, sign-extended.
    pub counts: [i32; CHANNELS],
    /// PIO input byte (switch in bits 4..7).
    pub pio: u8,
}

/// Decodes the 32-byte reply to `51`: 8 x 24-bit signed little-endian counters, then the PIO byte.
pub fn simple_decode_counters(bytes: &[u8]) -> Result<SimpleCounters, FrameError> {
    exact_len(bytes, SIMPLE_LEN)?;
    let mut r = SimpleCounters::default();
    for (i, c) in r.counts.iter_mut().enumerate() {
        let b = &bytes[3 * i..3 * i + 3];
        let raw = i32::from(b[0]) | (i32::from(b[1]) << 8) | (i32::from(b[2]) << 16);
        *c = (raw << 8) >> 8;
    }
    r.pio = bytes[24];
    Ok(r)
}

/// The board side of [`simple_decode_counters`] (fake boards in tests).
pub fn simple_encode_counters(r: &SimpleCounters, buf: &mut [u8; SIMPLE_LEN]) {
    buf.fill(0);
    for (i, c) in r.counts.iter().enumerate() {
        buf[3 * i..3 * i + 3].copy_from_slice(&c.to_le_bytes()[..3]);
    }
    buf[24] = r.pio;
}

/// What a host command to the Simple board is (the fake board's parser).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SimpleCommand {
    Reset { mask: u8 },
    ClearCounters,
    SetDa([i16; CHANNELS]),
    RequestCounters,
}

/// Decodes a host command to the Simple board (board side).
pub fn simple_decode_command(bytes: &[u8]) -> Result<SimpleCommand, FrameError> {
    exact_len(bytes, SIMPLE_LEN)?;
    match bytes[0] {
        0xA2 if bytes[1] == 0x1A => Ok(SimpleCommand::Reset { mask: bytes[2] }),
        0xA2 if bytes[1] == 0x19 => Ok(SimpleCommand::ClearCounters),
        0x52 => {
            let mut da = [0i16; CHANNELS];
            for (i, v) in da.iter_mut().enumerate() {
                *v = i16::from_le_bytes([bytes[1 + 2 * i], bytes[2 + 2 * i]]);
            }
            Ok(SimpleCommand::SetDa(da))
        }
        0x51 => Ok(SimpleCommand::RequestCounters),
        got => Err(FrameError::Header { want: 0x51, got }),
    }
}

// ---------------------------------------------------------------------------------------------
// USB SH-4.

/// SH-4: the 512-byte OUT packet: `01` (update all), `0E`, 8 x i16 DA, zeros.
pub fn sh4_encode_out(da: &[i16; CHANNELS], buf: &mut [u8; SH4_LEN]) {
    buf.fill(0);
    buf[0] = 0x01;
    buf[1] = 0x0E;
    for (i, v) in da.iter().enumerate() {
        buf[2 + 2 * i..4 + 2 * i].copy_from_slice(&v.to_le_bytes());
    }
}

/// SH-4: decodes the OUT packet (board side).
pub fn sh4_decode_out(bytes: &[u8]) -> Result<[i16; CHANNELS], FrameError> {
    exact_len(bytes, SH4_LEN)?;
    if bytes[0] != 0x01 || bytes[1] != 0x0E {
        return Err(FrameError::Header { want: 0x01, got: bytes[0] });
    }
    let mut da = [0i16; CHANNELS];
    for (i, v) in da.iter_mut().enumerate() {
        *v = i16::from_le_bytes([bytes[2 + 2 * i], bytes[3 + 2 * i]]);
    }
    Ok(da)
}

/// SH-4: the 512-byte IN packet.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Sh4In {
    /// Echo of the DA values (ignored by the driver).
    pub da_echo: [i16; CHANNELS],
    /// 16-bit wrapping encoder counters.
    pub counts: [u16; CHANNELS],
    /// A/D readings, 24 V / 4096 per digit.
    pub adc: [u16; CHANNELS],
    /// 16 PIO input bits (switch in bits 4..7).
    pub pio: u16,
    /// A field of unknown meaning: logged, never interpreted.
    pub unknown: u32,
}

/// Volts per A/D digit of the SH-4 board.
pub const SH4_ADC_VOLTS_PER_DIGIT: f64 = 24.0 / 4096.0;

pub fn sh4_decode_in(bytes: &[u8]) -> Result<Sh4In, FrameError> {
    exact_len(bytes, SH4_LEN)?;
    let w = |at: usize| u16::from_le_bytes([bytes[at], bytes[at + 1]]);
    let mut r = Sh4In::default();
    for i in 0..CHANNELS {
        r.da_echo[i] = w(2 * i) as i16;
        r.counts[i] = w(16 + 2 * i);
        r.adc[i] = w(32 + 2 * i);
    }
    r.pio = w(48);
    r.unknown = u32::from_le_bytes([bytes[50], bytes[51], bytes[52], bytes[53]]);
    Ok(r)
}

/// The board side of [`sh4_decode_in`].
pub fn sh4_encode_in(r: &Sh4In, buf: &mut [u8; SH4_LEN]) {
    buf.fill(0);
    for i in 0..CHANNELS {
        buf[2 * i..2 * i + 2].copy_from_slice(&r.da_echo[i].to_le_bytes());
        buf[16 + 2 * i..18 + 2 * i].copy_from_slice(&r.counts[i].to_le_bytes());
        buf[32 + 2 * i..34 + 2 * i].copy_from_slice(&r.adc[i].to_le_bytes());
    }
    buf[48..50].copy_from_slice(&r.pio.to_le_bytes());
    buf[50..54].copy_from_slice(&r.unknown.to_le_bytes());
}
