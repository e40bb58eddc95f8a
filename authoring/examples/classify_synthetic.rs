//! Writes the classification benchmark's synthetic photo (16-bit linear `photo.png`), its
//! `picks.json` and true `labels.png` into a directory, so that peers (OpenCV, in
//! `bench/peers/`) time themselves on the very image `benches/classify.rs` uses.
//!
//! `cargo run --release -p restage-authoring --example classify_synthetic -- DIR [WIDTH HEIGHT]`

use std::path::PathBuf;

use anyhow::{Context, Result};
use restage_authoring::classify::picks_from_labels;
use restage_authoring::classify::synthetic::{POTTERY_PAINTS, painted_pattern};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from(args.first().context("usage: classify_synthetic DIR [WIDTH HEIGHT]")?);
    let w: u32 = args.get(1).map_or(Ok(3872), |s| s.parse()).context("WIDTH")?;
    let h: u32 = args.get(2).map_or(Ok(2592), |s| s.parse()).context("HEIGHT")?;
    std::fs::create_dir_all(&dir)?;
    let scene = painted_pattern(w, h, &POTTERY_PAINTS, 0.04, 1)?;
    let names: Vec<String> = (0..5).map(|i| format!("paint {i}")).collect();
    let picks = picks_from_labels(&scene.truth, &names, &[], 8, 1)?;
    scene.photo.save_linear16(&dir.join("photo.png"))?;
    scene.truth.save(&dir.join("labels.png"))?;
    picks.save(&dir.join("picks.json"))?;
    Ok(())
}
