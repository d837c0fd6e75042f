//! The real USB transport: libusb through `rusb`, behind [`BulkTransport`] and [`UsbOpener`].
//!
//! Always through an explicit `rusb::Context` whose creation error is handled: on a machine
//! without USB (a VM, a container) libusb cannot start, and rusb's global helpers panic there.

use std::time::Duration;

use rusb::UsbContext;

use super::UsbOpener;
use crate::transport::BulkTransport;
use crate::{DeviceError, OpenError};

/// The udev rule file shipped with spidar and how to install it.
pub const UDEV_FIX: &str = "install spidar's udev rule and replug the board: \
     sudo cp configs/udev/99-spidar.rules /etc/udev/rules.d/ && sudo udevadm control --reload-rules \
     && sudo udevadm trigger (the rule gives the 'plugdev' group access; add yourself to it and log in again)";

/// An opened, claimed board.
pub struct RusbTransport {
    handle: rusb::DeviceHandle<rusb::Context>,
}

fn map(e: rusb::Error, doing: &'static str) -> DeviceError {
    match e {
        rusb::Error::Timeout => DeviceError::Timeout { waited_us: 0 },
        rusb::Error::NoDevice => DeviceError::Disconnected { what: "USB board unplugged" },
        rusb::Error::Pipe | rusb::Error::Overflow => DeviceError::Corrupt { what: doing },
        rusb::Error::Access => {
            DeviceError::Other { what: "USB permission denied: install configs/udev/99-spidar.rules" }
        }
        _ => DeviceError::Other { what: doing },
    }
}

impl BulkTransport for RusbTransport {
    fn bulk_write(&mut self, ep: u8, data: &[u8], timeout: Duration) -> Result<(), DeviceError> {
        let n = self.handle.write_bulk(ep, data, timeout).map_err(|e| map(e, "USB bulk write failed"))?;
        if n != data.len() {
            return Err(DeviceError::Corrupt { what: "short USB bulk write" });
        }
        Ok(())
    }
    fn bulk_read(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError> {
        self.handle.read_bulk(ep, buf, timeout).map_err(|e| map(e, "USB bulk read failed"))
    }
    fn reset_in(&mut self, ep: u8) -> Result<(), DeviceError> {
        self.handle.clear_halt(ep).map_err(|e| map(e, "USB clear halt on the IN endpoint failed"))
    }
}

/// Opens boards through libusb.
pub struct RusbOpener {
    ctx: rusb::Context,
}

impl RusbOpener {
    pub fn new() -> Result<RusbOpener, OpenError> {
        let ctx = rusb::Context::new().map_err(|e| OpenError::Device {
            what: format!("USB is not available on this machine (libusb: {e})"),
            source: DeviceError::Other {
                what: "libusb sees no USB bus (a VM or container without USB passthrough?)",
            },
        })?;
        Ok(RusbOpener { ctx })
    }
}

/// One USB device on the bus.
#[derive(Clone, Debug)]
pub struct UsbSeen {
    pub bus: u8,
    pub address: u8,
    pub vid: u16,
    pub pid: u16,
    /// Whether it could be opened (None: not tried).
    pub openable: Option<Result<(), String>>,
}

impl UsbSeen {
    pub fn place(&self) -> String {
        format!("bus {} addr {}", self.bus, self.address)
    }
}

/// Lists the USB devices (opening the SPIDAR boards to see whether permissions allow it).
pub fn list_usb() -> Result<Vec<UsbSeen>, String> {
    let ctx =
        rusb::Context::new().map_err(|e| format!("USB is not available on this machine (libusb: {e})"))?;
    let devs = ctx.devices().map_err(|e| format!("cannot list USB devices: {e}"))?;
    let mut out = Vec::new();
    for d in devs.iter() {
        let Ok(desc) = d.device_descriptor() else { continue };
        let ours = desc.vendor_id() == super::protocol::VENDOR_ID;
        let openable = ours.then(|| match d.open() {
            Ok(_) => Ok(()),
            Err(rusb::Error::Access) => Err(format!("permission denied: {UDEV_FIX}")),
            Err(e) => Err(e.to_string()),
        });
        out.push(UsbSeen {
            bus: d.bus_number(),
            address: d.address(),
            vid: desc.vendor_id(),
            pid: desc.product_id(),
            openable,
        });
    }
    Ok(out)
}

impl UsbOpener for RusbOpener {
    type Link = RusbTransport;

    fn candidates(&mut self, vid: u16, pid: u16) -> Result<Vec<(String, RusbTransport)>, OpenError> {
        let devs = self.ctx.devices().map_err(|e| OpenError::Device {
            what: format!("cannot list USB devices ({e})"),
            source: DeviceError::Other { what: "USB listing failed" },
        })?;
        let mut out = Vec::new();
        for d in devs.iter() {
            let Ok(desc) = d.device_descriptor() else { continue };
            if desc.vendor_id() != vid || desc.product_id() != pid {
                continue;
            }
            let place = format!("bus {} addr {}", d.bus_number(), d.address());
            let handle = d.open().map_err(|e| match e {
                rusb::Error::Access => OpenError::Permission {
                    what: format!("{vid:04x}:{pid:04x} at {place}"),
                    fix: UDEV_FIX.into(),
                },
                e => OpenError::Device {
                    what: format!("opening {vid:04x}:{pid:04x} at {place} ({e})"),
                    source: map(e, "USB open failed"),
                },
            })?;
            let _ = handle.set_auto_detach_kernel_driver(true);
            handle.claim_interface(0).map_err(|e| OpenError::Device {
                what: format!("claiming interface 0 of {vid:04x}:{pid:04x} at {place} ({e}); is another program using it?"),
                source: map(e, "USB claim failed"),
            })?;
            out.push((place, RusbTransport { handle }));
        }
        Ok(out)
    }

    fn seen(&mut self) -> String {
        match self.ctx.devices() {
            Ok(devs) => {
                let v: Vec<String> = devs
                    .iter()
                    .filter_map(|d| d.device_descriptor().ok())
                    .map(|d| format!("{:04x}:{:04x}", d.vendor_id(), d.product_id()))
                    .collect();
                if v.is_empty() {
                    "none".into()
                } else {
                    v.join(", ")
                }
            }
            Err(e) => format!("(cannot list: {e})"),
        }
    }
}
