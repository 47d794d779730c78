//! TLS on the RobotServer link (issue 32): robots that trust the server's certificate authority
//! train over it, one that trusts another is refused with the reason, the token never crosses
//! the wire in clear (a capturing proxy on loopback), and listening beyond loopback without TLS
//! or a token needs `--insecure`, which warns.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::{Arc, Mutex};

use crate::robot_hostile::fake_server;
use crate::server::{serve_process_with, temp, twinbots};

/// A certificate authority and a server certificate it signed for 127.0.0.1, as PEM files in
/// `dir`: (CA, server certificate, server key).
fn pki(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    use rcgen::{BasicConstraints, CertificateParams, IsCa, KeyPair};
    std::fs::create_dir_all(dir).unwrap();
    let ca_key = KeyPair::generate().unwrap();
    let mut ca_params = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca = ca_params.self_signed(&ca_key).unwrap();
    let key = KeyPair::generate().unwrap();
    let cert = CertificateParams::new(vec!["127.0.0.1".to_string(), "localhost".to_string()])
        .unwrap()
        .signed_by(&key, &ca, &ca_key)
        .unwrap();
    let files = (dir.join("ca.pem"), dir.join("server.pem"), dir.join("server.key"));
    std::fs::write(&files.0, ca.pem()).unwrap();
    std::fs::write(&files.1, cert.pem()).unwrap();
    std::fs::write(&files.2, key.serialize_pem()).unwrap();
    files
}

/// `twinbots serve cartpole` for 512 steps and one robot, with `extra` flags.
fn serve(out: &Path, extra: &[&str]) -> (Child, SocketAddr) {
    serve_process_with("127.0.0.1:0", 512, out, &[&["--robots", "1"], extra].concat())
}

/// A loopback proxy to `upstream` (a stand-in server whose every connection is relayed) that
/// keeps every byte that crosses it, both ways.
fn capturing_proxy(upstream: SocketAddr) -> (SocketAddr, Arc<Mutex<Vec<u8>>>) {
    let wire = Arc::new(Mutex::new(Vec::new()));
    let captured = wire.clone();
    let (addr, _) = fake_server(move |client| {
        let Ok(server) = TcpStream::connect(upstream) else { return };
        for (mut from, mut to) in [(client.try_clone().unwrap(), server.try_clone().unwrap()), (server, client)] {
            let wire = captured.clone();
            std::thread::spawn(move || {
                let mut buf = [0u8; 4096];
                while let Ok(n) = from.read(&mut buf) {
                    if n == 0 || to.write_all(&buf[..n]).is_err() {
                        break;
                    }
                    wire.lock().unwrap().extend_from_slice(&buf[..n]);
                }
                let _ = to.shutdown(std::net::Shutdown::Write);
            });
        }
    });
    (addr, wire)
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

/// A robot trains the served run through a capturing proxy; what crossed the wire.
fn train_through_proxy(dir: &Path, tls: bool) -> Vec<u8> {
    let (ca, cert, key) = pki(&dir.join("pki"));
    let out = dir.join(if tls { "run-tls" } else { "run-plain" });
    let tls_flags = ["--tls-cert", cert.to_str().unwrap(), "--tls-key", key.to_str().unwrap()];
    let (mut server, addr) = serve(&out, if tls { &tls_flags[..] } else { &[] });
    let (proxy, wire) = capturing_proxy(addr);
    let mut robot = twinbots();
    robot.args(["robot", "cartpole", "--server", &proxy.to_string(), "--token", "s3cret-t0ken", "--patience", "20"]);
    if tls {
        robot.arg("--tls-ca").arg(&ca);
    }
    let output = robot.output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(String::from_utf8_lossy(&output.stdout).contains("robots done"));
    assert!(server.wait().unwrap().success());

    wire.lock().unwrap().clone()
}

#[test]
fn robots_train_over_tls_and_the_token_never_crosses_the_wire_in_clear() {
    let dir = temp("tls-wire");
    let clear = train_through_proxy(&dir, false);
    // The capture works: without TLS the token and the messages are there to read.
    assert!(contains(&clear, b"s3cret-t0ken") && contains(&clear, b"\"type\":\"hello\""));
    let encrypted = train_through_proxy(&dir, true);
    assert!(encrypted.len() > 10_000, "a whole training run crossed: {} bytes", encrypted.len());
    assert!(!contains(&encrypted, b"s3cret-t0ken"), "the token crossed in clear");
    assert!(!contains(&encrypted, b"\"type\"") && !contains(&encrypted, b"cartpole"), "a message crossed in clear");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_robot_that_trusts_another_authority_is_refused_with_the_reason() {
    let dir = temp("tls-wrong-ca");
    let (_, cert, key) = pki(&dir.join("server"));
    let (other_ca, _, _) = pki(&dir.join("other"));
    let (mut server, addr) =
        serve(&dir.join("run"), &["--tls-cert", cert.to_str().unwrap(), "--tls-key", key.to_str().unwrap()]);
    let output = twinbots()
        .args(["robot", "cartpole", "--server", &addr.to_string(), "--patience", "5"])
        .arg("--tls-ca")
        .arg(&other_ca)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(err.contains(&format!("TLS with the server at {addr} failed: invalid peer certificate")), "{err}");
    // A robot without TLS: the server closes its connections before any welcome, and it says so.
    let output =
        twinbots().args(["robot", "cartpole", "--server", &addr.to_string(), "--patience", "2"]).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && err.contains("before its welcome (does it speak TLS?"), "{err}");
    server.kill().unwrap();
    server.wait().unwrap();
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn listening_beyond_loopback_needs_tls_and_a_token_or_insecure_which_warns() {
    let dir = temp("tls-exposure");
    let output = twinbots()
        .args(["serve", "cartpole", "--listen", "0.0.0.0:0", "--timesteps", "512", "--out"])
        .arg(dir.join("run"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(err.contains("reaches beyond this machine: it needs TLS (--tls-cert and --tls-key) and a token"), "{err}");
    let mut child = twinbots()
        .args(["serve", "cartpole", "--listen", "0.0.0.0:0", "--insecure", "--timesteps", "512", "--out"])
        .arg(dir.join("run"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    assert!(line.starts_with("listening on 0.0.0.0:"), "{line:?}");
    child.kill().unwrap();
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    assert!(err.contains("warning: --insecure") && err.contains("travel in clear"), "{err}");
    child.wait().unwrap();
    std::fs::remove_dir_all(&dir).ok();
}
