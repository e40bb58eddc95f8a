//! How much memory the appliance needs for a bundle's frame sizes: the one formula the
//! README's table, the systemd unit's `MemoryMax` and the memory test use.
//!
//! What is held (bytes; `S` = one scene's frames, `sum W*H*4` over projectors; `F` = the
//! largest frame): the pinned scenes (idle and first restoration) and the last scene read,
//! `3S`; the cross-fade's buffers, `S`; one shared buffer of zeros for black, `F`. During a
//! reload the worker streams the new bundle one frame section at a time (compressed and
//! decompressed, `2F`) and holds both bundles' certificates and the irradiance accumulator;
//! the old bundle's frames are released before the new one's are read, so frames are never
//! held twice. KMS adds two mapped scan-out buffers per projector, `2S`.

use restage_shared::bundle::{Manifest, SectionKind};
use restage_shared::light::LightCertificate;

/// Code, heap bookkeeping, SQLite's cache, tokio, the thread stacks: measured well under this
/// for a debug build (see the memory test), with room.
pub const BASE_BYTES: u64 = 40 << 20;

/// The estimate, in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryNeed {
    /// Frames held at the worst moment (see the module's text).
    pub frame_bytes: u64,
    /// Certificates and the check's working memory during a reload.
    pub certificate_bytes: u64,
    /// Everything, base included.
    pub total_bytes: u64,
}

/// Peak memory for projectors of `sizes` with a certificate of `points` points; `scan_out`:
/// the KMS output's mapped buffers count too.
pub fn need(sizes: &[(u32, u32)], points: u64, scan_out: bool) -> MemoryNeed {
    let frame = |&(w, h): &(u32, u32)| u64::from(w) * u64::from(h) * 4;
    let scene: u64 = sizes.iter().map(frame).sum();
    let largest = sizes.iter().map(frame).max().unwrap_or(0);
    let scan = if scan_out { 2 * scene } else { 0 };
    let frame_bytes = 4 * scene + largest + 2 * largest + scan;
    // Per point: a footprint per projector (kept by both bundles during a reload), its pixel,
    // and the accumulator (three f64) of the check.
    let per_point =
        2 * (sizes.len() as u64 * std::mem::size_of::<restage_shared::light::Footprint>() as u64 + 4) + 24;
    let certificate_bytes = points * per_point;
    MemoryNeed { frame_bytes, certificate_bytes, total_bytes: BASE_BYTES + frame_bytes + certificate_bytes }
}

/// [`need`] for a certificate.
pub fn need_for(cert: &LightCertificate, scan_out: bool) -> MemoryNeed {
    let sizes: Vec<(u32, u32)> = cert.projectors.iter().map(|m| (m.width, m.height)).collect();
    need(&sizes, u64::from(cert.points), scan_out)
}

/// [`need`] from a manifest alone (before any section is decoded): the certificate's points
/// are bounded by its encoded length, since postcard spends at least 8 bytes per footprint
/// (four varints of at least a byte, an f32).
pub fn need_for_manifest(m: &Manifest, scan_out: bool) -> MemoryNeed {
    let sizes: Vec<(u32, u32)> = m.projectors.iter().map(|p| (p.width, p.height)).collect();
    let cert_len: u64 =
        m.sections.iter().filter(|s| s.kind == SectionKind::Certificate).map(|s| s.raw_len).sum();
    need(&sizes, cert_len / (8 * sizes.len().max(1) as u64), scan_out)
}

/// This process's memory limit: its cgroup's `memory.max` (cgroup v2), when one is set.
pub fn cgroup_limit() -> Option<u64> {
    let cg = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    let path = cg.lines().find_map(|l| l.strip_prefix("0::"))?;
    let max = std::fs::read_to_string(format!("/sys/fs/cgroup{}/memory.max", path.trim())).ok()?;
    max.trim().parse().ok()
}

/// The stage the systemd unit's `MemoryMax` is sized for: three projectors up to 1920x1200,
/// DRM/KMS scan-out buffers, certificates up to 2^20 points (a 4 MP camera image at half
/// resolution). Larger stages raise `MemoryMax` by [`need`] (README, "Memory").
pub fn unit_stage_need() -> MemoryNeed {
    need(&[(1920, 1200); 3], 1 << 20, true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_units_memory_max_covers_its_stage_with_room() {
        let unit = include_str!("../../systemd/restage-appliance.service");
        let max: u64 = unit
            .lines()
            .find_map(|l| l.strip_prefix("MemoryMax="))
            .and_then(|v| v.trim().strip_suffix('M'))
            .and_then(|v| v.parse().ok())
            .expect("MemoryMax=<n>M in the unit");
        let need = unit_stage_need().total_bytes;
        assert!(max << 20 >= need + need / 4, "MemoryMax={max}M for a need of {} MiB", need >> 20);
    }

    #[test]
    fn grows_with_frame_size_and_projectors() {
        let one = need(&[(1920, 1200)], 0, false);
        let three = need(&[(1920, 1200); 3], 0, false);
        assert!(three.frame_bytes > 2 * one.frame_bytes);
        assert!(need(&[(1920, 1200); 3], 0, true).total_bytes > three.total_bytes);
        assert!(need(&[(1920, 1200); 3], 1 << 20, false).total_bytes > three.total_bytes);
    }
}
