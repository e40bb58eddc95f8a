//! Updates of the stage machine's own software (the image of `tools/image/`): a signed update
//! folder (a root file system, kernel and initramfs, and a manifest of their sizes and BLAKE3
//! hashes signed with Ed25519) is verified, written to the root slot that is not running, and
//! given a boot entry on trial. systemd-boot counts the slot's tries; the image's
//! `restage-boot-check.service` marks it good once the appliance is ready, and when the tries
//! run out the boot loader goes back to the other slot.
//!
//! Nothing is written before the whole update is verified, and the order of the writes keeps
//! every moment bootable: the target slot's old entry goes first (a half-written slot has
//! none), the new entry last (only a completely written slot gets one).

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use ed25519_dalek::{Signature, Signer};
use restage_shared::keys::{SigningKey, TrustStore, from_hex, to_hex};
use serde::{Deserialize, Serialize};

/// The manifest's file name in an update folder.
pub const MANIFEST: &str = "manifest.toml";
/// The signature of the manifest (hex, 128 digits).
pub const SIGNATURE: &str = "manifest.sig";
/// The files an update carries.
pub const FILES: [&str; 3] = ["root.squashfs", "vmlinuz", "initrd"];
/// What the signature covers before the manifest's bytes (no other signed restage object
/// can be passed off as an update manifest).
const DOMAIN: &[u8] = b"restage image update v1\0";

/// What an update is: its version and each file's size and hash.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// The image version it installs (`IMAGE_VERSION` in its os-release).
    pub version: String,
    pub files: BTreeMap<String, FileEntry>,
}

#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileEntry {
    pub size: u64,
    /// BLAKE3, 64 lowercase hex digits.
    pub blake3: String,
}

#[derive(Debug, thiserror::Error)]
pub enum UpdateError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not an update manifest: {message}")]
    Manifest { path: PathBuf, message: String },
    #[error(
        "{path}: the signature is not valid for any key in {trust} (tampered, or signed with a key this machine does not trust)"
    )]
    Signature { path: PathBuf, trust: PathBuf },
    #[error("{path}: {got} bytes, the signed manifest says {want}")]
    Size { path: PathBuf, got: u64, want: u64 },
    #[error("{path}: its content is not what the signed manifest says (BLAKE3 {got}, signed {want})")]
    Hash { path: PathBuf, got: String, want: String },
    #[error("update {update} is not newer than the running image {running}: refused (no downgrades)")]
    NotNewer { update: String, running: String },
    #[error("{device}: the slot holds {slot} bytes, the update's root file system is {need}")]
    TooBig { device: PathBuf, slot: u64, need: u64 },
    #[error(
        "the running slot {0} is still on trial (its boot entry counts tries): update once it is marked good"
    )]
    OnTrial(Slot),
    #[error("cannot tell which root slot is running: {0}")]
    NoSlot(String),
}

type Result<T> = std::result::Result<T, UpdateError>;

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> UpdateError + '_ {
    move |source| UpdateError::Io { path: path.into(), source }
}

/// One of the two root slots.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slot {
    A,
    B,
}

impl Slot {
    pub fn other(self) -> Slot {
        match self {
            Slot::A => Slot::B,
            Slot::B => Slot::A,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Slot::A => "a",
            Slot::B => "b",
        }
    }

    /// The slot a kernel command line names (`restage.slot=a`).
    pub fn from_cmdline(cmdline: &str) -> Option<Slot> {
        cmdline.split_whitespace().find_map(|w| match w {
            "restage.slot=a" => Some(Slot::A),
            "restage.slot=b" => Some(Slot::B),
            _ => None,
        })
    }
}

impl std::fmt::Display for Slot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Reads `path` through, hashing it; (size, hex BLAKE3). With `copy_to`, writes what it reads
/// there too (so what is written is exactly what was hashed).
fn hash_file(path: &Path, mut copy_to: Option<(&mut dyn Write, &Path)>) -> Result<(u64, String)> {
    let mut f = std::fs::File::open(path).map_err(io(path))?;
    let mut h = blake3::Hasher::new();
    let mut buf = vec![0u8; 1 << 20];
    let mut n = 0u64;
    loop {
        let k = f.read(&mut buf).map_err(io(path))?;
        if k == 0 {
            break;
        }
        h.update(&buf[..k]);
        if let Some((w, to)) = copy_to.as_mut() {
            w.write_all(&buf[..k]).map_err(io(to))?;
        }
        n += k as u64;
    }
    Ok((n, h.finalize().to_hex().to_string()))
}

/// Hashes the update's files in `dir` and writes its manifest and signature (the build
/// machine's side: `restage-appliance update sign`).
pub fn sign(dir: &Path, version: &str, key: &SigningKey) -> Result<Manifest> {
    let mut files = BTreeMap::new();
    for name in FILES {
        let (size, blake3) = hash_file(&dir.join(name), None)?;
        files.insert(name.to_string(), FileEntry { size, blake3 });
    }
    let manifest = Manifest { version: version.to_string(), files };
    let text = toml::to_string(&manifest)
        .map_err(|e| UpdateError::Manifest { path: dir.join(MANIFEST), message: e.to_string() })?;
    let path = dir.join(MANIFEST);
    std::fs::write(&path, &text).map_err(io(&path))?;
    let signature = key.sign(&[DOMAIN, text.as_bytes()].concat());
    let sig_path = dir.join(SIGNATURE);
    std::fs::write(&sig_path, to_hex(&signature.to_bytes()) + "\n").map_err(io(&sig_path))?;
    Ok(manifest)
}

/// Checks the update in `dir`: its manifest's signature against `trust` (`trust_dir` names
/// it in messages), then every file's size and hash. Returns the manifest.
pub fn verify(dir: &Path, trust: &TrustStore, trust_dir: &Path) -> Result<Manifest> {
    let path = dir.join(MANIFEST);
    let text = std::fs::read(&path).map_err(io(&path))?;
    let sig_path = dir.join(SIGNATURE);
    let sig_text = std::fs::read_to_string(&sig_path).map_err(io(&sig_path))?;
    let bad_sig = || UpdateError::Signature { path: sig_path.clone(), trust: trust_dir.into() };
    let bytes = from_hex::<64>(sig_text.trim()).ok_or_else(bad_sig)?;
    let signature = Signature::from_bytes(&bytes);
    let signed = [DOMAIN, &text].concat();
    let trusted =
        trust.ids().filter_map(|id| trust.get(id)).any(|k| k.key.verify_strict(&signed, &signature).is_ok());
    if !trusted {
        return Err(bad_sig());
    }
    let manifest_err = |message: String| UpdateError::Manifest { path: path.clone(), message };
    let text = std::str::from_utf8(&text).map_err(|e| manifest_err(e.to_string()))?;
    let manifest: Manifest = toml::from_str(text).map_err(|e| manifest_err(e.to_string()))?;
    for name in FILES {
        let want = manifest.files.get(name).ok_or_else(|| manifest_err(format!("no entry for {name}")))?;
        let file = dir.join(name);
        let (size, hash) = hash_file(&file, None)?;
        check(&file, size, &hash, want)?;
    }
    Ok(manifest)
}

/// The manifest's entry for `name`.
fn entry<'a>(manifest: &'a Manifest, name: &str) -> Result<&'a FileEntry> {
    manifest.files.get(name).ok_or_else(|| UpdateError::Manifest {
        path: PathBuf::from(MANIFEST),
        message: format!("no entry for {name}"),
    })
}

fn check(path: &Path, size: u64, hash: &str, want: &FileEntry) -> Result<()> {
    if size != want.size {
        return Err(UpdateError::Size { path: path.into(), got: size, want: want.size });
    }
    if hash != want.blake3 {
        return Err(UpdateError::Hash { path: path.into(), got: hash.into(), want: want.blake3.clone() });
    }
    Ok(())
}

/// Compares image versions the way people read them: runs of digits as numbers, other text
/// as text (`0.1.0-10` is newer than `0.1.0-9`).
pub fn version_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    fn parts(s: &str) -> Vec<(bool, &str)> {
        let mut out = Vec::new();
        let mut start = 0;
        let bytes = s.as_bytes();
        for i in 1..=bytes.len() {
            if i == bytes.len() || bytes[i].is_ascii_digit() != bytes[start].is_ascii_digit() {
                out.push((bytes[start].is_ascii_digit(), &s[start..i]));
                start = i;
            }
        }
        out
    }
    let (pa, pb) = (parts(a), parts(b));
    for (x, y) in pa.iter().zip(&pb) {
        let o = match (x, y) {
            ((true, x), (true, y)) => {
                let (x, y) = (x.trim_start_matches('0'), y.trim_start_matches('0'));
                x.len().cmp(&y.len()).then(x.cmp(y))
            }
            ((_, x), (_, y)) => x.cmp(y),
        };
        if o.is_ne() {
            return o;
        }
    }
    pa.len().cmp(&pb.len())
}

/// Where an update goes on the stage machine.
#[derive(Clone, Debug)]
pub struct Layout {
    /// The running slot.
    pub running: Slot,
    /// The running image's version.
    pub running_version: String,
    /// The running kernel's command line (the new entry keeps its provisioned arguments).
    pub cmdline: String,
    /// The EFI system partition, mounted.
    pub esp: PathBuf,
    /// The block device (or file) of each slot's root file system.
    pub slot_device: [PathBuf; 2],
}

impl Layout {
    /// The stage machine's own layout: slot and command line from `/proc/cmdline`, version
    /// from `/usr/lib/os-release`, the ESP at `/efi`, the slots by partition label.
    pub fn of_this_machine() -> Result<Layout> {
        let cmdline_path = Path::new("/proc/cmdline");
        let cmdline = std::fs::read_to_string(cmdline_path).map_err(io(cmdline_path))?;
        let running = Slot::from_cmdline(&cmdline).ok_or_else(|| {
            UpdateError::NoSlot(format!("no restage.slot= in /proc/cmdline ({})", cmdline.trim()))
        })?;
        let os_release = Path::new("/usr/lib/os-release");
        let text = std::fs::read_to_string(os_release).map_err(io(os_release))?;
        let running_version = text
            .lines()
            .find_map(|l| l.strip_prefix("IMAGE_VERSION="))
            .map(|v| v.trim_matches('"').to_string())
            .ok_or_else(|| {
                UpdateError::NoSlot("no IMAGE_VERSION in /usr/lib/os-release (not a restage image?)".into())
            })?;
        let part = |s: &str| PathBuf::from(format!("/dev/disk/by-partlabel/restage-root-{s}"));
        Ok(Layout {
            running,
            running_version,
            cmdline: cmdline.trim().to_string(),
            esp: PathBuf::from("/efi"),
            slot_device: [part("a"), part("b")],
        })
    }

    fn entries(&self) -> PathBuf {
        self.esp.join("loader/entries")
    }

    /// The boot entry files of `slot` (`restage-a.conf`, or `restage-a+2-1.conf` on trial).
    fn entry_files(&self, slot: Slot) -> Result<Vec<PathBuf>> {
        let dir = self.entries();
        let prefix = format!("restage-{slot}");
        let mut out = Vec::new();
        for e in std::fs::read_dir(&dir).map_err(io(&dir))? {
            let e = e.map_err(io(&dir))?;
            let name = e.file_name().to_string_lossy().into_owned();
            if name.ends_with(".conf")
                && (name == format!("{prefix}.conf") || name.starts_with(&format!("{prefix}+")))
            {
                out.push(e.path());
            }
        }
        Ok(out)
    }
}

/// The boot entry of `slot` for `version` (as `tools/image/entry.sh` writes the first): the
/// running command line with the root and slot switched. The sort key makes systemd-boot
/// order entries newest version first and one with no tries left last.
fn entry_text(slot: Slot, version: &str, cmdline: &str) -> String {
    let options: Vec<String> = cmdline
        .split_whitespace()
        .filter(|w| !w.starts_with("BOOT_IMAGE=") && !w.starts_with("initrd="))
        .map(|w| {
            if w.starts_with("root=") {
                format!("root=PARTLABEL=restage-root-{slot}")
            } else if w.starts_with("restage.slot=") {
                format!("restage.slot={slot}")
            } else {
                w.to_string()
            }
        })
        .collect();
    format!(
        "title restage {version} (slot {slot})\nsort-key restage\nversion {version}\nlinux /restage/{slot}/vmlinuz\n\
         initrd /restage/{slot}/initrd\noptions {}\n",
        options.join(" ")
    )
}

fn write_synced(path: &Path, write: impl FnOnce(&mut std::fs::File) -> Result<()>) -> Result<()> {
    let mut f = std::fs::File::create(path).map_err(io(path))?;
    write(&mut f)?;
    f.sync_all().map_err(io(path))
}

/// Installs the verified update in `dir` (its `manifest`) into the slot that is not running,
/// with a boot entry allowing `tries` boots on trial. Returns the slot written.
pub fn install(dir: &Path, manifest: &Manifest, layout: &Layout, tries: u32) -> Result<Slot> {
    if version_cmp(&manifest.version, &layout.running_version).is_le() {
        return Err(UpdateError::NotNewer {
            update: manifest.version.clone(),
            running: layout.running_version.clone(),
        });
    }
    let running_entries = layout.entry_files(layout.running)?;
    if running_entries.iter().any(|p| p.file_name().is_some_and(|n| n.to_string_lossy().contains('+'))) {
        return Err(UpdateError::OnTrial(layout.running));
    }
    let target = layout.running.other();
    // 1. The target's entry goes: from here until step 4 nothing boots the target slot.
    for old in layout.entry_files(target)? {
        std::fs::remove_file(&old).map_err(io(&old))?;
    }
    sync_dir(&layout.entries())?;
    // 2. The root file system into the slot, hashed as it is written.
    let device = &layout.slot_device[match target {
        Slot::A => 0,
        Slot::B => 1,
    }];
    let root = dir.join("root.squashfs");
    let want = entry(manifest, "root.squashfs")?;
    let mut dev = std::fs::OpenOptions::new().write(true).open(device).map_err(io(device))?;
    let slot_size = dev.seek(SeekFrom::End(0)).map_err(io(device))?;
    let is_file = dev.metadata().map_err(io(device))?.is_file();
    if !is_file && slot_size < want.size {
        return Err(UpdateError::TooBig { device: device.clone(), slot: slot_size, need: want.size });
    }
    dev.seek(SeekFrom::Start(0)).map_err(io(device))?;
    let (size, hash) = hash_file(&root, Some((&mut dev as &mut dyn Write, device.as_path())))?;
    dev.sync_all().map_err(io(device))?;
    check(&root, size, &hash, want)?;
    // 3. Kernel and initramfs onto the ESP.
    let slot_dir = layout.esp.join("restage").join(target.name());
    std::fs::create_dir_all(&slot_dir).map_err(io(&slot_dir))?;
    for name in ["vmlinuz", "initrd"] {
        let (from, to) = (dir.join(name), slot_dir.join(name));
        let mut got = (0, String::new());
        write_synced(&to, |f| {
            got = hash_file(&from, Some((f as &mut dyn Write, to.as_path())))?;
            Ok(())
        })?;
        check(&from, got.0, &got.1, entry(manifest, name)?)?;
    }
    sync_dir(&slot_dir)?;
    // 4. The entry, on trial: systemd-boot counts `tries` boots down in its name.
    let entry = layout.entries().join(format!("restage-{target}+{tries}.conf"));
    let text = entry_text(target, &manifest.version, &layout.cmdline);
    write_synced(&entry, |f| f.write_all(text.as_bytes()).map_err(io(&entry)))?;
    sync_dir(&layout.entries())?;
    Ok(target)
}

fn sync_dir(dir: &Path) -> Result<()> {
    std::fs::File::open(dir).and_then(|d| d.sync_all()).map_err(io(dir))
}

#[cfg(test)]
mod tests {
    use super::*;
    use restage_shared::keys::signing_key_from_seed;

    fn update(dir: &Path, version: &str, key: &SigningKey) -> Manifest {
        std::fs::create_dir_all(dir).unwrap();
        for (i, name) in FILES.iter().enumerate() {
            std::fs::write(dir.join(name), vec![i as u8 + 1; 1000 + i * 7]).unwrap();
        }
        sign(dir, version, key).unwrap()
    }

    fn trust(key: &SigningKey) -> TrustStore {
        let mut t = TrustStore::new();
        t.insert(key.verifying_key(), "test.pem");
        t
    }

    /// A stage machine in a folder: ESP with slot A's entry, two slot files.
    fn machine(root: &Path, running: Slot, running_version: &str) -> Layout {
        let esp = root.join("esp");
        std::fs::create_dir_all(esp.join("loader/entries")).unwrap();
        let cmdline = format!(
            "root=PARTLABEL=restage-root-{running} ro quiet fbcon=map:9 restage.slot={running} video=Virtual-1:640x480@60e"
        );
        std::fs::write(
            esp.join(format!("loader/entries/restage-{running}.conf")),
            entry_text(running, running_version, &cmdline),
        )
        .unwrap();
        let slot_device = [root.join("slot-a"), root.join("slot-b")];
        for d in &slot_device {
            std::fs::write(d, vec![0xee; 4096]).unwrap();
        }
        Layout { running, running_version: running_version.into(), cmdline, esp, slot_device }
    }

    #[test]
    fn a_signed_update_goes_to_the_other_slot_on_trial() {
        let dir = tempfile::tempdir().unwrap();
        let key = signing_key_from_seed([3; 32]);
        let upd = dir.path().join("upd");
        update(&upd, "0.1.0-2", &key);
        let manifest = verify(&upd, &trust(&key), Path::new("trust")).unwrap();
        let layout = machine(&dir.path().join("m"), Slot::A, "0.1.0-1");
        assert_eq!(install(&upd, &manifest, &layout, 3).unwrap(), Slot::B);
        assert_eq!(
            std::fs::read(&layout.slot_device[1]).unwrap()[..1000],
            std::fs::read(upd.join("root.squashfs")).unwrap()[..]
        );
        assert_eq!(
            std::fs::read(&layout.slot_device[0]).unwrap(),
            vec![0xee; 4096],
            "the running slot untouched"
        );
        let entry = std::fs::read_to_string(layout.esp.join("loader/entries/restage-b+3.conf")).unwrap();
        assert!(entry.contains("options root=PARTLABEL=restage-root-b ro quiet fbcon=map:9 restage.slot=b video=Virtual-1:640x480@60e"), "{entry}");
        assert!(entry.contains("version 0.1.0-2") && entry.contains("linux /restage/b/vmlinuz"), "{entry}");
        assert_eq!(
            std::fs::read(layout.esp.join("restage/b/initrd")).unwrap(),
            std::fs::read(upd.join("initrd")).unwrap()
        );
        assert!(layout.esp.join("loader/entries/restage-a.conf").exists(), "the running slot's entry stays");
    }

    #[test]
    fn tampered_unsigned_and_old_updates_are_refused_before_anything_is_written() {
        let dir = tempfile::tempdir().unwrap();
        let key = signing_key_from_seed([3; 32]);
        let trusted = trust(&key);
        // A file changed after signing.
        let upd = dir.path().join("tampered");
        update(&upd, "0.1.0-2", &key);
        let mut root = std::fs::read(upd.join("root.squashfs")).unwrap();
        root[500] ^= 1;
        std::fs::write(upd.join("root.squashfs"), root).unwrap();
        let e = verify(&upd, &trusted, Path::new("trust")).unwrap_err();
        assert!(matches!(e, UpdateError::Hash { .. }), "{e}");
        assert!(e.to_string().contains("root.squashfs"), "{e}");
        // The manifest edited (a file's hash swapped for the tampered one's).
        let upd = dir.path().join("edited");
        update(&upd, "0.1.0-2", &key);
        let text = std::fs::read_to_string(upd.join(MANIFEST)).unwrap().replace("0.1.0-2", "0.1.0-9");
        std::fs::write(upd.join(MANIFEST), text).unwrap();
        assert!(matches!(
            verify(&upd, &trusted, Path::new("trust")).unwrap_err(),
            UpdateError::Signature { .. }
        ));
        // Signed by a key this machine does not trust.
        let upd = dir.path().join("stranger");
        update(&upd, "0.1.0-2", &signing_key_from_seed([4; 32]));
        let e = verify(&upd, &trusted, Path::new("/etc/restage/update-trust")).unwrap_err();
        assert!(e.to_string().contains("/etc/restage/update-trust"), "{e}");
        // Garbage for a signature.
        std::fs::write(upd.join(SIGNATURE), "not hex at all").unwrap();
        assert!(matches!(
            verify(&upd, &trusted, Path::new("trust")).unwrap_err(),
            UpdateError::Signature { .. }
        ));
        // Not newer than what runs: nothing written.
        let upd = dir.path().join("old");
        let manifest = update(&upd, "0.1.0-1", &key);
        let layout = machine(&dir.path().join("m"), Slot::A, "0.1.0-1");
        let e = install(&upd, &manifest, &layout, 3).unwrap_err();
        assert!(matches!(e, UpdateError::NotNewer { .. }), "{e}");
        assert_eq!(std::fs::read(&layout.slot_device[1]).unwrap(), vec![0xee; 4096]);
    }

    #[test]
    fn a_running_slot_on_trial_is_not_updated_and_an_old_target_entry_goes() {
        let dir = tempfile::tempdir().unwrap();
        let key = signing_key_from_seed([3; 32]);
        let upd = dir.path().join("upd");
        let manifest = update(&upd, "0.1.0-3", &key);
        let layout = machine(&dir.path().join("m"), Slot::B, "0.1.0-2");
        let entries = layout.esp.join("loader/entries");
        std::fs::write(entries.join("restage-a.conf"), "old").unwrap();
        std::fs::rename(entries.join("restage-b.conf"), entries.join("restage-b+2-1.conf")).unwrap();
        assert!(matches!(install(&upd, &manifest, &layout, 3).unwrap_err(), UpdateError::OnTrial(Slot::B)));
        assert_eq!(std::fs::read_to_string(entries.join("restage-a.conf")).unwrap(), "old");
        std::fs::rename(entries.join("restage-b+2-1.conf"), entries.join("restage-b.conf")).unwrap();
        assert_eq!(install(&upd, &manifest, &layout, 1).unwrap(), Slot::A);
        assert!(!entries.join("restage-a.conf").exists());
        assert!(entries.join("restage-a+1.conf").exists());
    }

    #[test]
    fn versions_compare_as_people_read_them() {
        use std::cmp::Ordering::*;
        assert_eq!(version_cmp("0.1.0-10", "0.1.0-9"), Greater);
        assert_eq!(version_cmp("0.2.0-1", "0.10.0-1"), Less);
        assert_eq!(version_cmp("0.1.0-1", "0.1.0-1"), Equal);
        assert_eq!(version_cmp("0.1.0-1", "0.1.0"), Greater);
        assert_eq!(version_cmp("1.0", "01.0"), Equal);
    }
}
