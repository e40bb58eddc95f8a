//! The bundle inbox: a folder (where a USB stick is mounted, or one an operator copies to)
//! watched for signed bundles. A `*.bundle` file is taken once it has stood unchanged for
//! [`SETTLE_MS`] (a copy still under way is not), then verified and installed by the runtime; it is moved to `installed/` or `refused/` (with `NAME.txt` saying why), so the
//! operator sees the outcome where they put the file.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

/// A file's size and modification time: unchanged for a while, it is complete.
type Stamp = (u64, Option<SystemTime>);

/// How long a file must stand unchanged before it is taken (monotonic ms): longer than a
/// copier's pauses between writes.
pub const SETTLE_MS: u64 = 4_000;

#[derive(Debug)]
pub struct Inbox {
    dir: PathBuf,
    /// What the previous scan saw, and since when (monotonic ms) unchanged.
    last: HashMap<PathBuf, (Stamp, u64)>,
    /// Files finished with that could not be moved away (a read-only stick): not taken again
    /// unless they change.
    done: HashSet<(PathBuf, Stamp)>,
    /// Why the folder could not be read at the last scan (not "it is not there": no stick in),
    /// said once in the journal when it starts.
    problem: Option<String>,
}

impl Inbox {
    pub fn new(dir: &Path) -> Self {
        Self { dir: dir.into(), last: HashMap::new(), done: HashSet::new(), problem: None }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Why the folder could not be read at the last scan, if it is there but unreadable.
    pub fn problem(&self) -> Option<&str> {
        self.problem.as_deref()
    }

    /// Scans the folder at `now_ms` (monotonic); returns the first bundle (by name) that has
    /// stood unchanged for [`SETTLE_MS`]. A missing folder (no stick in) holds nothing; one
    /// that cannot be read holds nothing either, and the journal says why once.
    pub fn next_ready(&mut self, now_ms: u64) -> Option<PathBuf> {
        let listing = std::fs::read_dir(&self.dir);
        let problem = match &listing {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Some(format!("bundle inbox {} cannot be read: {e}", self.dir.display()))
            }
            _ => None,
        };
        if problem != self.problem {
            if let Some(p) = &problem {
                tracing::warn!("{p}");
            }
            self.problem = problem;
        }
        let mut now: Vec<(PathBuf, Stamp)> = listing
            .map(|entries| {
                entries
                    .flatten()
                    .filter(|e| {
                        e.file_name().to_str().is_some_and(|n| {
                            !n.starts_with('.') && n.to_ascii_lowercase().ends_with(".bundle")
                        })
                    })
                    .filter_map(|e| {
                        let m = e.metadata().ok().filter(|m| m.is_file())?;
                        Some((e.path(), (m.len(), m.modified().ok())))
                    })
                    .collect()
            })
            .unwrap_or_default();
        now.sort();
        let last = std::mem::take(&mut self.last);
        for (p, stamp) in now {
            let since = last.get(&p).filter(|(s, _)| *s == stamp).map_or(now_ms, |&(_, t)| t);
            self.last.insert(p, (stamp, since));
        }
        let mut ready: Vec<&PathBuf> = self
            .last
            .iter()
            .filter(|(p, (stamp, since))| {
                now_ms.saturating_sub(*since) >= SETTLE_MS && !self.done.contains(&((*p).clone(), *stamp))
            })
            .map(|(p, _)| p)
            .collect();
        ready.sort();
        ready.first().map(|p| (*p).clone())
    }

    /// Moves `file` into `installed/` or `refused/` (writing why beside a refused one). Where
    /// it cannot be moved, remembers it so that it is not taken again unless it changes.
    /// Returns where it went, or why it stayed.
    pub fn finish(&mut self, file: &Path, refused: Option<&str>) -> Result<PathBuf, String> {
        let sub = self.dir.join(if refused.is_some() { "refused" } else { "installed" });
        let name = file.file_name().unwrap_or_default();
        let to = sub.join(name);
        let moved = std::fs::create_dir_all(&sub).and_then(|()| std::fs::rename(file, &to)).and_then(|()| {
            match refused {
                Some(why) => {
                    let mut note = to.clone().into_os_string();
                    note.push(".txt");
                    std::fs::write(note, format!("{why}\n"))
                }
                None => Ok(()),
            }
        });
        match moved {
            Ok(()) => Ok(to),
            Err(e) => {
                if let Some((stamp, _)) = self.last.get(file) {
                    self.done.insert((file.into(), *stamp));
                }
                Err(format!("cannot move it to {}: {e}", sub.display()))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bundle_is_taken_once_it_stood_unchanged_for_a_scan() {
        let dir = tempfile::tempdir().unwrap();
        let mut inbox = Inbox::new(dir.path());
        let file = dir.path().join("new.bundle");
        std::fs::write(&file, b"first half").unwrap();
        std::fs::write(dir.path().join("notes.txt"), b"not a bundle").unwrap();
        std::fs::write(dir.path().join(".hidden.bundle"), b"a copier's temporary file").unwrap();
        assert_eq!(inbox.next_ready(0), None, "seen for the first time");
        std::fs::write(&file, b"first half, second half").unwrap();
        assert_eq!(inbox.next_ready(SETTLE_MS), None, "still growing");
        assert_eq!(inbox.next_ready(2 * SETTLE_MS - 1), None, "not settled long enough");
        assert_eq!(inbox.next_ready(2 * SETTLE_MS), Some(file.clone()));
        let to = inbox.finish(&file, Some("bundle new.bundle refused: bad signature")).unwrap();
        assert_eq!(to, dir.path().join("refused/new.bundle"));
        let why = std::fs::read_to_string(dir.path().join("refused/new.bundle.txt")).unwrap();
        assert!(why.contains("bad signature"), "{why}");
        assert_eq!(inbox.next_ready(3 * SETTLE_MS), None, "gone from the inbox");
    }

    #[test]
    fn a_folder_that_is_not_there_holds_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let mut inbox = Inbox::new(&dir.path().join("stick"));
        assert_eq!(inbox.next_ready(0), None);
        assert_eq!(inbox.next_ready(SETTLE_MS), None);
        assert_eq!(inbox.problem(), None, "no stick in is not a problem");
    }

    #[test]
    fn a_folder_that_cannot_be_read_is_named_and_forgotten_once_readable() {
        let dir = tempfile::tempdir().unwrap();
        let at = dir.path().join("stick");
        // A file where the folder should be (as root, a folder without permissions would
        // still be readable).
        std::fs::write(&at, b"").unwrap();
        let mut inbox = Inbox::new(&at);
        assert_eq!(inbox.next_ready(0), None);
        let p = inbox.problem().expect("the problem is kept").to_string();
        assert!(p.contains("stick") && p.contains("cannot be read"), "{p}");
        std::fs::remove_file(&at).unwrap();
        std::fs::create_dir(&at).unwrap();
        assert_eq!(inbox.next_ready(SETTLE_MS), None);
        assert_eq!(inbox.problem(), None);
    }

    #[test]
    fn a_file_that_cannot_be_moved_is_not_taken_again_unless_it_changes() {
        let dir = tempfile::tempdir().unwrap();
        let mut inbox = Inbox::new(dir.path());
        let file = dir.path().join("a.bundle");
        std::fs::write(&file, b"bundle").unwrap();
        // `installed` is a file here, so nothing can be moved into it.
        std::fs::write(dir.path().join("installed"), b"").unwrap();
        inbox.next_ready(0);
        assert_eq!(inbox.next_ready(SETTLE_MS), Some(file.clone()));
        assert!(inbox.finish(&file, None).is_err());
        assert_eq!(inbox.next_ready(2 * SETTLE_MS), None);
        std::fs::write(&file, b"another bundle").unwrap();
        inbox.next_ready(3 * SETTLE_MS);
        assert_eq!(inbox.next_ready(4 * SETTLE_MS), Some(file));
    }
}
