//! `restage-appliance-under-test run --config FILE`: the appliance's `run` (the same library
//! entry point `restage-appliance run` calls), built in this crate so its end-to-end tests
//! can start it as a real process and kill it.

use std::process::ExitCode;

fn main() -> ExitCode {
    tracing_subscriber::fmt().with_writer(std::io::stderr).init();
    let args: Vec<String> = std::env::args().collect();
    let [_, run, flag, path] = args.as_slice() else {
        eprintln!("usage: restage-appliance-under-test run --config FILE");
        return ExitCode::from(2);
    };
    if run != "run" || flag != "--config" {
        eprintln!("usage: restage-appliance-under-test run --config FILE");
        return ExitCode::from(2);
    }
    let result = restage_appliance::config::Config::load(std::path::Path::new(path))
        .map_err(|e| e.to_string())
        .and_then(|c| restage_appliance::runtime::run_blocking(c).map_err(|e| e.to_string()));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
