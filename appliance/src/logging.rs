//! How the appliance's log lines look: colours on a terminal only; under systemd each line
//! carries the sd-daemon priority prefix (`<3>` error ... `<7>` debug, parsed by journald's
//! default `SyslogLevelPrefix=yes`) and no timestamp (journald stamps its own).

use std::io::IsTerminal;

use tracing::{Event, Level, Subscriber};
use tracing_subscriber::EnvFilter;
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields, MakeWriter};
use tracing_subscriber::registry::LookupSpan;

/// Where the log goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogStyle {
    /// A terminal: the usual format, in colour.
    Terminal,
    /// A file or pipe: the usual format, no escape codes.
    Plain,
    /// systemd's journal: priority prefix, no timestamp, no escape codes.
    Journal,
}

/// Picks the style (`colour_terminal`: stderr is a terminal that wants colour, [`wants_colour`]). `journal_stream` is `$JOURNAL_STREAM` ("DEVICE:INODE" of the journal's
/// stream, set by systemd); it counts only when it names stderr (`stderr_id`, when known): a
/// program started from a unit with its stderr redirected elsewhere is not writing there.
pub fn style(colour_terminal: bool, journal_stream: Option<&str>, stderr_id: Option<(u64, u64)>) -> LogStyle {
    let names_stderr = |v: &str| match (v.split_once(':'), stderr_id) {
        (Some((dev, ino)), Some((d, i))) => dev.parse() == Ok(d) && ino.parse() == Ok(i),
        // stderr unknown: take systemd's word.
        (Some(_), None) => true,
        (None, _) => false,
    };
    if journal_stream.is_some_and(names_stderr) {
        LogStyle::Journal
    } else if colour_terminal {
        LogStyle::Terminal
    } else {
        LogStyle::Plain
    }
}

/// Whether a terminal wants colour: not with `NO_COLOR` set (no-color.org), nor without a
/// `TERM` or with `TERM=dumb` (a serial console, as on a stage machine's boot console, where
/// escape codes only garble the lines operators and tests read).
pub fn wants_colour(term: Option<&str>, no_color: Option<&str>) -> bool {
    no_color.is_none_or(str::is_empty) && term.is_some_and(|t| !t.is_empty() && t != "dumb")
}

/// This process's stderr's (device, inode).
fn stderr_id() -> Option<(u64, u64)> {
    use std::os::fd::AsFd;
    use std::os::unix::fs::MetadataExt;
    let fd = std::io::stderr().as_fd().try_clone_to_owned().ok()?;
    let meta = std::fs::File::from(fd).metadata().ok()?;
    Some((meta.dev(), meta.ino()))
}

/// The sd-daemon(3) prefix for `level`.
pub fn priority_prefix(level: Level) -> &'static str {
    match level {
        Level::ERROR => "<3>",
        Level::WARN => "<4>",
        Level::INFO => "<6>",
        Level::DEBUG | Level::TRACE => "<7>",
    }
}

/// Journal lines: `<P>target: message field=value`; a message of several lines gives several
/// journal lines, each with the prefix (journald splits at newlines).
#[derive(Clone, Copy, Debug, Default)]
pub struct JournalFormat;

impl<S, N> FormatEvent<S, N> for JournalFormat
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut writer: Writer<'_>,
        event: &Event<'_>,
    ) -> std::fmt::Result {
        // Fields into a plain buffer (no escape codes whatever the writer says).
        let mut fields = String::new();
        ctx.format_fields(Writer::new(&mut fields), event)?;
        let prefix = priority_prefix(*event.metadata().level());
        let target = event.metadata().target();
        let mut lines = fields.lines();
        writeln!(writer, "{prefix}{target}: {}", lines.next().unwrap_or(""))?;
        for line in lines {
            writeln!(writer, "{prefix}{line}")?;
        }
        Ok(())
    }
}

/// A subscriber in `style` writing to `writer`.
pub fn subscriber<W>(style: LogStyle, filter: EnvFilter, writer: W) -> Box<dyn Subscriber + Send + Sync>
where
    W: for<'a> MakeWriter<'a> + Send + Sync + 'static,
{
    let builder = tracing_subscriber::fmt().with_env_filter(filter).with_writer(writer);
    match style {
        LogStyle::Terminal => Box::new(builder.with_ansi(true).finish()),
        LogStyle::Plain => Box::new(builder.with_ansi(false).finish()),
        LogStyle::Journal => Box::new(builder.with_ansi(false).event_format(JournalFormat).finish()),
    }
}

/// Installs the global subscriber for stderr, in the style its destination wants.
pub fn init(filter: EnvFilter) {
    let journal = std::env::var("JOURNAL_STREAM").ok();
    let (term, no_color) = (std::env::var("TERM").ok(), std::env::var("NO_COLOR").ok());
    let colour = std::io::stderr().is_terminal() && wants_colour(term.as_deref(), no_color.as_deref());
    let style = style(colour, journal.as_deref(), stderr_id());
    if tracing::subscriber::set_global_default(subscriber(style, filter, std::io::stderr)).is_err() {
        // Only a second call gets here; the first subscriber stays.
        tracing::warn!("logging was already set up");
    }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use super::*;

    #[derive(Clone, Default)]
    struct Capture(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Capture {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn logged(style: LogStyle) -> String {
        let out = Capture::default();
        let w = out.clone();
        let sub = subscriber(style, EnvFilter::new("debug"), move || w.clone());
        tracing::subscriber::with_default(sub, || {
            tracing::error!("boom");
            tracing::warn!(pin = 17, "careful");
            tracing::info!("two\nlines");
            tracing::debug!("detail");
            tracing::trace!("not shown");
        });
        String::from_utf8(out.0.lock().unwrap().clone()).unwrap()
    }

    #[test]
    fn journal_lines_carry_the_priority_and_nothing_else() {
        let text = logged(LogStyle::Journal);
        let lines: Vec<&str> = text.lines().collect();
        let m = "restage_appliance::logging::tests";
        assert_eq!(
            lines,
            [
                format!("<3>{m}: boom"),
                format!("<4>{m}: careful pin=17"),
                format!("<6>{m}: two"),
                "<6>lines".to_string(),
                format!("<7>{m}: detail"),
            ]
        );
        assert!(!text.contains('\x1b'));
    }

    #[test]
    fn plain_has_no_escape_codes_and_terminal_has_colour() {
        let plain = logged(LogStyle::Plain);
        assert!(plain.contains("boom") && !plain.contains('\x1b'), "{plain:?}");
        assert!(!plain.contains("<3>"));
        // The check above can fail: the terminal style does write escapes.
        assert!(logged(LogStyle::Terminal).contains('\x1b'));
    }

    #[test]
    fn colour_only_where_a_terminal_wants_it() {
        assert!(wants_colour(Some("xterm-256color"), None));
        assert!(wants_colour(Some("linux"), Some("")));
        assert!(!wants_colour(Some("xterm"), Some("1")));
        assert!(!wants_colour(Some("dumb"), None));
        assert!(!wants_colour(None, None));
    }

    #[test]
    fn style_follows_stderr() {
        assert_eq!(style(true, None, Some((1, 2))), LogStyle::Terminal);
        assert_eq!(style(false, None, Some((1, 2))), LogStyle::Plain);
        assert_eq!(style(false, Some("1:2"), Some((1, 2))), LogStyle::Journal);
        // JOURNAL_STREAM inherited, stderr elsewhere: not the journal.
        assert_eq!(style(true, Some("1:3"), Some((1, 2))), LogStyle::Terminal);
        assert_eq!(style(false, Some("garbage"), Some((1, 2))), LogStyle::Plain);
        assert_eq!(style(false, Some("8:9"), None), LogStyle::Journal);
        assert_eq!(priority_prefix(Level::TRACE), "<7>");
    }
}
