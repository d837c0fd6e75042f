//! Datagram sockets, Unix or UDP, driven through `recvmsg`/`sendto` on the raw descriptor with
//! `MSG_DONTWAIT`: no call here blocks (waiting is [`Sock::wait`]'s job) and none allocates, so
//! the rig's tick can use them. Addresses are kept as raw `sockaddr`s ([`RawAddr`]) for the same
//! reason: comparing a sender with the peer is a few byte compares.
//!
//! The world's socket also asks the kernel to timestamp every datagram as it arrives
//! (`SO_TIMESTAMPNS`), so the world knows how old the newest hand sample is however late it
//! drains its queue.

use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::os::fd::{AsRawFd, RawFd};
use std::os::unix::fs::{FileTypeExt, MetadataExt};
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::private_dir::check_socket_dir;
use crate::LinkError;

/// A socket address as the kernel sees it.
#[derive(Clone, Copy)]
pub struct RawAddr {
    storage: libc::sockaddr_storage,
    len: libc::socklen_t,
}

fn zeroed_storage() -> libc::sockaddr_storage {
    // SAFETY: sockaddr_storage is plain data; all-zero is a valid (AF_UNSPEC) value.
    unsafe { std::mem::zeroed() }
}

impl RawAddr {
    fn empty() -> RawAddr {
        RawAddr { storage: zeroed_storage(), len: 0 }
    }

    /// The address of a Unix socket at `path` (at most 107 bytes).
    pub fn unix(path: &Path) -> Result<RawAddr, LinkError> {
        let bytes = path.as_os_str().as_encoded_bytes();
        let mut un: libc::sockaddr_un = unsafe { std::mem::zeroed() };
        if bytes.is_empty() || bytes.len() >= un.sun_path.len() || bytes.contains(&0) {
            return Err(LinkError::PathTooLong(path.to_path_buf()));
        }
        un.sun_family = libc::AF_UNIX as libc::sa_family_t;
        for (d, s) in un.sun_path.iter_mut().zip(bytes) {
            *d = *s as libc::c_char;
        }
        let mut a = RawAddr::empty();
        // SAFETY: sockaddr_un fits in sockaddr_storage (that is what storage is for).
        unsafe { std::ptr::write(&mut a.storage as *mut _ as *mut libc::sockaddr_un, un) };
        a.len = (std::mem::size_of::<libc::sa_family_t>() + bytes.len() + 1) as libc::socklen_t;
        Ok(a)
    }

    pub fn inet(addr: SocketAddr) -> RawAddr {
        let mut a = RawAddr::empty();
        match addr {
            SocketAddr::V4(v4) => {
                let sin = libc::sockaddr_in {
                    sin_family: libc::AF_INET as libc::sa_family_t,
                    sin_port: v4.port().to_be(),
                    sin_addr: libc::in_addr { s_addr: u32::from_ne_bytes(v4.ip().octets()) },
                    sin_zero: [0; 8],
                };
                // SAFETY: sockaddr_in fits in sockaddr_storage.
                unsafe { std::ptr::write(&mut a.storage as *mut _ as *mut libc::sockaddr_in, sin) };
                a.len = std::mem::size_of::<libc::sockaddr_in>() as libc::socklen_t;
            }
            SocketAddr::V6(v6) => {
                let sin6 = libc::sockaddr_in6 {
                    sin6_family: libc::AF_INET6 as libc::sa_family_t,
                    sin6_port: v6.port().to_be(),
                    sin6_flowinfo: v6.flowinfo(),
                    sin6_addr: libc::in6_addr { s6_addr: v6.ip().octets() },
                    sin6_scope_id: v6.scope_id(),
                };
                // SAFETY: sockaddr_in6 fits in sockaddr_storage.
                unsafe { std::ptr::write(&mut a.storage as *mut _ as *mut libc::sockaddr_in6, sin6) };
                a.len = std::mem::size_of::<libc::sockaddr_in6>() as libc::socklen_t;
            }
        }
        a
    }

    fn family(&self) -> i32 {
        self.storage.ss_family as i32
    }

    /// The path bytes of a Unix address (up to its NUL), or None.
    fn unix_path(&self) -> Option<&[u8]> {
        if self.family() != libc::AF_UNIX {
            return None;
        }
        let off = std::mem::size_of::<libc::sa_family_t>();
        let len = (self.len as usize).saturating_sub(off);
        // SAFETY: storage is at least sizeof(sockaddr_un); `len` is bounded below.
        let all = unsafe {
            std::slice::from_raw_parts((&self.storage as *const _ as *const u8).add(off), 108.min(len))
        };
        let end = all.iter().position(|b| *b == 0).unwrap_or(all.len());
        Some(&all[..end])
    }

    fn inet_addr(&self) -> Option<SocketAddr> {
        match self.family() {
            libc::AF_INET => {
                // SAFETY: the family says the storage holds a sockaddr_in.
                let sin = unsafe { &*(&self.storage as *const _ as *const libc::sockaddr_in) };
                let ip = std::net::Ipv4Addr::from(sin.sin_addr.s_addr.to_ne_bytes());
                Some(SocketAddr::from((ip, u16::from_be(sin.sin_port))))
            }
            libc::AF_INET6 => {
                // SAFETY: the family says the storage holds a sockaddr_in6.
                let s6 = unsafe { &*(&self.storage as *const _ as *const libc::sockaddr_in6) };
                let ip = std::net::Ipv6Addr::from(s6.sin6_addr.s6_addr);
                Some(SocketAddr::V6(std::net::SocketAddrV6::new(
                    ip,
                    u16::from_be(s6.sin6_port),
                    s6.sin6_flowinfo,
                    s6.sin6_scope_id,
                )))
            }
            _ => None,
        }
    }

    /// Same sender? Unix: the same path (an unnamed sender matches nothing). UDP: the same IP
    /// address and port. Never allocates.
    pub fn same(&self, other: &RawAddr) -> bool {
        match (self.unix_path(), other.unix_path()) {
            (Some(a), Some(b)) => !a.is_empty() && a == b,
            (None, None) => match (self.inet_addr(), other.inet_addr()) {
                (Some(a), Some(b)) => a.ip() == b.ip() && a.port() == b.port(),
                _ => false,
            },
            _ => false,
        }
    }

    /// `unix:PATH` or `udp://IP:PORT`, for messages (allocates).
    pub fn describe(&self) -> String {
        if let Some(p) = self.unix_path() {
            if p.is_empty() {
                return "an unnamed Unix socket".into();
            }
            return format!("unix:{}", String::from_utf8_lossy(p));
        }
        match self.inet_addr() {
            Some(a) => format!("udp://{a}"),
            None => format!("an address of family {}", self.family()),
        }
    }
}

impl std::fmt::Debug for RawAddr {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.describe())
    }
}

enum Inner {
    Unix(UnixDatagram),
    Udp(UdpSocket),
}

/// One datagram socket.
pub struct Sock {
    inner: Inner,
    /// The Unix socket file this socket created (removed when it closes).
    own_path: Option<PathBuf>,
    local: RawAddr,
}

/// What one receive got.
pub struct Received {
    pub len: usize,
    pub from: RawAddr,
    /// CLOCK_REALTIME at the datagram's arrival, when the socket timestamps.
    pub arrived_ns: Option<i64>,
    /// The datagram was longer than the buffer.
    pub truncated: bool,
}

impl Sock {
    /// A Unix datagram socket bound at `path`, in a directory only this user can write to. A
    /// stale socket file of this user's (nobody listening) is replaced; a live one, a symlink or
    /// anything else is refused.
    pub fn bind_unix(path: &Path) -> Result<Sock, LinkError> {
        let local = RawAddr::unix(path)?;
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        check_socket_dir(dir)?;
        let unsafe_path = |why: String| LinkError::Unsafe { what: "socket", path: path.to_path_buf(), why };
        match std::fs::symlink_metadata(path) {
            Ok(m) if m.file_type().is_symlink() => {
                return Err(unsafe_path(
                    "is a symbolic link: refusing to use it (it may have been planted); remove it or choose another path"
                        .into(),
                ))
            }
            // SAFETY: geteuid cannot fail.
            Ok(m) if m.file_type().is_socket() && m.uid() == unsafe { libc::geteuid() } => {
                let probe = UnixDatagram::unbound().map_err(|e| LinkError::io("creating a socket", path, e))?;
                if probe.connect(path).is_ok() {
                    return Err(unsafe_path(
                        "is in use by another process (another spidar world?): stop it or choose another path".into(),
                    ));
                }
                std::fs::remove_file(path).map_err(|e| LinkError::io("removing the stale socket", path, e))?;
            }
            Ok(_) => {
                return Err(unsafe_path(
                    "exists and is not a socket of yours: remove it or choose another path".into(),
                ))
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(LinkError::io("checking", path, e)),
        }
        let s = UnixDatagram::bind(path).map_err(|e| LinkError::io("binding", path, e))?;
        Ok(Sock { inner: Inner::Unix(s), own_path: Some(path.to_path_buf()), local })
    }

    /// A UDP socket bound at `addr` (port 0: any free port).
    pub fn bind_udp(addr: SocketAddr) -> Result<Sock, LinkError> {
        let s = UdpSocket::bind(addr).map_err(|e| LinkError::io("binding", &format!("udp://{addr}"), e))?;
        let bound = s
            .local_addr()
            .map_err(|e| LinkError::io("reading the address of", &format!("udp://{addr}"), e))?;
        Ok(Sock { inner: Inner::Udp(s), own_path: None, local: RawAddr::inet(bound) })
    }

    fn fd(&self) -> RawFd {
        match &self.inner {
            Inner::Unix(s) => s.as_raw_fd(),
            Inner::Udp(s) => s.as_raw_fd(),
        }
    }

    /// The address this socket is bound to (with the real port for UDP port 0).
    pub fn local(&self) -> &RawAddr {
        &self.local
    }

    pub fn local_udp(&self) -> Option<SocketAddr> {
        self.local.inet_addr()
    }

    /// Asks the kernel to stamp each datagram with its arrival time.
    pub fn enable_timestamps(&self) -> io::Result<()> {
        let one: libc::c_int = 1;
        setsockopt(self.fd(), libc::SO_TIMESTAMPNS, one)
    }

    /// Asks for a receive buffer of `bytes` (beyond the system's limit when privileged). Best
    /// effort: returns what the kernel granted.
    pub fn grow_receive_buffer(&self, bytes: usize) -> usize {
        let b = bytes.min(i32::MAX as usize) as libc::c_int;
        if setsockopt(self.fd(), libc::SO_RCVBUFFORCE, b).is_err() {
            let _ = setsockopt(self.fd(), libc::SO_RCVBUF, b);
        }
        let mut got: libc::c_int = 0;
        let mut len = std::mem::size_of::<libc::c_int>() as libc::socklen_t;
        // SAFETY: valid out-pointers of the right size.
        unsafe {
            libc::getsockopt(
                self.fd(),
                libc::SOL_SOCKET,
                libc::SO_RCVBUF,
                &mut got as *mut _ as *mut _,
                &mut len,
            )
        };
        got.max(0) as usize
    }

    /// Receives one datagram if one is queued (`WouldBlock` otherwise). Never blocks or allocates.
    pub fn recv(&self, buf: &mut [u8]) -> io::Result<Received> {
        let mut from = RawAddr::empty();
        let mut iov = libc::iovec { iov_base: buf.as_mut_ptr() as *mut _, iov_len: buf.len() };
        // Room for one SCM_TIMESTAMPNS message, aligned for cmsghdr.
        let mut control = [0u64; 8];
        // SAFETY: msghdr is plain data; zero is a valid start.
        let mut msg: libc::msghdr = unsafe { std::mem::zeroed() };
        msg.msg_name = &mut from.storage as *mut _ as *mut _;
        msg.msg_namelen = std::mem::size_of::<libc::sockaddr_storage>() as libc::socklen_t;
        msg.msg_iov = &mut iov;
        msg.msg_iovlen = 1;
        msg.msg_control = control.as_mut_ptr() as *mut _;
        msg.msg_controllen = std::mem::size_of_val(&control) as _;
        // SAFETY: every pointer in `msg` points to live buffers of the lengths given.
        let n = unsafe { libc::recvmsg(self.fd(), &mut msg, libc::MSG_DONTWAIT) };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        from.len = msg.msg_namelen;
        let mut arrived_ns = None;
        // SAFETY: CMSG_* walk the control buffer the kernel filled, within msg_controllen.
        unsafe {
            let mut c = libc::CMSG_FIRSTHDR(&msg);
            while !c.is_null() {
                if (*c).cmsg_level == libc::SOL_SOCKET && (*c).cmsg_type == libc::SCM_TIMESTAMPNS {
                    let ts = std::ptr::read_unaligned(libc::CMSG_DATA(c) as *const libc::timespec);
                    arrived_ns = Some(ts.tv_sec as i64 * 1_000_000_000 + ts.tv_nsec as i64);
                }
                c = libc::CMSG_NXTHDR(&msg, c);
            }
        }
        Ok(Received { len: n as usize, from, arrived_ns, truncated: msg.msg_flags & libc::MSG_TRUNC != 0 })
    }

    /// Sends one datagram to `to` without blocking (`WouldBlock` when the way is full). Never
    /// allocates.
    pub fn send_to(&self, d: &[u8], to: &RawAddr) -> io::Result<()> {
        // SAFETY: `d` and `to.storage` are live for the call, with the lengths given.
        let n = unsafe {
            libc::sendto(
                self.fd(),
                d.as_ptr() as *const _,
                d.len(),
                libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
                &to.storage as *const _ as *const libc::sockaddr,
                to.len,
            )
        };
        if n < 0 {
            Err(io::Error::last_os_error())
        } else {
            Ok(())
        }
    }

    /// Waits until a datagram is queued or `timeout` passes; true if one is.
    pub fn wait(&self, timeout: Duration) -> bool {
        wait_readable(self.fd(), timeout)
    }

    /// Another descriptor for the same socket (e.g. to wait on it from another owner).
    pub fn try_clone_waiter(&self) -> io::Result<Waiter> {
        let fd = match &self.inner {
            Inner::Unix(s) => std::os::fd::OwnedFd::from(s.try_clone()?),
            Inner::Udp(s) => std::os::fd::OwnedFd::from(s.try_clone()?),
        };
        Ok(Waiter { fd })
    }
}

impl Drop for Sock {
    fn drop(&mut self) {
        if let Some(p) = self.own_path.take() {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Waits for a socket owned by someone else to become readable (lockstep runs).
pub struct Waiter {
    fd: std::os::fd::OwnedFd,
}

impl Waiter {
    /// True once a datagram is queued, false after `timeout`.
    pub fn wait(&self, timeout: Duration) -> bool {
        wait_readable(self.fd.as_raw_fd(), timeout)
    }
}

/// `ppoll` for readability with a nanosecond timeout (`poll`'s milliseconds would turn a
/// sub-millisecond wait into none).
fn wait_readable(fd: RawFd, timeout: Duration) -> bool {
    let mut p = libc::pollfd { fd, events: libc::POLLIN, revents: 0 };
    let ts = libc::timespec {
        tv_sec: timeout.as_secs().min(i32::MAX as u64) as libc::time_t,
        tv_nsec: timeout.subsec_nanos() as _,
    };
    // SAFETY: one valid pollfd, a valid timespec, no signal mask.
    let r = unsafe { libc::ppoll(&mut p, 1, &ts, std::ptr::null()) };
    r > 0 && p.revents & libc::POLLIN != 0
}

fn setsockopt(fd: RawFd, opt: libc::c_int, v: libc::c_int) -> io::Result<()> {
    // SAFETY: `v` is a c_int, as these options take.
    let r = unsafe {
        libc::setsockopt(
            fd,
            libc::SOL_SOCKET,
            opt,
            &v as *const _ as *const _,
            std::mem::size_of::<libc::c_int>() as libc::socklen_t,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// CLOCK_REALTIME in nanoseconds (what the kernel stamps datagrams with).
pub fn realtime_ns() -> i64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: valid out-pointer; CLOCK_REALTIME always exists.
    unsafe { libc::clock_gettime(libc::CLOCK_REALTIME, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// True for the errors a send gets when nobody is there to receive (a world or rig gone).
pub fn is_gone(e: &io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::ECONNREFUSED) | Some(libc::ENOENT) | Some(libc::ENOTCONN) | Some(libc::EHOSTUNREACH)
    )
}

/// True for the errors of a full way (the receiver's queue or our send buffer).
pub fn is_full(e: &io::Error) -> bool {
    e.kind() == io::ErrorKind::WouldBlock || e.raw_os_error() == Some(libc::ENOBUFS)
}
