//! `restage-appliance`: the stage machine's program.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use restage_appliance::clock::{Clock, LedgerClock, SystemTime, TimeSource};
use restage_appliance::config::{Config, LEDGER_FILE};
use restage_appliance::ledger::Ledger;
use restage_appliance::loader;
use tracing_subscriber::EnvFilter;

#[derive(Parser)]
#[command(name = "restage-appliance", version, about = "Play a signed restage bundle on the stage")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the player: outputs, inputs, exposure timer and ledger (the systemd service).
    Run {
        /// The TOML configuration (see systemd/restage-appliance.toml).
        #[arg(long)]
        config: PathBuf,
    },
    /// Print the light budget used and left, the active bundle, warnings and last showings,
    /// from the ledger (works while the appliance runs).
    Status {
        #[arg(long)]
        config: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Verify BUNDLE (signature, validity, version, light bound), then atomically make it the
    /// active bundle and ask a running appliance to reload.
    Install {
        bundle: PathBuf,
        #[arg(long)]
        config: PathBuf,
    },
    /// Acknowledge that this stage's ledger is lost or was replaced (the appliance refuses
    /// light until then): the old file is kept aside, a fresh ledger records REASON. Run it
    /// with the appliance stopped.
    LedgerReset {
        #[arg(long)]
        config: PathBuf,
        /// Why (recorded in the new ledger), e.g. "disk replaced after failure, ticket 1234".
        #[arg(long)]
        reason: String,
    },
    /// Verify a bundle (signature, validity, every section, every scene's light check: lit
    /// pixels vouched for by the certificate, peak within the bound) with the same code the
    /// player loads bundles with.
    Verify {
        bundle: PathBuf,
        /// Directory of trusted public keys (*.pem, SPKI).
        #[arg(long)]
        trust: PathBuf,
        /// The stage's farthest projector throw in metres, as `[light_check] max_throw_m`.
        #[arg(long, default_value_t = restage_shared::light::DEFAULT_MAX_THROW_M)]
        max_throw_m: f64,
        /// As `[light_check] min_cos`.
        #[arg(long, default_value_t = restage_shared::light::DEFAULT_MIN_COS)]
        min_cos: f64,
    },
}

fn main() -> Result<()> {
    // Colour on a terminal only; priority prefixes, no timestamps under systemd.
    restage_appliance::logging::init(
        EnvFilter::try_from_env("RESTAGE_LOG").unwrap_or_else(|_| EnvFilter::new("info")),
    );
    match Cli::parse().command {
        Command::Run { config } => run(&config),
        Command::Status { config, json } => status(&config, json),
        Command::Install { bundle, config } => install(&bundle, &config),
        Command::Verify { bundle, trust, max_throw_m, min_cos } => {
            verify(&bundle, &trust, restage_shared::light::StageLimits { max_throw_m, min_cos })
        }
        Command::LedgerReset { config, reason } => ledger_reset(&config, &reason),
    }
}
fn ledger_reset(config: &Path, reason: &str) -> Result<()> {
    let config = Config::load(config)?;
    if reason.trim().len() < 3 {
        bail!("--reason must say why the ledger is being reset (it is recorded)");
    }
    let now = SystemTime.wall_ms();
    let (_, kept) =
        Ledger::reset_acknowledged(&config.state_dir, config.ledger.utc_offset_minutes, reason, now)?;
    eprintln!("a fresh ledger records the reset in {}", config.state_dir.join(LEDGER_FILE).display());
    for k in kept {
        eprintln!("kept the old file as {}", k.display());
    }
    Ok(())
}

/// Ledger time for a tool run beside the appliance: the wall clock, never below the ledger's
/// high-water mark.
fn ledger_now(ledger: &Ledger) -> Result<i64> {
    Ok(LedgerClock::new(SystemTime, ledger.high_water_ms()?).now().unix_ms)
}

fn verify(bundle: &Path, trust: &Path, stage: restage_shared::light::StageLimits) -> Result<()> {
    // The one time of this load, taken before anything is read.
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .context("the system clock is before 1970")?
        .as_secs() as i64;
    print!("{}", restage_appliance::verify::verify_report(bundle, trust, now, stage)?);
    Ok(())
}

fn run(config: &Path) -> Result<()> {
    let config = Config::load(config)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the event loop")?;
    rt.block_on(restage_appliance::runtime::run(config)).context("the appliance stopped (outputs dark)")?;
    Ok(())
}

fn status(config: &Path, json: bool) -> Result<()> {
    let config = Config::load(config)?;
    let path = config.state_dir.join(LEDGER_FILE);
    if !path.exists() {
        bail!("no ledger at {} (has the appliance run yet?)", path.display());
    }
    let ledger = Ledger::open_read_only(&path, config.ledger.utc_offset_minutes)?;
    let s = ledger.status(ledger_now(&ledger)?)?;
    let mut out = std::io::stdout().lock();
    if json {
        writeln!(out, "{}", serde_json::to_string_pretty(&s)?)?;
        return Ok(());
    }
    match &s.active {
        Some(a) => writeln!(
            out,
            "active bundle: {} version {} ({}), {}",
            a.object,
            a.version,
            &a.bundle_hash[..16.min(a.bundle_hash.len())],
            a.path
        )?,
        None => writeln!(out, "active bundle: none")?,
    }
    let left = |l: Option<f64>| l.map_or("no budget".into(), |l| format!("{l:.3} lx·h left"));
    writeln!(
        out,
        "today ({}): {:.3} lx·h used, {}",
        s.day,
        s.day_used_lux_hours,
        left(s.day_left_lux_hours)
    )?;
    writeln!(out, "last 365 days: {:.3} lx·h used, {}", s.year_used_lux_hours, left(s.year_left_lux_hours))?;
    writeln!(out, "all time: {:.3} lx·h; open reservations: {}", s.total_lux_hours, s.open_reservations)?;
    for w in &s.warnings {
        writeln!(
            out,
            "WARNING: {} budget at {:.0} % ({:.3} of {:.3} lx·h, {})",
            w.budget,
            w.threshold * 100.0,
            w.used,
            w.budget_lux_hours,
            w.period
        )?;
    }
    writeln!(out, "last showings:")?;
    for sh in &s.last_showings {
        writeln!(
            out,
            "  {} +{:.1} s  {}  (ended by {})",
            sh.started_ms,
            (sh.ended_ms - sh.started_ms) as f64 / 1000.0,
            sh.scenes,
            sh.ended_by
        )?;
    }
    writeln!(out, "last events:")?;
    for e in &s.last_events {
        writeln!(out, "  {} {}: {}", e.at_ms, e.kind, e.detail)?;
    }
    Ok(())
}

fn install(bundle: &Path, config: &Path) -> Result<()> {
    let config = Config::load(config)?;
    let ledger = Ledger::open_stage(&config.state_dir, config.ledger.utc_offset_minutes)?;
    let now = ledger_now(&ledger)?;
    let (verified, hash) =
        loader::open_verified(bundle, &config.trust_dir, &ledger, now, config.light_check.limits())?;
    loader::check_object(bundle, &ledger, config.object_id.as_deref(), &verified.manifest.object.id)?;
    let m = &verified.manifest;
    eprintln!(
        "verified: {} version {} ({} scenes), manifest {}",
        m.object.id,
        m.version,
        m.scenes.len(),
        &hash[..16]
    );
    drop(verified);

    // Copy next to the target, flush, rename over it, flush the directory: a crash leaves the
    // old bundle or the new one, never a mix.
    let target = config.bundle_path();
    let dir = target.parent().context("the bundle path has no directory")?;
    let tmp = dir.join(format!(".install-{}.tmp", std::process::id()));
    let copy = || -> std::io::Result<()> {
        std::fs::copy(bundle, &tmp)?;
        std::fs::File::open(&tmp)?.sync_all()?;
        std::fs::rename(&tmp, &target)?;
        std::fs::File::open(dir)?.sync_all()
    };
    if let Err(e) = copy() {
        let _ = std::fs::remove_file(&tmp);
        return Err(e).with_context(|| format!("installing {} as {}", bundle.display(), target.display()));
    }
    // The file now in place must be the one verified (a bundle changed between verify and
    // copy would otherwise slip in): verify the installed copy again.
    loader::open_verified(&target, &config.trust_dir, &ledger, now, config.light_check.limits())
        .context("the installed copy does not verify")?;
    eprintln!("installed as {}", target.display());
    if let Some(sock) = &config.inputs.control_socket {
        match ask(sock, "reload") {
            Ok(answer) => eprintln!("running appliance: {answer}"),
            Err(e) => eprintln!(
                "no running appliance answered on {} ({e}); it loads the bundle at start",
                sock.display()
            ),
        }
    }
    Ok(())
}

/// Sends one command to the control socket and returns the answer line.
fn ask(socket: &Path, command: &str) -> std::io::Result<String> {
    use std::io::{BufRead, BufReader};
    let mut s = std::os::unix::net::UnixStream::connect(socket)?;
    s.set_read_timeout(Some(std::time::Duration::from_secs(10)))?;
    s.write_all(format!("{command}\n").as_bytes())?;
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line)?;
    Ok(line.trim_end().to_string())
}
