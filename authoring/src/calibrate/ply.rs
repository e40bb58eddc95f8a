//! PLY export of the dense model (binary little-endian: position, normal, colour per vertex),
//! the format MeshLab, CloudCompare and Blender open.

use std::io::Write;
use std::path::Path;

use super::CalibrateError;

/// Writes the finite points with their normals (zero where unknown) and colours (grey where not
/// given) to `path`. Returns the number of vertices written.
pub fn save_ply(
    path: &Path,
    points: &[[f32; 3]],
    normals: &[[f32; 3]],
    colours: Option<&[[u8; 3]]>,
) -> Result<usize, CalibrateError> {
    let keep: Vec<usize> = (0..points.len()).filter(|&i| points[i].iter().all(|c| c.is_finite())).collect();
    let mut out = Vec::with_capacity(64 + keep.len() * 27);
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\ncomment restage dense model, camera frame, millimetres\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        keep.len()
    )
    .expect("writing to memory");
    for &i in &keep {
        let n = normals.get(i).copied().filter(|n| n.iter().all(|c| c.is_finite())).unwrap_or([0.0; 3]);
        for c in points[i].iter().chain(&n) {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&colours.and_then(|c| c.get(i)).copied().unwrap_or([160; 3]));
    }
    std::fs::write(path, out).map_err(|source| CalibrateError::Write { path: path.into(), source })?;
    Ok(keep.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_count_matches_body() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.ply");
        let pts = [[1.0, 2.0, 3.0], [f32::NAN; 3], [4.0, 5.0, 6.0]];
        let nrm = [[0.0, 0.0, -1.0], [f32::NAN; 3], [f32::NAN; 3]];
        let n = save_ply(&path, &pts, &nrm, Some(&[[255, 0, 0], [0; 3], [0, 255, 0]])).unwrap();
        assert_eq!(n, 2);
        let bytes = std::fs::read(&path).unwrap();
        let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let header = std::str::from_utf8(&bytes[..end]).unwrap();
        assert!(header.contains("element vertex 2"));
        assert_eq!(bytes.len() - end, 2 * (6 * 4 + 3));
        // Second vertex: x = 4.0, colour green.
        let v1 = &bytes[end + 27..];
        assert_eq!(f32::from_le_bytes(v1[..4].try_into().unwrap()), 4.0);
        assert_eq!(&v1[24..27], &[0, 255, 0]);
    }
}
