//! The transports under the board drivers: a byte stream (a serial port) and bulk transfers (USB).
//!
//! Why it exists: the protocol code of every board is pure encode/decode over byte buffers, and
//! the drivers move those buffers through one of these two small traits. Tests put a fake board
//! behind the trait and check the bytes exactly; the real transports (a serial file descriptor,
//! a libusb handle) are thin. What they must never do: allocate, lock or block past the deadline
//! they are given, or panic; every failure becomes a `Copy` [`DeviceError`].

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::time::{Duration, Instant};

use crate::DeviceError;

/// A byte stream with deadlines (a serial port, a pseudo-terminal).
pub trait ByteTransport: Send {
    /// Writes all of `bytes`, or fails once `deadline` has passed.
    fn write_all(&mut self, bytes: &[u8], deadline: Instant) -> Result<(), DeviceError>;
    /// Fills all of `buf`, or fails with `Timeout` once `deadline` has passed.
    fn read_exact(&mut self, buf: &mut [u8], deadline: Instant) -> Result<(), DeviceError>;
    /// Throws away whatever has been received and not read (late or extra replies).
    fn clear_input(&mut self) -> Result<(), DeviceError>;
    /// What the port's set-up managed (serial ports only).
    fn port_report(&self) -> Option<PortReport> {
        None
    }
}

/// USB bulk transfers with a timeout.
pub trait BulkTransport: Send {
    /// Writes `data` to the OUT endpoint `ep`.
    fn bulk_write(&mut self, ep: u8, data: &[u8], timeout: Duration) -> Result<(), DeviceError>;
    /// Reads one transfer from the IN endpoint `ep` into `buf`; returns the bytes received.
    fn bulk_read(&mut self, ep: u8, buf: &mut [u8], timeout: Duration) -> Result<usize, DeviceError>;
    /// Resets the IN endpoint `ep` (clear halt: the data toggle restarts); stale packets are then
    /// read away by the driver.
    fn reset_in(&mut self, ep: u8) -> Result<(), DeviceError>;
}

/// The time left until `deadline`, rounded up to whole milliseconds for `poll` (0 when passed).
pub(crate) fn poll_ms(deadline: Instant) -> Option<libc::c_int> {
    let now = Instant::now();
    if now >= deadline {
        return None;
    }
    let left = deadline - now;
    Some(left.as_micros().div_ceil(1000).min(i32::MAX as u128) as libc::c_int)
}

/// Maps an errno from a serial device to a device error. A pty whose other end closed reads EIO;
/// an unplugged USB serial adapter reads EIO or ENXIO/ENODEV.
pub(crate) fn errno_error(errno: i32, doing: &'static str) -> DeviceError {
    match errno {
        libc::EIO | libc::ENXIO | libc::ENODEV | libc::EBADF | libc::EPIPE | libc::ENOENT => {
            DeviceError::Disconnected { what: doing }
        }
        libc::ETIMEDOUT => DeviceError::Timeout { waited_us: 0 },
        _ => DeviceError::Other { what: doing },
    }
}

/// The current thread's errno (after a failed libc call).
pub(crate) fn last_errno() -> i32 {
    std::io::Error::last_os_error().raw_os_error().unwrap_or(0)
}

/// What the set-up of a serial port managed to do (plain data: reported, never allocated, so a
/// reopen inside the tick can fill it too).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PortSetting {
    /// Done (or already so).
    Done,
    /// The device has no such setting (a pseudo-terminal answers ENOTTY): nothing to do.
    NotApplicable,
    /// The device has the setting but refused it (the errno).
    Failed(i32),
}

/// The serial-port settings the UART boards want, as far as the port allowed them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PortReport {
    /// The kernel's low-latency flag (for FTDI adapters it sets the latency timer to 1 ms; by
    /// default they hold received bytes for up to 16 ms, longer than a tick).
    pub low_latency: PortSetting,
    /// DTR and RTS cleared (the lab's driver clears both).
    pub modem_lines_cleared: PortSetting,
}

/// A serial port as a file descriptor, driven with `poll`/`read`/`write`: no allocation and a
/// deadline on every call, which a buffered port type does not give.
#[derive(Debug)]
pub struct FdTransport {
    fd: OwnedFd,
    /// Set when an error showed the other end is gone: later calls fail fast.
    gone: bool,
    port: Option<PortReport>,
}

impl FdTransport {
    /// Takes ownership of an open, configured (raw) serial descriptor and makes it non-blocking,
    /// so a read after `poll` said "readable" can never block the tick.
    pub fn from_fd(fd: OwnedFd) -> FdTransport {
        let raw = fd.as_raw_fd();
        // SAFETY: `raw` is the open descriptor `fd` owns; F_GETFL/F_SETFL touch only its flags.
        unsafe {
            let flags = libc::fcntl(raw, libc::F_GETFL);
            if flags >= 0 {
                libc::fcntl(raw, libc::F_SETFL, flags | libc::O_NONBLOCK);
            }
        }
        FdTransport { fd, gone: false, port: None }
    }

    pub fn fd(&self) -> libc::c_int {
        self.fd.as_raw_fd()
    }

    fn wait(
        &mut self,
        events: libc::c_short,
        deadline: Instant,
        waited_from: Instant,
    ) -> Result<(), DeviceError> {
        loop {
            let Some(ms) = poll_ms(deadline) else {
                return Err(DeviceError::Timeout { waited_us: waited_us(waited_from) });
            };
            let mut p = libc::pollfd { fd: self.fd(), events, revents: 0 };
            // SAFETY: one valid pollfd for the duration of the call.
            let n = unsafe { libc::poll(&mut p, 1, ms) };
            if n < 0 {
                let e = last_errno();
                if e == libc::EINTR {
                    continue;
                }
                return Err(self.fail(e, "poll on the serial port"));
            }
            if n == 0 {
                continue; // the loop head reports the timeout once the deadline has passed
            }
            if p.revents & (libc::POLLNVAL) != 0 {
                return Err(self.fail(libc::EBADF, "serial port closed"));
            }
            // POLLHUP with data still buffered: read it first; the read then reports EIO.
            return Ok(());
        }
    }

    fn fail(&mut self, errno: i32, doing: &'static str) -> DeviceError {
        let e = errno_error(errno, doing);
        if matches!(e, DeviceError::Disconnected { .. }) {
            self.gone = true;
        }
        e
    }
}

fn waited_us(from: Instant) -> u32 {
    from.elapsed().as_micros().min(u32::MAX as u128) as u32
}

impl ByteTransport for FdTransport {
    fn write_all(&mut self, mut bytes: &[u8], deadline: Instant) -> Result<(), DeviceError> {
        if self.gone {
            return Err(DeviceError::Disconnected { what: "serial port gone" });
        }
        let from = Instant::now();
        while !bytes.is_empty() {
            let n = unsafe { libc::write(self.fd(), bytes.as_ptr().cast(), bytes.len()) };
            if n > 0 {
                bytes = &bytes[n as usize..];
                continue;
            }
            let e = if n == 0 { libc::EAGAIN } else { last_errno() };
            match e {
                libc::EINTR => continue,
                libc::EAGAIN => self.wait(libc::POLLOUT, deadline, from)?,
                _ => return Err(self.fail(e, "writing to the serial port")),
            }
        }
        Ok(())
    }

    fn read_exact(&mut self, buf: &mut [u8], deadline: Instant) -> Result<(), DeviceError> {
        if self.gone {
            return Err(DeviceError::Disconnected { what: "serial port gone" });
        }
        let from = Instant::now();
        let mut got = 0;
        while got < buf.len() {
            let rest = &mut buf[got..];
            let n = unsafe { libc::read(self.fd(), rest.as_mut_ptr().cast(), rest.len()) };
            if n > 0 {
                got += n as usize;
                continue;
            }
            if n == 0 {
                // End of file on a tty: the other side hung up.
                self.gone = true;
                return Err(DeviceError::Disconnected { what: "serial port hung up" });
            }
            let e = last_errno();
            match e {
                libc::EINTR => continue,
                libc::EAGAIN => self.wait(libc::POLLIN, deadline, from)?,
                _ => return Err(self.fail(e, "reading from the serial port")),
            }
        }
        Ok(())
    }

    /// What [`open_serial`] set on the port (None for a descriptor given to [`FdTransport::from_fd`]).
    fn port_report(&self) -> Option<PortReport> {
        self.port
    }

    fn clear_input(&mut self) -> Result<(), DeviceError> {
        if self.gone {
            return Err(DeviceError::Disconnected { what: "serial port gone" });
        }
        // tcflush drops the kernel's queue; then read away anything that raced in, without waiting.
        unsafe { libc::tcflush(self.fd(), libc::TCIFLUSH) };
        let mut scratch = [0u8; 256];
        loop {
            let n = unsafe { libc::read(self.fd(), scratch.as_mut_ptr().cast(), scratch.len()) };
            if n > 0 {
                continue;
            }
            if n == 0 {
                self.gone = true;
                return Err(DeviceError::Disconnected { what: "serial port hung up" });
            }
            let e = last_errno();
            return match e {
                libc::EAGAIN | libc::EINTR => Ok(()),
                _ => Err(self.fail(e, "reading from the serial port")),
            };
        }
    }
}

/// Opens a serial device (or a pty slave) by path in raw 8N1 mode at `baud`, exclusive, and asks
/// for what the UART boards want: the kernel's low-latency flag and DTR/RTS cleared (a pty has
/// neither: that is not an error; [`FdTransport::port_report`] says what happened). Allocates
/// nothing: `path` is a prepared C string, so a driver can call this again from its reopen path
/// inside the tick.
pub fn open_serial(path: &std::ffi::CStr, baud: u32) -> Result<FdTransport, DeviceError> {
    // SAFETY: a valid NUL-terminated path; the flags are plain open(2) flags.
    let fd = unsafe {
        libc::open(path.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK | libc::O_CLOEXEC)
    };
    if fd < 0 {
        let e = last_errno();
        return Err(match e {
            libc::ENOENT | libc::ENXIO | libc::ENODEV | libc::EIO => {
                DeviceError::Disconnected { what: "serial port not present" }
            }
            libc::EACCES | libc::EPERM => DeviceError::Other {
                what: "permission denied on the serial port: add yourself to the 'dialout' group (then log in again)",
            },
            libc::EBUSY => DeviceError::Other { what: "the serial port is in use by another program" },
            _ => DeviceError::Other { what: "cannot open the serial port" },
        });
    }
    // SAFETY: `fd` was just opened and is owned by nothing else.
    let mut link = FdTransport::from_fd(unsafe { OwnedFd::from_raw_fd(fd) });
    // Exclusive use: two programs writing currents to the same boards is never right.
    // SAFETY: TIOCEXCL takes no argument.
    unsafe { libc::ioctl(fd, libc::TIOCEXCL) };
    // SAFETY: termios is plain data; tcgetattr fills it.
    let mut t: libc::termios = unsafe { std::mem::zeroed() };
    if unsafe { libc::tcgetattr(fd, &mut t) } != 0 {
        return Err(DeviceError::Other { what: "the path is not a serial port (tcgetattr failed)" });
    }
    // SAFETY: `t` is a valid termios.
    unsafe { libc::cfmakeraw(&mut t) };
    t.c_cflag |= libc::CREAD | libc::CLOCAL;
    t.c_cflag &= !(libc::CSTOPB | libc::PARENB | libc::CRTSCTS);
    let speed = baud_constant(baud).ok_or(DeviceError::Other { what: "unsupported baud rate" })?;
    // SAFETY: `t` is a valid termios; `speed` a termios speed constant.
    unsafe {
        libc::cfsetispeed(&mut t, speed);
        libc::cfsetospeed(&mut t, speed);
    }
    if unsafe { libc::tcsetattr(fd, libc::TCSANOW, &t) } != 0 {
        return Err(DeviceError::Other { what: "cannot configure the serial port (tcsetattr failed)" });
    }
    link.port = Some(PortReport { low_latency: set_low_latency(fd), modem_lines_cleared: clear_dtr_rts(fd) });
    Ok(link)
}

/// An errno from a tty ioctl: the device lacks the feature (a pty), or refused it.
fn setting_errno(e: i32) -> PortSetting {
    match e {
        libc::ENOTTY | libc::EINVAL => PortSetting::NotApplicable,
        e => PortSetting::Failed(e),
    }
}

/// Clears DTR and RTS (TIOCMBIC).
fn clear_dtr_rts(fd: libc::c_int) -> PortSetting {
    let bits: libc::c_int = libc::TIOCM_DTR | libc::TIOCM_RTS;
    // SAFETY: TIOCMBIC reads one c_int through the pointer.
    if unsafe { libc::ioctl(fd, libc::TIOCMBIC, &bits) } == 0 {
        PortSetting::Done
    } else {
        setting_errno(last_errno())
    }
}

/// Linux's `struct serial_struct` (TIOCGSERIAL/TIOCSSERIAL), which libc does not define.
#[cfg(target_os = "linux")]
#[repr(C)]
struct SerialStruct {
    kind: libc::c_int,
    line: libc::c_int,
    port: libc::c_uint,
    irq: libc::c_int,
    flags: libc::c_int,
    xmit_fifo_size: libc::c_int,
    custom_divisor: libc::c_int,
    baud_base: libc::c_int,
    close_delay: libc::c_ushort,
    io_type: libc::c_char,
    reserved_char: [libc::c_char; 1],
    hub6: libc::c_int,
    closing_wait: libc::c_ushort,
    closing_wait2: libc::c_ushort,
    iomem_base: *mut libc::c_uchar,
    iomem_reg_shift: libc::c_ushort,
    port_high: libc::c_uint,
    iomap_base: libc::c_ulong,
}

/// `ASYNC_LOW_LATENCY` in `serial_struct.flags` (bit 13).
#[cfg(target_os = "linux")]
const ASYNC_LOW_LATENCY: libc::c_int = 1 << 13;

/// Sets the kernel's low-latency flag on a serial port (FTDI adapters then use a 1 ms latency
/// timer instead of 16 ms).
#[cfg(target_os = "linux")]
fn set_low_latency(fd: libc::c_int) -> PortSetting {
    // SAFETY: SerialStruct is plain data with the kernel's layout; TIOCGSERIAL fills it.
    let mut ss: SerialStruct = unsafe { std::mem::zeroed() };
    if unsafe { libc::ioctl(fd, libc::TIOCGSERIAL, &mut ss) } != 0 {
        return setting_errno(last_errno());
    }
    if ss.flags & ASYNC_LOW_LATENCY != 0 {
        return PortSetting::Done;
    }
    ss.flags |= ASYNC_LOW_LATENCY;
    // SAFETY: as above; TIOCSSERIAL reads the struct.
    if unsafe { libc::ioctl(fd, libc::TIOCSSERIAL, &ss) } == 0 {
        PortSetting::Done
    } else {
        // The port has the setting (the read worked) but refused the change.
        PortSetting::Failed(last_errno())
    }
}

#[cfg(not(target_os = "linux"))]
fn set_low_latency(_fd: libc::c_int) -> PortSetting {
    PortSetting::NotApplicable
}

/// The latency timer of a USB serial adapter behind `port` (FTDI: sysfs `latency_timer`, in ms),
/// None when the port has none (a pty, a built-in UART) or it cannot be read. Set-up time only
/// (allocates).
pub fn latency_timer_ms(port: &str) -> Option<u32> {
    let real = std::fs::canonicalize(port).ok()?;
    let name = real.file_name()?.to_str()?;
    let text = std::fs::read_to_string(format!("/sys/class/tty/{name}/device/latency_timer")).ok()?;
    text.trim().parse().ok()
}

fn baud_constant(baud: u32) -> Option<libc::speed_t> {
    Some(match baud {
        115_200 => libc::B115200,
        230_400 => libc::B230400,
        460_800 => libc::B460800,
        921_600 => libc::B921600,
        1_000_000 => libc::B1000000,
        2_000_000 => libc::B2000000,
        3_000_000 => libc::B3000000,
        4_000_000 => libc::B4000000,
        _ => return None,
    })
}
