//! Correspondences for camera pixels that a projector did not decode but that lie between
//! pixels it did: dark paint, whose Gray-code contrast drowns in the camera's noise bit by bit
//! although the surface under it is as smooth as around it, and surface turned away from the
//! camera, where one camera pixel spans many projector pixels. Each such pixel's projector
//! coordinate is interpolated by a local quadratic fit of the decoded neighbours, and
//! [`crate::calibrate::fulllight::StripeSums::confirms`] keeps it only where the Gray-code
//! images agree with it (lit on the stripes it predicts lit, dark on the others, beyond noise).
//! The silhouette's rim (within 2 px of decoded pixels, decoded on one side only: camera pixels
//! straddling the edge) is extrapolated the same way, and kept where the images show the
//! projector's light there. Gaps the neighbours' coordinates jump across (an occluding edge)
//! are left empty, and so is a projector's shadow, where its images show no light, whether or
//! not another projector decoded the pixel. The fill runs in rounds, each fitting from what the
//! last kept too, so a rim or band wider than one round reaches closes up to where the
//! projector's light stops.

use rayon::prelude::*;

/// Standard errors by which a filled pixel's lit samples must stand above its black ones
/// ([`crate::calibrate::fulllight::StripeSums::confirms`]).
pub const MIN_Z: f64 = 8.0;

/// How far to look for decoded neighbours and how well they must fit.
#[derive(Clone, Copy, Debug)]
pub struct FillParams {
    /// Window half-sizes tried in turn (camera pixels): the pixel must have decoded pixels on
    /// both sides along one of four directions within it.
    pub radii: [usize; 3],
    /// Decoded neighbours needed in the window for the fit.
    pub min_neighbours: usize,
    /// The fit's RMS residual over the neighbours must stay under this (projector pixels)...
    pub max_rms_px: f64,
    /// ... or under this many camera pixels' worth of the fit's own gradient, where that is
    /// more: where the surface turns away from the camera one camera pixel spans many
    /// projector pixels, the decoded neighbours scatter by several of them, and a fit within
    /// a fraction of a camera pixel still places the pixel's light right.
    pub max_rms_camera_px: f64,
    /// A pixel not between decoded ones but this close to one (camera pixels, in x and y; the
    /// silhouette's rim, where a camera pixel straddles the edge) is given the fit of the
    /// smallest window, extrapolated.
    pub rim_px: i64,
    /// Rounds at most, each fitting from the coordinates the rounds before kept too (see
    /// [`in_rounds`]).
    pub rounds: usize,
}

impl Default for FillParams {
    fn default() -> Self {
        Self {
            radii: [6, 12, 24],
            min_neighbours: 24,
            max_rms_px: 0.5,
            max_rms_camera_px: 0.25,
            rim_px: 2,
            rounds: 4,
        }
    }
}

/// Candidate coordinates for projector map `map` (camera `w x h`, NaN where not decoded) at the
/// pixels where `skip` is false (the caller skips the pixels a projector decoded): `(pixel,
/// projector coordinate)`.
pub fn interpolate(
    w: usize,
    h: usize,
    map: &[[f32; 2]],
    skip: &[bool],
    params: &FillParams,
) -> Vec<(usize, [f32; 2])> {
    let valid = |x: i64, y: i64| {
        x >= 0
            && y >= 0
            && (x as usize) < w
            && (y as usize) < h
            && map[y as usize * w + x as usize][0].is_finite()
    };
    (0..w * h)
        .into_par_iter()
        .filter(|&i| !skip[i])
        .filter_map(|i| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let between = params.radii.iter().find_map(|&r| {
                let r = r as i64;
                let bridged = [(1, 0), (0, 1), (1, 1), (1, -1)].iter().any(|&(dx, dy)| {
                    let side = |s: i64| (1..=r).any(|t| valid(x + s * t * dx, y + s * t * dy));
                    side(1) && side(-1)
                });
                if !bridged {
                    return None;
                }
                fit_at(w, h, map, (x, y), r, params)
            });
            let k = params.rim_px;
            let near = || (-k..=k).any(|dy| (-k..=k).any(|dx| valid(x + dx, y + dy)));
            between
                .or_else(|| {
                    if near() { fit_at(w, h, map, (x, y), params.radii[0] as i64, params) } else { None }
                })
                .map(|u| (i, u))
        })
        .collect()
}

/// Fills `maps` (one per projector, NaN where not decoded) in rounds, each fitting
/// ([`interpolate`]) from what the rounds before kept too, so that a band wider than a window
/// reaches or a rim wider than `rim_px` closes, until a round keeps nothing or
/// `params.rounds` have run. Every pixel a projector has no coordinate for is a candidate for
/// it, decoded by another projector or not: `confirms` tells its shadow (no light there) from
/// its dark paint (light too faint to decode). Each round `measure`s the maps with its
/// candidates in place, and a candidate is kept where `confirms(measurement, projector,
/// pixel)`. Returns per projector the pixels kept in each round, and the last round's
/// measurement.
pub fn in_rounds<S, E>(
    w: usize,
    h: usize,
    maps: &mut [Vec<[f32; 2]>],
    params: &FillParams,
    mut measure: impl FnMut(&[Vec<[f32; 2]>]) -> Result<S, E>,
    confirms: impl Fn(&S, usize, usize) -> bool,
) -> Result<(Vec<Vec<usize>>, S), E> {
    let mut kept = vec![Vec::new(); maps.len()];
    let mut last = None;
    for _ in 0..params.rounds.max(1) {
        let candidates: Vec<Vec<(usize, [f32; 2])>> = maps
            .iter()
            .map(|m| {
                let skip: Vec<bool> = m.iter().map(|u| u[0].is_finite()).collect();
                interpolate(w, h, m, &skip, params)
            })
            .collect();
        if last.is_some() && candidates.iter().all(Vec::is_empty) {
            break;
        }
        let mut tentative = maps.to_vec();
        for (map, cands) in tentative.iter_mut().zip(&candidates) {
            for &(i, u) in cands {
                map[i] = u;
            }
        }
        let measured = measure(&tentative)?;
        let mut added = 0;
        for (k, cands) in candidates.iter().enumerate() {
            let before = added;
            for &(i, u) in cands.iter().filter(|&&(i, _)| confirms(&measured, k, i)) {
                maps[k][i] = u;
                added += 1;
            }
            kept[k].push(added - before);
        }
        last = Some(measured);
        if added == 0 {
            break;
        }
    }
    Ok((kept, last.expect("at least one round runs")))
}

/// Least-squares quadratic of each projector coordinate over the decoded pixels within `r`
/// of `(x, y)` (every `step`-th row and column for the wider windows), evaluated at `(x, y)`.
fn fit_at(
    w: usize,
    h: usize,
    map: &[[f32; 2]],
    (x, y): (i64, i64),
    r: i64,
    params: &FillParams,
) -> Option<[f32; 2]> {
    let step = (r / 8).max(1);
    let mut ata = nalgebra::Matrix6::<f64>::zeros();
    let mut atb = [nalgebra::Vector6::<f64>::zeros(); 2];
    let mut samples = Vec::new();
    for yy in (y - r..=y + r).step_by(step as usize) {
        for xx in (x - r..=x + r).step_by(step as usize) {
            if xx < 0 || yy < 0 || xx as usize >= w || yy as usize >= h {
                continue;
            }
            let m = map[yy as usize * w + xx as usize];
            if !m[0].is_finite() {
                continue;
            }
            // Scaled offsets keep the normal equations well conditioned.
            let (u, v) = ((xx - x) as f64 / r as f64, (yy - y) as f64 / r as f64);
            let row = nalgebra::Vector6::new(1.0, u, v, u * u, u * v, v * v);
            ata += row * row.transpose();
            for a in 0..2 {
                atb[a] += row * m[a] as f64;
            }
            samples.push((row, m));
        }
    }
    if samples.len() < params.min_neighbours {
        return None;
    }
    let lu = ata.lu();
    let coef = [lu.solve(&atb[0])?, lu.solve(&atb[1])?];
    let sq: f64 = samples
        .iter()
        .map(|(row, m)| (0..2).map(|a| (coef[a].dot(row) - m[a] as f64).powi(2)).sum::<f64>())
        .sum();
    let rms = (sq / samples.len() as f64).sqrt();
    // Projector pixels per camera pixel: the Frobenius norm of the fit's Jacobian at (x, y).
    let gradient = (0..2).map(|a| coef[a][1].powi(2) + coef[a][2].powi(2)).sum::<f64>().sqrt() / r as f64;
    let tolerance = params.max_rms_px.max(params.max_rms_camera_px * gradient);
    (rms.is_finite() && rms <= tolerance).then(|| [coef[0][0] as f32, coef[1][0] as f32])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `truth` sampled at every camera pixel of a `w x h` image, each coordinate scattered by up
    /// to `scatter` projector px (seeded), NaN where `undecoded`.
    fn sampled(
        w: usize,
        h: usize,
        truth: &impl Fn(usize, usize) -> [f32; 2],
        undecoded: impl Fn(usize, usize) -> bool,
        scatter: f32,
    ) -> Vec<[f32; 2]> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let t = truth(x, y);
                let noise: [f32; 2] =
                    std::array::from_fn(
                        |_| {
                            if scatter > 0.0 { rng.gen_range(-scatter..scatter) } else { 0.0 }
                        },
                    );
                if undecoded(x, y) { [f32::NAN; 2] } else { [t[0] + noise[0], t[1] + noise[1]] }
            })
            .collect()
    }

    /// What `interpolate` fills in `m`, every finite pixel counted as decoded.
    fn fill_gaps(w: usize, h: usize, m: &[[f32; 2]], params: &FillParams) -> Vec<(usize, [f32; 2])> {
        let decoded: Vec<bool> = m.iter().map(|c| c[0].is_finite()).collect();
        interpolate(w, h, m, &decoded, params)
    }

    /// A smooth map (a tilted, curved surface), with a band of undecoded rows through it and
    /// the image's right part undecoded (beyond a silhouette).
    fn map(w: usize, h: usize, jump: bool) -> (Vec<[f32; 2]>, impl Fn(usize, usize) -> [f32; 2]) {
        let truth = move |x: usize, y: usize| {
            let (xf, yf) = (x as f32, y as f32);
            let z = if jump && y < 30 { 40.0 } else { 0.0 };
            [1.7 * xf + 0.004 * xf * xf + 0.3 * yf + z, 1.6 * yf + 0.003 * (xf - 40.0) * (yf - 20.0)]
        };
        (sampled(w, h, &truth, |x, y| (30..36).contains(&y) || x >= 70, 0.0), truth)
    }

    #[test]
    fn a_band_of_dark_paint_is_bridged_and_the_rim_extended_by_two_pixels() {
        let (w, h) = (100, 60);
        let (m, truth) = map(w, h, false);
        let filled = fill_gaps(w, h, &m, &FillParams::default());
        let band = filled.iter().filter(|(i, _)| i % w < 70).count();
        assert_eq!(band, 6 * 70, "every band pixel left of the silhouette");
        let rim = filled.iter().filter(|(i, _)| i % w >= 70).count();
        assert_eq!(rim, 2 * (h - 6) + 2 * 4, "two columns past the silhouette (the band's end beside)");
        assert!(filled.iter().all(|(i, _)| i % w < 72), "nothing further out");
        for (i, u) in &filled {
            let (x, y) = (i % w, i / w);
            let t = truth(x, y);
            let tol = if x < 70 { 0.05 } else { 0.2 };
            assert!((u[0] - t[0]).abs() < tol && (u[1] - t[1]).abs() < tol, "({x}, {y}): {u:?} vs {t:?}");
        }
    }

    #[test]
    fn a_gap_the_coordinates_jump_across_is_left_empty() {
        // Above the band the surface is another one (an occluding edge): 40 projector px apart.
        let (w, h) = (100, 60);
        let (m, _) = map(w, h, true);
        let filled = fill_gaps(w, h, &m, &FillParams::default());
        let across = filled.iter().filter(|(i, _)| i % w < 70).count();
        assert_eq!(across, 0, "{across} pixels filled across the edge");
        // The silhouette's rim is still extended, each side from its own surface.
        assert_eq!(filled.len(), 2 * (h - 6), "the rim beside the band is left empty too");
    }

    #[test]
    fn rounds_close_a_rim_wider_than_one_round_reaches_and_stop_where_the_light_does() {
        // The object ends at column 76 and its last 6 columns were not decoded; a second
        // projector, shadowed from column 50 on, decoded the object up to column 44 only (a band
        // of dark paint it lights but could not decode before its shadow).
        let (w, h) = (100, 40);
        let (object_end, decoded_end, dark_paint, shadow) = (76, 70, 44, 50);
        let truth = |x: usize, y: usize| {
            let (xf, yf) = (x as f32, y as f32);
            [1.7 * xf + 0.004 * xf * xf + 0.3 * yf, 1.6 * yf + 0.003 * (xf - 40.0) * (yf - 20.0)]
        };
        let maps = vec![
            sampled(w, h, &truth, |x, _| x >= decoded_end, 0.0),
            sampled(w, h, &truth, |x, _| x >= dark_paint, 0.0),
        ];
        // The "images" confirm a coordinate within 3 projector px of the truth where the
        // projector's light arrives: on the object, and for projector 1 before its shadow.
        let run = |rounds: usize| {
            let mut maps = maps.clone();
            let params = FillParams { rounds, ..FillParams::default() };
            let confirms = |m: &Vec<Vec<[f32; 2]>>, k: usize, i: usize| {
                let (x, y) = (i % w, i / w);
                let (u, t) = (m[k][i], truth(x, y));
                x < object_end && (k == 0 || x < shadow) && (u[0] - t[0]).hypot(u[1] - t[1]) < 3.0
            };
            let (kept, _) =
                in_rounds(w, h, &mut maps, &params, |m| Ok::<_, ()>(m.to_vec()), confirms).unwrap();
            (kept, maps)
        };
        let (kept, _) = run(1);
        assert_eq!(kept, [vec![2 * h], vec![2 * h]], "one round: the 2 px rim, for both");
        let (kept, maps) = run(FillParams::default().rounds);
        assert_eq!(
            kept[0],
            [2 * h, 2 * h, 2 * h, 0],
            "three rounds to the object's edge, a fourth finds nothing"
        );
        // Projector 0 decoded the dark band: projector 1 still fills it, up to its shadow.
        assert_eq!(kept[1], [2 * h, 2 * h, 2 * h, 0], "projector 1's dark band, and not its shadow");
        for (k, end) in [(0, object_end), (1, shadow)] {
            for (i, u) in maps[k].iter().enumerate() {
                let (x, y) = (i % w, i / w);
                if x >= end {
                    assert!(u[0].is_nan(), "projector {k}: ({x}, {y}) filled beyond its light");
                } else {
                    let t = truth(x, y);
                    assert!(
                        (u[0] - t[0]).abs() < 0.2 && (u[1] - t[1]).abs() < 0.2,
                        "({x}, {y}): {u:?} vs {t:?}"
                    );
                }
            }
        }
    }

    /// Surface turned away from the camera: 9 projector px per camera px along x, the decoded
    /// coordinates scattered by up to 2 projector px in each axis (RMS 1.6 over both, a sixth
    /// of a camera pixel, as the bowl's flank at seed 9 scatters about a quadratic fit there),
    /// a band of undecoded rows through it; above row 20, with `jump`, another surface 40
    /// projector px off.
    fn steep_map(w: usize, h: usize, jump: bool) -> (Vec<[f32; 2]>, impl Fn(usize, usize) -> [f32; 2]) {
        let truth = move |x: usize, y: usize| {
            let (xf, yf) = (x as f32, y as f32);
            let z = if jump && y < 20 { 40.0 } else { 0.0 };
            [9.0 * xf + 0.02 * xf * xf + 0.5 * yf + z, 1.6 * yf]
        };
        (sampled(w, h, &truth, |_, y| (20..24).contains(&y), 2.0), truth)
    }

    #[test]
    fn a_surface_turned_away_is_bridged_to_a_fraction_of_a_camera_pixel() {
        let (w, h) = (60, 50);
        let (m, truth) = steep_map(w, h, false);
        let filled = fill_gaps(w, h, &m, &FillParams::default());
        assert_eq!(filled.len(), 4 * w, "every pixel of the band");
        for (i, u) in &filled {
            let (x, y) = (i % w, i / w);
            let t = truth(x, y);
            // A ninth of a camera pixel along x here.
            assert!((u[0] - t[0]).abs() < 1.0 && (u[1] - t[1]).abs() < 1.0, "({x}, {y}): {u:?} vs {t:?}");
        }
        // The scatter is more than the fixed tolerance allows, and more than an eighth of a
        // camera pixel: a quarter of the gradient decides.
        for camera_px in [0.0, 0.125] {
            let tighter = FillParams { max_rms_camera_px: camera_px, ..FillParams::default() };
            let n = fill_gaps(w, h, &m, &tighter).len();
            assert!(n < w, "{n} pixels bridged with {camera_px} of a camera pixel's gradient");
        }
    }

    #[test]
    fn a_jump_on_a_surface_turned_away_is_still_left_empty() {
        let (w, h) = (60, 50);
        let (m, _) = steep_map(w, h, true);
        let filled = fill_gaps(w, h, &m, &FillParams::default());
        assert!(filled.is_empty(), "{} pixels filled across the edge", filled.len());
    }
}
