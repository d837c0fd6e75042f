//! The USB layouts byte by byte (docs/protocols.md, the USB sections), and the drivers
//! against fake boards that play the board's side of the bulk transfers.

use std::time::Duration;

use super::protocol::*;
use super::*;
use crate::transport::BulkTransport;
use crate::ErrorKind;

#[test]
fn simple_commands_have_the_documented_bytes() {
    let mut b = [0xEEu8; SIMPLE_LEN];
    simple_reset(&mut b);
    assert_eq!(&b[..4], &[0xA2, 0x1A, 0xFF, 0]);
    simple_clear_counters(&mut b);
    assert_eq!(&b[..4], &[0xA2, 0x19, 0xFF, 0]);
    simple_request_counters(&mut b);
    assert_eq!(b[0], 0x51);
    assert!(b[1..].iter().all(|&x| x == 0), "zero padded to 32 bytes");
    simple_set_da(&[415, -415, 0, 1, 2, 3, 4, -32767], &mut b);
    assert_eq!(&b[..5], &[0x52, 0x9F, 0x01, 0x61, 0xFE]);
    assert_eq!(&b[15..17], &[0x01, 0x80]);
    assert!(b[17..].iter().all(|&x| x == 0));
}

#[test]
fn simple_counters_are_24_bit_signed_little_endian_then_the_pio_byte() {
    let mut b = [0u8; SIMPLE_LEN];
    b[0..3].copy_from_slice(&[0xFF, 0xFF, 0xFF]); // -1
    b[3..6].copy_from_slice(&[0x00, 0x00, 0x80]); // -2^23
    b[6..9].copy_from_slice(&[0xFF, 0xFF, 0x7F]); // 2^23 - 1
    b[9..12].copy_from_slice(&[0x01, 0x02, 0x03]);
    b[24] = 0x35; // switch 3
    let r = simple_decode_counters(&b).unwrap();
    assert_eq!(&r.counts[..4], &[-1, -8_388_608, 8_388_607, 0x030201]);
    assert_eq!(switch_of_pio(u16::from(r.pio)), 3);
    let mut again = [0u8; SIMPLE_LEN];
    simple_encode_counters(&r, &mut again);
    assert_eq!(again, b);
    assert!(matches!(simple_decode_counters(&b[..31]), Err(FrameError::Short { need: 32, got: 31 })));
}

#[test]
fn sh4_packets_have_the_documented_layout() {
    let mut out = [0xEEu8; SH4_LEN];
    sh4_encode_out(&[415, -1, 0, 0, 0, 0, 0, 7], &mut out);
    assert_eq!(&out[..6], &[0x01, 0x0E, 0x9F, 0x01, 0xFF, 0xFF]);
    assert_eq!(&out[16..18], &[0x07, 0x00]);
    assert!(out[18..].iter().all(|&x| x == 0));
    let mut inb = [0u8; SH4_LEN];
    inb[16..18].copy_from_slice(&0xFFFEu16.to_le_bytes()); // counter 0
    inb[32..34].copy_from_slice(&2048u16.to_le_bytes()); // A/D 0: 12 V
    inb[48..50].copy_from_slice(&0x0050u16.to_le_bytes()); // switch 5
    inb[50..54].copy_from_slice(&0xDEADBEEFu32.to_le_bytes());
    let r = sh4_decode_in(&inb).unwrap();
    assert_eq!(r.counts[0], 0xFFFE);
    assert_eq!(f64::from(r.adc[0]) * SH4_ADC_VOLTS_PER_DIGIT, 12.0);
    assert_eq!(switch_of_pio(r.pio), 5);
    assert_eq!(r.unknown, 0xDEADBEEF);
    assert!(sh4_decode_in(&inb[..511]).is_err());
}

#[test]
fn da_scale_is_415_digits_per_volt_clamped_to_the_volt_limit() {
    assert_eq!(volts_to_da(1.0, DEFAULT_DIGITS_PER_VOLT, 10.0), 415);
    assert_eq!(volts_to_da(-20.0, DEFAULT_DIGITS_PER_VOLT, 10.0), -4150);
    assert_eq!(volts_to_da(f64::NAN, DEFAULT_DIGITS_PER_VOLT, 10.0), 0);
    assert_eq!(volts_to_da(1.0, 400.0, 10.0), 400);
}

/// A fake board of either kind: counters it is told, DA it received, faults to inject.
#[derive(Default)]
struct FakeBoard {
    sh4: bool,
    switch: u8,
    counts: [i64; CHANNELS],
    da: [i16; CHANNELS],
    resets: u32,
    pending: bool,
    short_reply: bool,
    unplugged: bool,
    /// Replies left in the IN endpoint by an earlier process (counts it had then).
    stale: Vec<[i64; CHANNELS]>,
    in_resets: u32,
}

struct FakeTransport(std::sync::Arc<std::sync::Mutex<FakeBoard>>);

impl BulkTransport for FakeTransport {
    fn bulk_write(&mut self, ep: u8, data: &[u8], _: Duration) -> Result<(), DeviceError> {
        let mut b = self.0.lock().unwrap();
        assert_eq!(ep, EP_OUT);
        if b.unplugged {
            return Err(DeviceError::Disconnected { what: "fake unplugged" });
        }
        if b.sh4 {
            b.da = sh4_decode_out(data).expect("the driver sends valid SH-4 packets");
            b.pending = true;
        } else {
            match simple_decode_command(data).expect("the driver sends valid Simple commands") {
                SimpleCommand::Reset { .. } => b.resets += 1,
                SimpleCommand::ClearCounters => b.counts = [0; CHANNELS],
                SimpleCommand::SetDa(da) => b.da = da,
                SimpleCommand::RequestCounters => b.pending = true,
            }
        }
        Ok(())
    }
    fn bulk_read(&mut self, ep: u8, buf: &mut [u8], _: Duration) -> Result<usize, DeviceError> {
        let mut b = self.0.lock().unwrap();
        assert_eq!(ep, EP_IN);
        if b.unplugged {
            return Err(DeviceError::Disconnected { what: "fake unplugged" });
        }
        let counts = if !b.stale.is_empty() {
            b.stale.remove(0)
        } else if std::mem::take(&mut b.pending) {
            b.counts
        } else {
            return Err(DeviceError::Timeout { waited_us: 0 });
        };
        let pio = u16::from(b.switch) << 4;
        let n = if b.sh4 {
            let r = Sh4In {
                da_echo: b.da,
                counts: counts.map(|c| c as u16),
                pio,
                unknown: 42,
                ..Default::default()
            };
            let mut p = [0u8; SH4_LEN];
            sh4_encode_in(&r, &mut p);
            buf[..SH4_LEN].copy_from_slice(&p);
            SH4_LEN
        } else {
            let r = SimpleCounters { counts: counts.map(|c| c as i32), pio: pio as u8 };
            let mut p = [0u8; SIMPLE_LEN];
            simple_encode_counters(&r, &mut p);
            buf[..SIMPLE_LEN].copy_from_slice(&p);
            SIMPLE_LEN
        };
        Ok(if b.short_reply { n - 1 } else { n })
    }
    fn reset_in(&mut self, ep: u8) -> Result<(), DeviceError> {
        assert_eq!(ep, EP_IN);
        self.0.lock().unwrap().in_resets += 1;
        Ok(())
    }
}

type Shared = std::sync::Arc<std::sync::Mutex<FakeBoard>>;

struct FakeBus {
    boards: Vec<(u16, Shared)>,
    denied: bool,
}

impl UsbOpener for FakeBus {
    type Link = FakeTransport;
    fn candidates(&mut self, vid: u16, pid: u16) -> Result<Vec<(String, FakeTransport)>, OpenError> {
        if self.denied {
            return Err(OpenError::Permission {
                what: "0cec:0203".into(),
                fix: rusb_transport::UDEV_FIX.into(),
            });
        }
        assert_eq!(vid, VENDOR_ID);
        Ok(self
            .boards
            .iter()
            .enumerate()
            .filter(|(_, (p, _))| *p == pid)
            .map(|(i, (_, b))| (format!("bus 1 addr {}", i + 2), FakeTransport(b.clone())))
            .collect())
    }
    fn seen(&mut self) -> String {
        "1d6b:0002, 046d:c52b".into()
    }
}

fn board(sh4: bool, switch: u8) -> Shared {
    std::sync::Arc::new(std::sync::Mutex::new(FakeBoard { sh4, switch, ..Default::default() }))
}

#[test]
fn simple_driver_picks_the_board_by_switch_resets_it_and_scales_the_da() {
    let (a, b) = (board(false, 1), board(false, 3));
    let bus = FakeBus {
        boards: vec![(SIMPLE_PRODUCT_ID, a.clone()), (SIMPLE_PRODUCT_ID, b.clone())],
        denied: false,
    };
    let mut d = UsbBoard::new(UsbKind::Simple, bus, UsbOptions { switch: Some(3), ..Default::default() });
    d.open_detailed().unwrap();
    assert_eq!(d.switch(), 3);
    assert!(d.info().identity.contains("switch 3"));
    assert_eq!(b.lock().unwrap().resets, 1);
    d.activate().unwrap();
    let mut out = Output::default();
    out.volts[0] = 1.0;
    out.volts[7] = -2.0;
    let mut inp = Input::default();
    d.exchange(&out, &mut inp).unwrap();
    assert_eq!(b.lock().unwrap().da[0], 415);
    assert_eq!(b.lock().unwrap().da[7], -830);
    assert_eq!(a.lock().unwrap().da, [0; CHANNELS], "the other board is not driven");
    assert_eq!(inp.status >> STATUS_PIO_SHIFT, 0x30);
}

#[test]
fn simple_counters_extend_across_the_24_bit_wrap() {
    let b = board(false, 0);
    let bus = FakeBus { boards: vec![(SIMPLE_PRODUCT_ID, b.clone())], denied: false };
    let mut d = UsbBoard::new(UsbKind::Simple, bus, UsbOptions::default());
    d.open_detailed().unwrap();
    let mut inp = Input::default();
    // Counters start at 0 after the open's clear; 4000 counts a tick for 2100 ticks passes
    // 2^23 - 1, where the 24-bit value on the wire wraps to negative.
    for step in 0..2100i64 {
        b.lock().unwrap().counts[2] = 4000 * step;
        d.exchange(&Output::default(), &mut inp).unwrap();
        assert_eq!(inp.counts[2], 4000 * step);
    }
    assert!(inp.counts[2] > 1 << 23);
}

#[test]
fn sh4_driver_extends_16_bit_counters_and_keeps_the_unknown_field_for_logs() {
    let b = board(true, 5);
    let bus = FakeBus { boards: vec![(SH4_PRODUCT_ID, b.clone())], denied: false };
    let mut d = UsbBoard::new(UsbKind::Sh4, bus, UsbOptions::default());
    d.open_detailed().unwrap();
    d.activate().unwrap();
    let mut inp = Input::default();
    for step in 0..100i64 {
        b.lock().unwrap().counts[1] = -1000 * step; // wraps below 0 and then past -32768
        let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
        d.exchange(&out, &mut inp).unwrap();
        assert_eq!(inp.counts[1], -1000 * step);
    }
    assert_eq!(b.lock().unwrap().da[3], 208); // 0.5 V x 415, rounded
    assert_eq!(d.unknown_field(), 42);
    assert_eq!(d.switch(), 5);
}

#[test]
fn short_transfers_and_unplugging_map_to_corrupt_and_disconnected() {
    let b = board(false, 0);
    let bus = FakeBus { boards: vec![(SIMPLE_PRODUCT_ID, b.clone())], denied: false };
    let mut d = UsbBoard::new(UsbKind::Simple, bus, UsbOptions::default());
    d.open().unwrap();
    let mut inp = Input::default();
    b.lock().unwrap().short_reply = true;
    assert_eq!(d.exchange(&Output::default(), &mut inp).unwrap_err().kind(), ErrorKind::Corrupt);
    b.lock().unwrap().short_reply = false;
    d.exchange(&Output::default(), &mut inp).unwrap();
    b.lock().unwrap().unplugged = true;
    assert_eq!(d.exchange(&Output::default(), &mut inp).unwrap_err().kind(), ErrorKind::Disconnected);
    b.lock().unwrap().unplugged = false;
    let e = d.exchange(&Output::default(), &mut inp).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Disconnected, "the handle is gone: {e}");
}

#[test]
fn not_found_wrong_switch_and_permission_errors_say_what_was_found_and_what_to_do() {
    let bus = FakeBus { boards: vec![(SH4_PRODUCT_ID, board(true, 2))], denied: false };
    let mut d = UsbBoard::new(UsbKind::Simple, bus, UsbOptions::default());
    let msg = d.open_detailed().unwrap_err().to_string();
    assert!(msg.contains("0cec:0203") && msg.contains("046d:c52b"), "{msg}");

    let bus = FakeBus { boards: vec![(SH4_PRODUCT_ID, board(true, 2))], denied: false };
    let mut d = UsbBoard::new(UsbKind::Sh4, bus, UsbOptions { switch: Some(4), ..Default::default() });
    let msg = d.open_detailed().unwrap_err().to_string();
    assert!(msg.contains("switch 4") && msg.contains("switch 2"), "{msg}");

    let bus = FakeBus {
        boards: vec![(SH4_PRODUCT_ID, board(true, 2)), (SH4_PRODUCT_ID, board(true, 6))],
        denied: false,
    };
    let mut d = UsbBoard::new(UsbKind::Sh4, bus, UsbOptions::default());
    let msg = d.open_detailed().unwrap_err().to_string();
    assert!(msg.contains("--switch") && msg.contains("switch 6"), "{msg}");

    let bus = FakeBus { boards: vec![], denied: true };
    let mut d = UsbBoard::new(UsbKind::Simple, bus, UsbOptions::default());
    let msg = d.open_detailed().unwrap_err().to_string();
    assert!(msg.contains("99-spidar.rules"), "{msg}");
}

#[test]
fn usb_exchange_allocates_nothing_in_the_driver() {
    let b = board(true, 0);
    let bus = FakeBus { boards: vec![(SH4_PRODUCT_ID, b)], denied: false };
    let mut d = UsbBoard::new(UsbKind::Sh4, bus, UsbOptions::default());
    d.open().unwrap();
    d.activate().unwrap();
    let out = Output { volts: [0.5; crate::MAX_CHANNELS] };
    let mut inp = Input::default();
    let n = crate::sim::tests::allocations_during(|| {
        for _ in 0..100 {
            d.exchange(&out, &mut inp).unwrap();
        }
    });
    assert_eq!(n, 0);
}

#[test]
fn a_stale_reply_left_in_the_in_endpoint_is_read_away_at_open_on_both_boards() {
    for sh4 in [true, false] {
        let b = board(sh4, 1);
        // A killed process asked for the counters and never read them: two packets wait.
        b.lock().unwrap().stale = vec![[9000; CHANNELS], [9001; CHANNELS]];
        let kind = if sh4 { UsbKind::Sh4 } else { UsbKind::Simple };
        let pid = kind.product_id();
        let bus = FakeBus { boards: vec![(pid, b.clone())], denied: false };
        let mut d = UsbBoard::new(kind, bus, UsbOptions::default());
        d.open_detailed().unwrap();
        assert_eq!(b.lock().unwrap().in_resets, 1, "the IN endpoint is reset at open");
        assert_eq!(d.stale_packets(), 2);
        let mut inp = Input::default();
        for step in 1..20i64 {
            b.lock().unwrap().counts[0] = 10 * step;
            d.exchange(&Output::default(), &mut inp).unwrap();
            assert_eq!(inp.counts[0], 10 * step, "each reply is this tick's, not one behind");
        }
    }
}

#[test]
fn the_default_da_limit_is_what_the_spidar_h_needs_not_10_volts() {
    let o = UsbOptions::default();
    assert_eq!(o.volts_max, DEFAULT_DA_LIMIT_V);
    assert!(o.volts_max < 5.0);
    assert_eq!(volts_to_da(10.0, o.digits_per_volt, o.volts_max), 1660);
}
