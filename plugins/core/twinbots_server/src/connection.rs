//! One robot's connection, from `hello` to disconnect, on its own thread.
//!
//! Every request must arrive whole within the read timeout (the handshake timeout for
//! `hello`), is checked ([`crate::checks`]) before the learner sees it, and gets exactly one
//! reply (none for `bye`). Refusals are logged with the peer's address; only fatal ones, and
//! a peer that is gone, end the connection.

use std::io::BufReader;
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use crate::closing::close_after_reply;
use crate::shared::{Shared, panic_message};
use twinbots_link::checks::{Admission, Rejection, check_hello, check_request};
use twinbots_link::deadline::DeadlineStream;
use twinbots_link::frame::{FrameError, read_frame, read_message, write_message};
use twinbots_link::protocol::{ErrorCode, RobotMessage, ServerMessage, VERSION, error};
use twinbots_link::tls::{Transport, is_tls_refusal};

/// How long a closing connection waits for what its client already sent (see `closing`).
const LINGER: Duration = Duration::from_millis(200);

struct Connection<'a> {
    peer: SocketAddr,
    id: u64,
    shared: &'a Shared,
    /// Requests are read through the buffer; replies are written whole to the stream under it.
    link: BufReader<DeadlineStream>,
}

impl Connection<'_> {
    /// Sends a reply; false if the peer is gone.
    fn reply(&mut self, message: &ServerMessage) -> bool {
        write_message(self.link.get_mut(), message).is_ok()
    }

    /// Answers a refused message and logs it; false if the connection must end.
    fn refuse(&mut self, rejection: &Rejection) -> bool {
        self.shared.log_rejection(self.peer, &format!("robot {}", self.id), rejection);
        self.reply(&rejection.reply()) && !rejection.fatal
    }

    /// Answers a frame that could not be read; false if the connection must end.
    fn refuse_frame(&mut self, e: &FrameError) -> bool {
        match Rejection::of_frame(e) {
            Some(rejection) => self.refuse(&rejection),
            None => false, // the peer is gone: nobody to answer
        }
    }

    /// The learner's answer; a panic inside it is caught here, while the lock is held, and
    /// becomes the learner's error: training ends and `wait` reports it.
    fn ask_learner(&self, message: RobotMessage) -> Option<ServerMessage> {
        let mut learner = self.shared.learner();
        let answer = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| learner.handle(self.id, message)));
        let answer = answer.unwrap_or_else(|panic| {
            let why = format!("the learner panicked: {}", panic_message(&*panic));
            learner.error.get_or_insert(why.clone());
            Some(error(ErrorCode::LearnerFailed, true, why))
        });
        self.shared.notify_if_stopped(&learner);
        answer
    }
}

pub(crate) fn serve(stream: TcpStream, peer: SocketAddr, id: u64, shared: &Shared) {
    let limits = &shared.limits;
    let _ = stream.set_nodelay(true);
    // A robot that stops reading cannot hold its thread forever either.
    let _ = stream.set_write_timeout(Some(limits.read_timeout));
    let Ok(closer) = stream.try_clone() else { return };
    // Under TLS the handshake happens within the hello's deadline, on its first read.
    let Ok(transport) = Transport::accept(stream, limits.tls.as_ref()) else { return };
    let mut conn = Connection { peer, id, shared, link: BufReader::new(DeadlineStream::new(transport)) };

    conn.link.get_mut().expire_in(limits.handshake_timeout);
    let admitted = read_frame(&mut conn.link)
        .map_err(|e| {
            // A failed TLS handshake leaves no channel to answer on: it is logged only.
            if let FrameError::Io(io) = &e
                && is_tls_refusal(io)
            {
                shared.log_rejection(
                    peer,
                    "new connection",
                    &Rejection::new(ErrorCode::HandshakeExpected, true, format!("TLS handshake failed: {io}")),
                );
            }
            Rejection::of_frame(&e)
        })
        .and_then(|payload| {
            let admission = Admission { task: &shared.task, token: limits.token.as_deref() };
            check_hello(&payload, &admission).map_err(Some)
        });
    match admitted {
        Ok(_) => shared.learner().join(id),
        Err(rejection) => {
            if let Some(rejection) = rejection {
                conn.refuse(&Rejection { fatal: true, ..rejection });
                close_after_reply(&closer, LINGER);
            }
            return;
        }
    }
    let welcome = ServerMessage::Welcome { version: VERSION, robot_id: id, task: shared.task.clone() };
    if conn.reply(&welcome) {
        converse(&mut conn, limits.read_timeout);
    }
    shared.learner().leave(id);
    close_after_reply(&closer, LINGER);
}

/// Request after request until the robot leaves, training ends or an error is fatal.
fn converse(conn: &mut Connection, read_timeout: Duration) {
    loop {
        conn.link.get_mut().expire_in(read_timeout);
        let message = match read_message::<RobotMessage>(&mut conn.link) {
            Ok(m) => m,
            Err(e) => {
                if conn.refuse_frame(&e) {
                    continue;
                }
                return;
            }
        };
        if let Err(rejection) = check_request(&message, &conn.shared.task) {
            if conn.refuse(&rejection) {
                continue;
            }
            return;
        }
        let Some(answer) = conn.ask_learner(message) else { return }; // bye
        if let ServerMessage::Error { code, message, fatal } = &answer {
            let rejection = Rejection::new(*code, *fatal, message.clone());
            conn.shared.log_rejection(conn.peer, &format!("robot {}", conn.id), &rejection);
        }
        let last = matches!(answer, ServerMessage::Done { .. } | ServerMessage::Error { fatal: true, .. });
        if !conn.reply(&answer) || last {
            return;
        }
    }
}
