//! `restage-appliance-under-test run --config FILE`, `... verify BUNDLE --trust DIR` and
//! `... install BUNDLE --to FILE`: the appliance's `run`, `verify` and the copy `install` ends
//! with (the same library entry points `restage-appliance` calls, with default light-check
//! limits), built in this crate so its end-to-end tests can start it as a real process and
//! kill it.

use std::path::Path;
use std::process::ExitCode;

const USAGE: &str = "usage: restage-appliance-under-test run --config FILE | verify BUNDLE --trust DIR \
                     | install BUNDLE --to FILE";

fn main() -> ExitCode {
    tracing_subscriber::fmt().with_writer(std::io::stderr).init();
    let args: Vec<String> = std::env::args().collect();
    let result = match args.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        [_, "run", "--config", path] => restage_appliance::config::Config::load(Path::new(path))
            .map_err(|e| e.to_string())
            .and_then(|c| restage_appliance::runtime::run_blocking(c).map_err(|e| e.to_string())),
        [_, "verify", bundle, "--trust", trust] => {
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs() as i64);
            restage_appliance::verify::verify_report(
                Path::new(bundle),
                Path::new(trust),
                now,
                Default::default(),
                false,
            )
            .map(|report| print!("{report}"))
            .map_err(|e| e.to_string())
        }
        [_, "install", bundle, "--to", target] => {
            restage_appliance::install::put_in_place(Path::new(bundle), Path::new(target), |_| true)
                .map(|_| ())
                .map_err(|e| e.to_string())
        }
        _ => {
            eprintln!("{USAGE}");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
