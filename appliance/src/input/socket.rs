//! The operators' control socket: a Unix stream socket taking one command per line —
//! `press`, `status`, `stop`, `reload` — and answering one line each (status as JSON).

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::oneshot;

use super::serial::LineBuffer;
use super::{Control, InputEvent, InputSender};

/// Binds the socket (replacing a stale one), readable and writable by owner and group.
pub fn bind(path: &Path) -> std::io::Result<UnixListener> {
    if path.exists() {
        std::fs::remove_file(path)?;
    }
    let listener = UnixListener::bind(path)?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))?;
    Ok(listener)
}

/// Accepts connections forever.
pub async fn run(listener: UnixListener, path: PathBuf, tx: InputSender) {
    tracing::info!(path = %path.display(), "control socket listening");
    loop {
        match listener.accept().await {
            Ok((stream, _)) => {
                let tx = tx.clone();
                tokio::spawn(async move {
                    if let Err(e) = serve(stream, tx).await {
                        tracing::debug!(%e, "control connection ended");
                    }
                });
            }
            Err(e) => {
                tracing::warn!(%e, "control socket accept failed");
                tokio::time::sleep(std::time::Duration::from_millis(200)).await;
            }
        }
    }
}

async fn serve(mut stream: UnixStream, tx: InputSender) -> std::io::Result<()> {
    let mut lines = LineBuffer::new(256);
    let mut buf = [0u8; 1024];
    loop {
        let n = stream.read(&mut buf).await?;
        if n == 0 {
            return Ok(());
        }
        let mut commands = Vec::new();
        lines.feed(&buf[..n], |l| commands.push(String::from_utf8_lossy(l).into_owned()));
        for line in commands {
            let answer = answer(&line, &tx).await;
            stream.write_all(answer.as_bytes()).await?;
            stream.write_all(b"\n").await?;
        }
    }
}

/// Sends one command line to the loop and waits for its one-line answer.
pub async fn answer(line: &str, tx: &InputSender) -> String {
    let Some(command) = Control::parse(line) else {
        return format!("error: unknown command {:?} (press, status, stop, reload)", line.trim());
    };
    let (reply, rx) = oneshot::channel();
    if tx.send(InputEvent::Control { command, reply: Some(reply) }).await.is_err() {
        return "error: the appliance is shutting down".into();
    }
    rx.await.unwrap_or_else(|_| "error: no answer".into())
}
