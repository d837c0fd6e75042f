//! What is connected: serial ports (candidate UART board links) and USB devices (candidate USB
//! Simple / SH-4 boards), what each is and whether it can be opened. Behind `spidar devices`.
//!
//! Why it exists: the first thing a person setting up a rig needs is "which port is my board on,
//! and why can't I open it". What it must never do: send bytes to a serial port unless asked to
//! probe (an unknown device on a port may not like our enumeration), or panic without USB.

use std::time::Duration;

use crate::transport::PortSetting;
use crate::uart::{UartDevice, UartOptions};
use crate::usb::rusb_transport::{list_usb, UsbSeen};
use crate::usb::UsbKind;

/// One serial port.
#[derive(Clone, Debug)]
pub struct SerialSeen {
    pub path: String,
    /// What the OS says it is (USB adapter ids need the `udev` feature).
    pub kind: String,
    /// Ok(what answered) or why it could not be opened / probed.
    pub status: Result<String, String>,
}

/// Lists serial ports, plus `extra` paths (a pty from `spidar emulate` is not listed by the OS).
/// With `probe`, each port that opens is enumerated for UART boards.
pub fn serial_ports(extra: &[String], probe: bool) -> (Vec<SerialSeen>, Option<String>) {
    let mut found = Vec::new();
    let mut warning = None;
    let mut paths: Vec<(String, String)> = Vec::new();
    match serialport::available_ports() {
        Ok(ports) => {
            for p in ports {
                let kind = match &p.port_type {
                    serialport::SerialPortType::UsbPort(u) => format!(
                        "USB serial {:04x}:{:04x}{}",
                        u.vid,
                        u.pid,
                        u.product.as_deref().map(|s| format!(" ({s})")).unwrap_or_default()
                    ),
                    serialport::SerialPortType::PciPort => "PCI serial".into(),
                    serialport::SerialPortType::BluetoothPort => "Bluetooth serial".into(),
                    serialport::SerialPortType::Unknown => "serial".into(),
                };
                paths.push((p.port_name, kind));
            }
        }
        Err(e) => warning = Some(format!("cannot list serial ports: {e}")),
    }
    for e in extra {
        if !paths.iter().any(|(p, _)| p == e) {
            paths.push((e.clone(), "given with --port".into()));
        }
    }
    for (path, kind) in paths {
        let status = check_serial(&path, probe);
        found.push(SerialSeen { path, kind, status });
    }
    (found, warning)
}

fn check_serial(path: &str, probe: bool) -> Result<String, String> {
    let c = std::ffi::CString::new(path).map_err(|_| "bad path".to_string())?;
    if !probe {
        return crate::transport::open_serial(&c, crate::uart::protocol::BAUD)
            .map(|_| "opens (not probed: add --probe to ask for UART boards)".to_string())
            .map_err(|e| e.to_string());
    }
    let opts = UartOptions { enumerate_timeout: Duration::from_millis(10), ..UartOptions::default() };
    let mut dev = UartDevice::on_port(path, opts).map_err(|e| e.to_string())?;
    dev.open_detailed().map_err(|e| e.to_string())?;
    let r = probe_report(&dev);
    // The probe leaves the boards as it found them: zero commands.
    let _ = crate::Device::deactivate(&mut dev);
    Ok(r)
}

/// What `spidar devices --probe` says about the UART boards on an opened link: each board's
/// model, counts, firmware reply layout, the command lengths declared for it and what its
/// commands mean; the port's latency settings; and what will not work.
pub fn probe_report<C: crate::uart::Connector>(dev: &UartDevice<C>) -> String {
    use std::fmt::Write;
    let boards = dev.probed();
    let motors: usize = boards.iter().map(|b| usize::from(b.info.n_motor)).sum();
    let mut s = format!("UART boards: {}, {motors} channels", boards.len());
    for b in &boards {
        let i = &b.info;
        let kinds: Vec<&str> = b.commands[..usize::from(i.n_motor)].iter().map(|k| k.name()).collect();
        let mut kinds_dedup = kinds.clone();
        kinds_dedup.dedup();
        let _ = write!(
            s,
            "\n  id {} {}: {} motors ({}), {} current sensors, {} force sensors; {}, reply {} bytes\
             \n    command lengths declared, ids 0..11: {}",
            i.id,
            i.model_name(),
            i.n_motor,
            kinds_dedup.join(" / "),
            i.n_current,
            i.n_force,
            b.layout.firmware(),
            i.current_reply_len(b.layout),
            b.lengths.iter().map(|l| l.to_string()).collect::<Vec<_>>().join(" ")
        );
    }
    let setting = |p: PortSetting, done: &str| match p {
        PortSetting::Done => done.to_string(),
        PortSetting::NotApplicable => "not applicable (no such setting: a pseudo-terminal?)".to_string(),
        PortSetting::Failed(e) => format!("FAILED ({})", std::io::Error::from_raw_os_error(e)),
    };
    match dev.port_report() {
        Some(p) => {
            let _ = write!(
                s,
                "\n  port: low latency {}; DTR/RTS {}; adapter latency timer {}",
                setting(p.low_latency, "set"),
                setting(p.modem_lines_cleared, "cleared"),
                dev.latency_timer_ms()
                    .map_or("none (not a USB serial adapter with one)".into(), |ms| format!("{ms} ms"))
            );
        }
        None => s.push_str("\n  port: not a serial port"),
    }
    let mut warnings: Vec<String> = dev.warnings().to_vec();
    if motors < 8 {
        warnings.push(format!("{motors} motors: a SPIDAR-H needs 8 (two 4-motor boards)"));
    }
    for w in warnings {
        let _ = write!(s, "\n  warning: {w}");
    }
    s
}

/// One USB device, with what spidar makes of it.
#[derive(Clone, Debug)]
pub struct UsbReport {
    pub seen: UsbSeen,
    pub kind: Option<UsbKind>,
}

/// Lists USB devices; Err when USB cannot be used on this machine at all.
pub fn usb_devices() -> Result<Vec<UsbReport>, String> {
    Ok(list_usb()?
        .into_iter()
        .map(|s| {
            let kind =
                (s.vid == crate::usb::protocol::VENDOR_ID).then(|| UsbKind::from_product_id(s.pid)).flatten();
            UsbReport { seen: s, kind }
        })
        .collect())
}
