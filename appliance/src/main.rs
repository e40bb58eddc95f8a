//! `restage-appliance`: the stage machine's program.

// Non-test code never unwraps, expects or panics: bad input or a fault is an error value and
// the outputs go dark on it, never an abort. Tests may.
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use restage_appliance::clock::{Clock, LedgerClock, SystemTime, TimeSource};
use restage_appliance::config::{Config, LEDGER_FILE};
use restage_appliance::ledger::Ledger;
use restage_appliance::loader;
use restage_shared::text::printable;
use tracing_subscriber::EnvFilter;

#[derive(Parser)]
#[command(
    name = "restage-appliance",
    version,
    about = "Play a signed restage bundle on the stage",
    long_about = "Play a signed restage bundle on the stage: when a visitor presses the button, \
light the object with the bundle's projector images for the exposure time, inside the daily and \
yearly lux-hour budget, and keep the projectors dark otherwise and on any fault.\n\n\
Files: /etc/restage/appliance.toml, the configuration (every key documented in it); \
/etc/restage/trust/*.pub.pem, the keys whose bundles are accepted; /var/lib/restage/, the light \
ledger (ledger.sqlite) and the active bundle. The service is restage-appliance.service \
(systemctl status restage-appliance; journalctl -u restage-appliance)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Where the packaged unit and the operator's commands find the configuration.
const DEFAULT_CONFIG: &str = "/etc/restage/appliance.toml";

#[derive(clap::Args)]
struct ConfigArg {
    /// The TOML configuration (documented example: systemd/restage-appliance.toml).
    #[arg(long, default_value = DEFAULT_CONFIG)]
    config: PathBuf,
}

#[derive(Subcommand)]
enum Command {
    /// Run the player: outputs, inputs, exposure timer and ledger (the systemd service).
    Run {
        #[command(flatten)]
        config: ConfigArg,
    },
    /// Print the light budget used and left, the active bundle, warnings and last showings,
    /// from the ledger (works while the appliance runs).
    Status {
        #[command(flatten)]
        config: ConfigArg,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Verify BUNDLE (signature, validity, version, light bound), then atomically make it the
    /// active bundle and ask a running appliance to reload.
    Install {
        bundle: PathBuf,
        #[command(flatten)]
        config: ConfigArg,
    },
    /// Show projector K's commissioning pattern (grid, frame and its number) on the running
    /// appliance, the others black: which projector is which, and where it lands. Only while
    /// idle; paid from the light budget like any light.
    Identify {
        #[command(flatten)]
        config: ConfigArg,
        /// The projector, counted from 1 in the bundle's order.
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..))]
        projector: u8,
        /// How long, in seconds.
        #[arg(long, default_value_t = restage_appliance::input::IDENTIFY_DEFAULT_S,
              value_parser = clap::value_parser!(u16).range(1..=i64::from(restage_appliance::input::IDENTIFY_MAX_S)))]
        seconds: u16,
    },
    /// The light ledger: export its history, or acknowledge a lost one.
    Ledger {
        #[command(subcommand)]
        command: LedgerCommand,
    },
    /// Same as `ledger reset` (kept for scripts written before `ledger`).
    #[command(hide = true)]
    LedgerReset {
        #[command(flatten)]
        config: ConfigArg,
        #[arg(long)]
        reason: String,
    },
    /// Verify a bundle (signature, validity, every section, every scene's light check: lit
    /// pixels vouched for by the certificate, peak within the bound) with the same code the
    /// player loads bundles with; a bundle signed with the public demo key is refused unless
    /// --allow-demo-key.
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
        /// Accept a bundle signed with the public demo key, as `allow_demo_key = true` in the
        /// configuration does (for trying the demo only: anyone can sign with that key).
        #[arg(long)]
        allow_demo_key: bool,
    },
    /// Update the stage machine's own software (its image): verify a signed update folder,
    /// write it to the root slot not running, and boot it on trial (it becomes the machine's
    /// software once the appliance is ready on it; otherwise the machine goes back by itself).
    Update {
        #[command(subcommand)]
        command: UpdateCommand,
    },
}

/// Where the stage machine keeps the keys its image updates must be signed with (apart from
/// the bundles' keys: whoever signs scenes cannot change the software).
const UPDATE_TRUST: &str = "/etc/restage/update-trust";

#[derive(Subcommand)]
enum UpdateCommand {
    /// Hash the update in DIR (root.squashfs, vmlinuz, initrd) and sign its manifest with
    /// KEY (tools/image/build.sh does this on the build machine).
    Sign {
        dir: PathBuf,
        /// The image version it installs (its IMAGE_VERSION).
        #[arg(long)]
        version: String,
        /// The private key (PEM).
        #[arg(long)]
        key: PathBuf,
    },
    /// Check the update in DIR: signature, every file's size and hash.
    Verify {
        dir: PathBuf,
        /// Directory of trusted public keys (*.pem).
        #[arg(long, default_value = UPDATE_TRUST)]
        trust: PathBuf,
    },
    /// Verify the update in DIR, then write it to the slot not running with a boot entry on
    /// trial (run as root on the stage machine; reboot to start it).
    Install {
        dir: PathBuf,
        /// Directory of trusted public keys (*.pem).
        #[arg(long, default_value = UPDATE_TRUST)]
        trust: PathBuf,
        /// Boots the new slot gets to reach "appliance ready" before the machine goes back.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=9))]
        tries: u32,
    },
}

#[derive(Subcommand)]
enum LedgerCommand {
    /// Write the light history (every exposure, with lux, times and lux·h) as CSV: for the
    /// conservator's records or a loan agreement's light report.
    Export {
        #[command(flatten)]
        config: ConfigArg,
        /// CSV output (the only format; the flag says so in scripts).
        #[arg(long, required = true)]
        csv: bool,
        /// Write to FILE instead of standard output (refuses to overwrite an existing file).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
    /// Acknowledge that this stage's ledger is lost or was replaced (the appliance refuses
    /// light until then): the old file is kept aside, a fresh ledger records REASON. Run it
    /// with the appliance stopped.
    Reset {
        #[command(flatten)]
        config: ConfigArg,
        /// Why (recorded in the new ledger), e.g. "disk replaced after failure, ticket 1234".
        #[arg(long)]
        reason: String,
    },
}

fn main() -> Result<()> {
    // Colour on a terminal only; priority prefixes, no timestamps under systemd.
    restage_appliance::logging::init(
        EnvFilter::try_from_env("RESTAGE_LOG").unwrap_or_else(|_| EnvFilter::new("info")),
    );
    match Cli::parse().command {
        Command::Run { config } => run(&config.config),
        Command::Status { config, json } => status(&config.config, json),
        Command::Install { bundle, config } => install(&bundle, &config.config),
        Command::Verify { bundle, trust, max_throw_m, min_cos, allow_demo_key } => verify(
            &bundle,
            &trust,
            restage_shared::light::StageLimits { max_throw_m, min_cos },
            allow_demo_key,
        ),
        Command::Ledger { command: LedgerCommand::Reset { config, reason } }
        | Command::LedgerReset { config, reason } => ledger_reset(&config.config, &reason),
        Command::Identify { config, projector, seconds } => identify(&config.config, projector, seconds),
        Command::Ledger { command: LedgerCommand::Export { config, csv: _, out } } => {
            ledger_export(&config.config, out.as_deref())
        }
        Command::Update { command } => update(command),
    }
}

fn update(command: UpdateCommand) -> Result<()> {
    use restage_appliance::sysupdate;
    let trusted = |trust: &Path| {
        restage_shared::keys::TrustStore::load_dir(trust)
            .with_context(|| format!("the update keys in {}", trust.display()))
    };
    match command {
        UpdateCommand::Sign { dir, version, key } => {
            let key = restage_shared::keys::load_private_key(&key)?;
            let m = sysupdate::sign(&dir, &version, &key)?;
            println!("signed update {} in {}", m.version, dir.display());
        }
        UpdateCommand::Verify { dir, trust } => {
            let m = sysupdate::verify(&dir, &trusted(&trust)?, &trust)?;
            println!("update {} in {}: signature and files good", m.version, dir.display());
        }
        UpdateCommand::Install { dir, trust, tries } => {
            let m = sysupdate::verify(&dir, &trusted(&trust)?, &trust)?;
            let layout = sysupdate::Layout::of_this_machine()?;
            let slot = sysupdate::install(&dir, &m, &layout, tries)?;
            tracing::info!(version = %m.version, %slot, tries, "image update installed");
            println!(
                "update {} installed in slot {slot} (running: {} in slot {}); it starts at the next boot, on trial for {tries} boots",
                m.version, layout.running_version, layout.running
            );
        }
    }
    Ok(())
}

fn ledger_export(config: &Path, out: Option<&Path>) -> Result<()> {
    let config = Config::load(config)?;
    let ledger = open_ledger_read_only(&config)?;
    let rows = ledger.history(i64::MIN / 2, i64::MAX / 2)?;
    let utc = |ms: i64| restage_shared::time::format_utc(ms.div_euclid(1000));
    let zone = config.local_zone();
    let local = |ms: i64| zone.local_time_s(ms);
    match out {
        Some(path) => {
            let file = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(path)
                .with_context(|| format!("creating {}", path.display()))?;
            restage_appliance::export::write_csv(&rows, utc, local, std::io::BufWriter::new(file))
                .with_context(|| format!("writing {}", path.display()))?;
            eprintln!("{} exposure rows written to {}", rows.len(), path.display());
        }
        None => restage_appliance::export::write_csv(&rows, utc, local, std::io::stdout().lock())?,
    }
    Ok(())
}

fn identify(config: &Path, projector: u8, seconds: u16) -> Result<()> {
    let config = Config::load(config)?;
    let Some(sock) = &config.inputs.control_socket else {
        bail!("identify talks to the running appliance: set [inputs] control_socket in the configuration");
    };
    let answer = ask(sock, &format!("identify {projector} {seconds}"))
        .with_context(|| format!("no running appliance answered on {}", sock.display()))?;
    match answer.strip_prefix("error: ") {
        Some(why) => bail!("projector {projector}: {why}"),
        None => println!("{answer}"),
    }
    Ok(())
}

/// The stage's ledger, read-only (the appliance may be running).
fn open_ledger_read_only(config: &Config) -> Result<Ledger> {
    let path = config.state_dir.join(LEDGER_FILE);
    if !path.exists() {
        bail!("no ledger at {} (has the appliance run yet?)", path.display());
    }
    Ok(Ledger::open_read_only(&path, config.local_zone().clone())?)
}
fn ledger_reset(config: &Path, reason: &str) -> Result<()> {
    let config = Config::load(config)?;
    if reason.trim().len() < 3 {
        bail!("--reason must say why the ledger is being reset (it is recorded)");
    }
    let now = SystemTime.wall_ms();
    let (_, kept) = Ledger::reset_acknowledged(&config.state_dir, config.local_zone().clone(), reason, now)?;
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

fn verify(
    bundle: &Path,
    trust: &Path,
    stage: restage_shared::light::StageLimits,
    allow_demo_key: bool,
) -> Result<()> {
    // The one time of this load, taken before anything is read.
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .context("the system clock is before 1970")?
        .as_secs() as i64;
    print!("{}", restage_appliance::verify::verify_report(bundle, trust, now, stage, allow_demo_key)?);
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
    let ledger = open_ledger_read_only(&config)?;
    let now = ledger_now(&ledger)?;
    let s = ledger.status(now)?;
    let installed =
        loader::installed(&config.bundle_path(), &config.trust_dir, config.allow_demo_key, &ledger, now);
    let mut out = std::io::stdout().lock();
    if json {
        let v = serde_json::json!({ "ledger": s, "installed": installed });
        writeln!(out, "{}", serde_json::to_string_pretty(&v)?)?;
        return Ok(());
    }
    let zone = config.local_zone();
    let time = |ms: i64| zone.local_time(ms);
    writeln!(out, "now: {} ({})", time(now), zone.name())?;
    match &s.active {
        Some(a) => writeln!(
            out,
            "playing: {} version {} ({}), since {}",
            printable(&a.object),
            a.version,
            &a.bundle_hash[..16.min(a.bundle_hash.len())],
            time(a.loaded_ms)
        )?,
        None => writeln!(
            out,
            "playing: nothing yet (the appliance plays the installed bundle once it starts or reloads)"
        )?,
    }
    let what = match (&installed.object, installed.version) {
        (Some(o), Some(v)) => format!("{} version {v}", printable(o)),
        _ => "no readable bundle".to_string(),
    };
    let expiry = match installed.expires_unix_ms {
        Some(e) => {
            let days = (e - now) as f64 / 86_400_000.0;
            if days >= 0.0 {
                format!("expires {} (in {days:.0} days)", time(e))
            } else {
                format!("EXPIRED {} ({:.0} days ago)", time(e), -days)
            }
        }
        None => "no expiry".to_string(),
    };
    writeln!(out, "installed: {what} at {}; {expiry}", installed.path)?;
    if let Some(p) = &installed.problem {
        writeln!(out, "  REFUSED: {}", printable(p))?;
    }
    let opening = config.opening_hours().at(now);
    if config.opening_hours().is_scheduled() {
        writeln!(out, "opening hours: {}", opening.reason)?;
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
            time(sh.started_ms),
            (sh.ended_ms - sh.started_ms) as f64 / 1000.0,
            printable(&sh.scenes),
            sh.ended_by
        )?;
    }
    writeln!(out, "last events:")?;
    for e in &s.last_events {
        writeln!(out, "  {} {}: {}", time(e.at_ms), e.kind, printable(&e.detail))?;
    }
    Ok(())
}

fn install(bundle: &Path, config: &Path) -> Result<()> {
    let config = Config::load(config)?;
    let ledger = Ledger::open_stage(&config.state_dir, config.local_zone().clone())?;
    let now = ledger_now(&ledger)?;
    let opts = loader::LoadOptions::from_config(&config);
    let target = config.bundle_path();
    // A crash leaves the old bundle or the new one, never a mix; a showing on the running
    // appliance does not wait behind the copy.
    let what = restage_appliance::install::install_verified(
        bundle,
        &target,
        &config.trust_dir,
        &ledger,
        now,
        &opts,
    )?;
    eprintln!("verified: {what}");
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

#[cfg(test)]
mod tests {
    use super::Cli;
    use clap::CommandFactory;
    use std::path::Path;

    /// The Debian package ships `appliance/man/*.1`; they must say what the program does, so
    /// they are generated from the command line's own definition and checked here.
    /// `RESTAGE_UPDATE_GOLDEN=1` rewrites them after a change to the options.
    #[test]
    fn the_packaged_man_pages_are_the_command_lines_own() {
        let fresh = tempfile::tempdir().unwrap();
        clap_mangen::generate_to(Cli::command(), fresh.path()).unwrap();
        let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("man");
        let pages = |dir: &Path| {
            let mut names: Vec<String> = std::fs::read_dir(dir)
                .map(|d| d.map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect())
                .unwrap_or_default();
            names.sort();
            names
        };
        if std::env::var_os("RESTAGE_UPDATE_GOLDEN").is_some() {
            let _ = std::fs::remove_dir_all(&committed);
            std::fs::create_dir_all(&committed).unwrap();
            for name in pages(fresh.path()) {
                std::fs::copy(fresh.path().join(&name), committed.join(&name)).unwrap();
            }
        }
        let names = pages(fresh.path());
        assert!(names.contains(&"restage-appliance.1".to_string()), "{names:?}");
        assert_eq!(pages(&committed), names, "man pages in {}", committed.display());
        for name in &names {
            let want = std::fs::read(fresh.path().join(name)).unwrap();
            let have = std::fs::read(committed.join(name)).unwrap();
            assert!(
                want == have,
                "{} differs from what the command line generates; RESTAGE_UPDATE_GOLDEN=1 rewrites it",
                committed.join(name).display()
            );
        }
    }
}
