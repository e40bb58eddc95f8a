//! Standard input for development: the control socket's commands, one per line, answers on
//! standard output.

use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

use super::InputSender;
use super::socket::answer;

/// Reads commands until standard input closes.
pub async fn run(tx: InputSender) {
    let mut lines = BufReader::new(tokio::io::stdin()).lines();
    let mut out = tokio::io::stdout();
    while let Ok(Some(line)) = lines.next_line().await {
        if line.trim().is_empty() {
            continue;
        }
        let a = answer(&line, &tx).await;
        let _ = out.write_all(format!("{a}\n").as_bytes()).await;
        let _ = out.flush().await;
    }
    tracing::debug!("standard input closed");
}
