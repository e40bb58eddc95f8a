//! The headless recorder: every frame and blank, with its time, written to a folder, for tests
//! and measurements. No display needed.
//!
//! Layout: `DIR/log.tsv`, one line per output change, appended with a single write so a
//! killed process never leaves half a line: `UNIX_US<TAB>BOOT_US<TAB>show<TAB>FILE[<TAB>FILE...]`
//! (one frame file per projector) or `UNIX_US<TAB>BOOT_US<TAB>blank`. `BOOT_US` is the
//! kernel's CLOCK_BOOTTIME, read here and not through the appliance's injected clock, so a
//! test can judge the ledger's timeline against an independent one. Frame files are
//! `DIR/frames/<blake3>-<W>x<H>.xrgb` (raw XRGB8888, written once per distinct content).

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use super::{FrameRef, Output, OutputError, check_frames};

/// Records frames into a folder.
#[derive(Debug)]
pub struct HeadlessOutput {
    dir: PathBuf,
    log: File,
    projectors: usize,
    sizes: Option<Vec<(u32, u32)>>,
}

/// The log's file name inside the recorder folder.
pub const LOG_FILE: &str = "log.tsv";

impl HeadlessOutput {
    /// Opens (creating) the recorder folder for `projectors` outputs.
    pub fn open(dir: &Path, projectors: usize) -> Result<HeadlessOutput, OutputError> {
        let err = |e: std::io::Error| OutputError::Device {
            output: format!("headless {}", dir.display()),
            problem: e.to_string(),
        };
        std::fs::create_dir_all(dir.join("frames")).map_err(err)?;
        let log = OpenOptions::new().create(true).append(true).open(dir.join(LOG_FILE)).map_err(err)?;
        Ok(HeadlessOutput { dir: dir.to_path_buf(), log, projectors, sizes: None })
    }

    fn err(&self, e: std::io::Error) -> OutputError {
        OutputError::Device { output: format!("headless {}", self.dir.display()), problem: e.to_string() }
    }

    fn append(&mut self, line: String) -> Result<(), OutputError> {
        self.log.write_all(line.as_bytes()).map_err(|e| self.err(e))
    }
}

/// `UNIX_US<TAB>BOOT_US`, now.
fn stamp() -> String {
    format!("{}\t{}", crate::clock::unix_us(), crate::clock::boot_us())
}

impl Output for HeadlessOutput {
    fn projector_count(&self) -> usize {
        self.projectors
    }

    fn set_modes(&mut self, sizes: &[(u32, u32)]) -> Result<(), OutputError> {
        self.projectors = sizes.len();
        self.sizes = Some(sizes.to_vec());
        Ok(())
    }

    fn show(&mut self, frames: &[FrameRef<'_>]) -> Result<(), OutputError> {
        check_frames(self.projectors, self.sizes.as_deref(), frames)?;
        let mut line = String::new();
        for f in frames {
            let name = format!("{}-{}x{}.xrgb", blake3::hash(f.xrgb).to_hex(), f.width, f.height);
            let path = self.dir.join("frames").join(&name);
            if !path.exists() {
                let tmp = self.dir.join("frames").join(format!(".{name}.tmp"));
                std::fs::write(&tmp, f.xrgb)
                    .and_then(|_| std::fs::rename(&tmp, &path))
                    .map_err(|e| self.err(e))?;
            }
            line.push('\t');
            line.push_str(&name);
        }
        // The time is taken when the frame is "on screen": after its file exists.
        self.append(format!("{}\tshow{line}\n", stamp()))
    }

    fn blank(&mut self) -> Result<(), OutputError> {
        self.append(format!("{}\tblank\n", stamp()))
    }
}

/// One line of a recorder log.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    pub unix_us: u128,
    /// CLOCK_BOOTTIME, microseconds.
    pub boot_us: u64,
    /// Frame file names (one per projector); empty for a blank.
    pub frames: Vec<String>,
}

/// Reads a recorder log (tests, measurements). A torn last line is skipped.
pub fn read_log(dir: &Path) -> std::io::Result<Vec<Record>> {
    let text = std::fs::read_to_string(dir.join(LOG_FILE))?;
    let mut out = Vec::new();
    for line in text.split_inclusive('\n').filter(|l| l.ends_with('\n')) {
        let mut parts = line.trim_end().split('\t');
        let (Some(t), Some(b), Some(kind)) = (parts.next(), parts.next(), parts.next()) else { continue };
        let (Ok(unix_us), Ok(boot_us)) = (t.parse(), b.parse()) else { continue };
        let frames = if kind == "show" { parts.map(String::from).collect() } else { Vec::new() };
        out.push(Record { unix_us, boot_us, frames });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_frames_and_blanks_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut o = HeadlessOutput::open(dir.path(), 2).unwrap();
        o.set_modes(&[(2, 1), (1, 1)]).unwrap();
        let a = [1u8, 2, 3, 0, 4, 5, 6, 0];
        let b = [9u8, 9, 9, 0];
        o.show(&[FrameRef { width: 2, height: 1, xrgb: &a }, FrameRef { width: 1, height: 1, xrgb: &b }])
            .unwrap();
        o.blank().unwrap();
        let log = read_log(dir.path()).unwrap();
        assert_eq!(log.len(), 2);
        assert_eq!(log[0].frames.len(), 2);
        assert!(log[1].frames.is_empty());
        assert!(log[0].unix_us <= log[1].unix_us);
        assert_eq!(std::fs::read(dir.path().join("frames").join(&log[0].frames[0])).unwrap(), a);
        // Wrong sizes are refused.
        let e = o.show(&[FrameRef { width: 1, height: 1, xrgb: &b }]).unwrap_err();
        assert!(matches!(e, OutputError::FrameCount { expected: 2, got: 1 }));
    }
}
