//! Redraws the orbit report's charts (`scene-NAME.{png,svg}`, `scene-NAME-seams.{png,svg}`) from
//! the `scenes.json` it wrote, without measuring again:
//! `cargo run --release -p mixvol-experiments --example redraw_scene_charts -- docs/report`.

use mixvol_experiments::scenes::{summaries_from_json, write_charts};
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "docs/report".into()),
    );
    let path = dir.join("scenes.json");
    let text =
        std::fs::read_to_string(&path).map_err(|e| format!("reading {}: {e}", path.display()))?;
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| format!("parsing {}: {e}", path.display()))?;
    let summaries = summaries_from_json(&json, &path)?;
    write_charts(&summaries, &dir)?;
    for s in &summaries {
        println!("{}: scene-{0}.png/.svg, scene-{0}-seams.png/.svg", s.name);
    }
    Ok(())
}
