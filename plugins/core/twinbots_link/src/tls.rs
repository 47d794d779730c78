//! TLS for the RobotServer link (rustls with ring): the server's certificate and key
//! (`serve --tls-cert/--tls-key`), the certificate authority robots trust (`robot --tls-ca`),
//! and [`Transport`], the byte stream either end talks through, plain TCP or TLS over it.
//! Frames are the same inside TLS; only the bytes on the wire are encrypted, the token too.

use std::io::{self, Read, Write};
use std::net::{IpAddr, TcpStream};
use std::path::Path;
use std::sync::Arc;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName};
use rustls::{ClientConfig, ClientConnection, RootCertStore, ServerConfig, ServerConnection, StreamOwned};

fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

fn certificates(path: &Path) -> anyhow::Result<Vec<CertificateDer<'static>>> {
    let certs = CertificateDer::pem_file_iter(path)
        .and_then(|certs| certs.collect::<Result<Vec<_>, _>>())
        .map_err(|e| anyhow::anyhow!("{}: not a PEM certificate file: {e}", path.display()))?;
    anyhow::ensure!(!certs.is_empty(), "{}: holds no PEM certificate (-----BEGIN CERTIFICATE-----)", path.display());
    Ok(certs)
}

/// A server's TLS settings: its certificate chain and private key.
#[derive(Clone)]
pub struct ServerTls(Arc<ServerConfig>);

impl std::fmt::Debug for ServerTls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ServerTls")
    }
}

impl ServerTls {
    /// Reads a PEM certificate chain (the server's first) and its PEM private key; errors name
    /// the file.
    pub fn from_pem_files(cert: &Path, key: &Path) -> anyhow::Result<Self> {
        let chain = certificates(cert)?;
        let private = PrivateKeyDer::from_pem_file(key)
            .map_err(|e| anyhow::anyhow!("{}: not a PEM private key: {e}", key.display()))?;
        let config = ServerConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()?
            .with_no_client_auth()
            .with_single_cert(chain, private)
            .map_err(|e| anyhow::anyhow!("{} with {}: {e}", cert.display(), key.display()))?;
        Ok(Self(Arc::new(config)))
    }
}

/// A robot's TLS settings: the certificate authorities it trusts to sign its server's
/// certificate (a self-signed server certificate is its own authority).
#[derive(Clone)]
pub struct ClientTls(Arc<ClientConfig>);

impl std::fmt::Debug for ClientTls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ClientTls")
    }
}

impl ClientTls {
    /// Trusts the PEM certificates in `ca`; errors name the file.
    pub fn from_ca_file(ca: &Path) -> anyhow::Result<Self> {
        let mut roots = RootCertStore::empty();
        for cert in certificates(ca)? {
            roots.add(cert).map_err(|e| anyhow::anyhow!("{}: {e}", ca.display()))?;
        }
        let config = ClientConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()?
            .with_root_certificates(roots)
            .with_no_client_auth();
        Ok(Self(Arc::new(config)))
    }
}

/// The name a robot checks its server's certificate against: `name` if given (`--tls-name`),
/// else the address it connects to (an IP address, which the certificate must list).
pub fn server_name(name: Option<&str>, ip: IpAddr) -> anyhow::Result<ServerName<'static>> {
    match name {
        Some(name) => ServerName::try_from(name.to_string()).map_err(|e| anyhow::anyhow!("--tls-name {name:?}: {e}")),
        None => Ok(ServerName::IpAddress(ip.into())),
    }
}

/// A connection's byte stream: plain TCP, or TLS over TCP (either end).
pub enum Transport {
    Tcp(TcpStream),
    Server(Box<StreamOwned<ServerConnection, TcpStream>>),
    Client(Box<StreamOwned<ClientConnection, TcpStream>>),
}

impl Transport {
    /// The server's end of an accepted connection (the handshake happens on first use).
    pub fn accept(stream: TcpStream, tls: Option<&ServerTls>) -> io::Result<Self> {
        Ok(match tls {
            None => Self::Tcp(stream),
            Some(tls) => Self::Server(Box::new(StreamOwned::new(
                ServerConnection::new(tls.0.clone()).map_err(io::Error::other)?,
                stream,
            ))),
        })
    }

    /// A robot's end of a connection to `name` (the handshake happens on first use).
    pub fn connect(stream: TcpStream, tls: Option<(&ClientTls, ServerName<'static>)>) -> io::Result<Self> {
        Ok(match tls {
            None => Self::Tcp(stream),
            Some((tls, name)) => Self::Client(Box::new(StreamOwned::new(
                ClientConnection::new(tls.0.clone(), name).map_err(io::Error::other)?,
                stream,
            ))),
        })
    }

    /// The TCP socket underneath (for timeouts and shutdown).
    pub fn tcp(&self) -> &TcpStream {
        match self {
            Self::Tcp(s) => s,
            Self::Server(s) => s.get_ref(),
            Self::Client(s) => s.get_ref(),
        }
    }
}

impl From<TcpStream> for Transport {
    fn from(stream: TcpStream) -> Self {
        Self::Tcp(stream)
    }
}

impl Read for Transport {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Self::Tcp(s) => s.read(buf),
            Self::Server(s) => s.read(buf),
            Self::Client(s) => s.read(buf),
        }
    }
}

impl Write for Transport {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match self {
            Self::Tcp(s) => s.write(buf),
            Self::Server(s) => s.write(buf),
            Self::Client(s) => s.write(buf),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        match self {
            Self::Tcp(s) => s.flush(),
            Self::Server(s) => s.flush(),
            Self::Client(s) => s.flush(),
        }
    }
}

/// Whether an I/O error is TLS refusing the peer (a certificate it does not trust, a peer that
/// does not speak TLS): a reason to stop, not to retry.
pub fn is_tls_refusal(e: &io::Error) -> bool {
    e.kind() == io::ErrorKind::InvalidData && e.get_ref().is_some_and(|inner| inner.is::<rustls::Error>())
}
