//! HTTPS and secure WebSockets for the view (`--view-tls CERT,KEY`): a headset on the network
//! opens the page only from a secure context, and a page served over HTTPS may only open secure
//! WebSockets. Each of the view's two public ports is a TLS front (rustls) that relays every
//! connection, decrypted, to the view's own plain server on a loopback port: the page server
//! (`tiny_http`) and the viewers' WebSockets stay exactly as they are without TLS, and a viewer
//! that stalls is still dropped by its socket's write timeout (the relay stops reading from it).
//!
//! Must never: relay a connection that failed its handshake, wait for the network's bytes while
//! holding a connection's lock, or outlive the view (the fronts stop with its flag).

use std::io::{ErrorKind, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::{ServerConfig, ServerConnection};

use super::{Shared, ViewError};

/// The certificate and key the view serves HTTPS with.
#[derive(Clone)]
pub struct TlsIdentity {
    config: Arc<ServerConfig>,
}

impl std::fmt::Debug for TlsIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TlsIdentity")
    }
}

impl TlsIdentity {
    /// Reads a PEM certificate chain (the server's first) and its PEM private key.
    pub fn from_pem_files(cert: &Path, key: &Path) -> Result<TlsIdentity, ViewError> {
        let bad = |what: &str, path: &Path, e: String| {
            ViewError::Tls(format!(
                "{what} {}: {e} (make a certificate and key as docs/display.md says, e.g. `openssl req -x509 ...`)",
                path.display()
            ))
        };
        let chain = CertificateDer::pem_file_iter(cert)
            .map_err(|e| bad("the certificate", cert, e.to_string()))?
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| bad("the certificate", cert, e.to_string()))?;
        if chain.is_empty() {
            return Err(bad("the certificate", cert, "no CERTIFICATE block in it".into()));
        }
        let key_der =
            PrivateKeyDer::from_pem_file(key).map_err(|e| bad("the private key", key, e.to_string()))?;
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let config = ServerConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .and_then(|b| b.with_no_client_auth().with_single_cert(chain, key_der))
            .map_err(|e| bad("the certificate and key", cert, e.to_string()))?;
        Ok(TlsIdentity { config: Arc::new(config) })
    }

    /// `--view-tls`'s value: `CERT.pem,KEY.pem`.
    pub fn from_arg(arg: &str) -> Result<TlsIdentity, ViewError> {
        let (cert, key) = arg.split_once(',').ok_or_else(|| {
            ViewError::Tls(format!(
                "--view-tls '{arg}': give the certificate and the key file as CERT.pem,KEY.pem"
            ))
        })?;
        TlsIdentity::from_pem_files(Path::new(cert.trim()), Path::new(key.trim()))
    }
}

/// The TLS front of one public port: accepts connections until the view stops, each relayed to
/// `backend` (the plain server on loopback) on a thread of its own.
pub(super) fn front(listener: TcpListener, backend: SocketAddr, id: TlsIdentity, shared: Arc<Shared>) {
    if listener.set_nonblocking(true).is_err() {
        return;
    }
    while !shared.stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((client, _)) => {
                let config = id.config.clone();
                let _ = std::thread::Builder::new().name("spidar-view-tls".into()).spawn(move || {
                    let _ = relay(client, backend, config);
                });
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(Duration::from_millis(20)),
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

fn tls_err(e: rustls::Error) -> std::io::Error {
    std::io::Error::new(ErrorKind::InvalidData, e)
}

/// One connection: the handshake, then the client's bytes decrypted to the backend (this thread)
/// and the backend's encrypted to the client (a second thread), until either side closes.
fn relay(client: TcpStream, backend: SocketAddr, config: Arc<ServerConfig>) -> std::io::Result<()> {
    client.set_nonblocking(false)?;
    client.set_nodelay(true)?;
    client.set_read_timeout(Some(Duration::from_secs(10)))?;
    client.set_write_timeout(Some(Duration::from_secs(5)))?;
    let mut conn = ServerConnection::new(config).map_err(tls_err)?;
    let mut sock = client.try_clone()?;
    while conn.is_handshaking() {
        let (rd, wr) = conn.complete_io(&mut sock)?;
        if rd == 0 && wr == 0 && conn.is_handshaking() {
            return Err(ErrorKind::UnexpectedEof.into());
        }
    }
    client.set_read_timeout(None)?;
    let plain = TcpStream::connect(backend)?;
    plain.set_nodelay(true)?;
    let conn = Arc::new(Mutex::new(conn));
    // The backend's bytes to the client.
    let down = {
        let (conn, mut from, mut to) = (conn.clone(), plain.try_clone()?, client.try_clone()?);
        std::thread::Builder::new().name("spidar-view-tls-out".into()).spawn(move || {
            let mut buf = vec![0u8; 64 * 1024];
            loop {
                let n = match from.read(&mut buf) {
                    Ok(0) | Err(_) => {
                        if let Ok(mut c) = conn.lock() {
                            c.send_close_notify();
                            while c.wants_write() && c.write_tls(&mut to).is_ok() {}
                        }
                        break;
                    }
                    Ok(n) => n,
                };
                let Ok(mut c) = conn.lock() else { break };
                if c.writer().write_all(&buf[..n]).is_err() {
                    break;
                }
                let mut failed = false;
                while c.wants_write() {
                    if c.write_tls(&mut to).is_err() {
                        failed = true;
                        break;
                    }
                }
                if failed {
                    break;
                }
            }
            let _ = to.shutdown(Shutdown::Both);
            let _ = from.shutdown(Shutdown::Both);
        })?
    };
    // The client's bytes to the backend. The handshake's last read may already have brought the
    // first request: what the connection holds is passed on before the socket is read again.
    let result = (|| -> std::io::Result<()> {
        let mut raw = vec![0u8; 64 * 1024];
        let mut clear = vec![0u8; 64 * 1024];
        let (mut from, mut to, mut reply) = (client.try_clone()?, plain.try_clone()?, client.try_clone()?);
        let mut n = 0;
        loop {
            let mut rest = &raw[..n];
            loop {
                let mut c = conn.lock().map_err(|_| std::io::Error::other("lock"))?;
                if !rest.is_empty() {
                    c.read_tls(&mut rest)?;
                }
                let state = c.process_new_packets().map_err(tls_err);
                // An alert, or an answer the protocol owes (a key update), goes out at once.
                while c.wants_write() {
                    c.write_tls(&mut reply)?;
                }
                state?;
                loop {
                    match c.reader().read(&mut clear) {
                        Ok(0) => return Ok(()),
                        Ok(k) => to.write_all(&clear[..k])?,
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        Err(e) => return Err(e),
                    }
                }
                if rest.is_empty() {
                    break;
                }
            }
            n = from.read(&mut raw)?;
            if n == 0 {
                return Ok(());
            }
        }
    })();
    let _ = plain.shutdown(Shutdown::Both);
    let _ = client.shutdown(Shutdown::Both);
    let _ = down.join();
    result
}
