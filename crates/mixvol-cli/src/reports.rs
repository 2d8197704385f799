//! `mixvol report` and `mixvol kraus`: the experiment reports of `mixvol-experiments`, written
//! as files and printed.

use crate::args::{KrausArgs, ReportArgs};
use glam::{UVec3, Vec3};
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::scene::Camera;
use mixvol::volume::{ScalarType, SyntheticField};
use mixvol::{Error, Result};
use std::sync::Arc;

/// Runs `mixvol report`: the accuracy-versus-time report of the default scene.
pub fn accuracy(args: &ReportArgs) -> Result<()> {
    let volume = Arc::new(
        SyntheticField::MarschnerLobb.generate(UVec3::splat(args.volume_size), ScalarType::U8)?,
    );
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: None,
    })?;
    let tf = TransferFunction::preset(TfPreset::Fire);
    let options = mixvol_experiments::accuracy::ReportOptions {
        size: args.size,
        frames: args.frames,
        brick_size: args.brick_size,
        camera: Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0),
    };
    let report = mixvol_experiments::accuracy::accuracy_report(&ctx, volume, &tf, &options)?;
    std::fs::create_dir_all(&args.output_dir).map_err(|e| Error::ImageWrite {
        path: args.output_dir.clone(),
        message: e.to_string(),
    })?;
    let when = std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d %H:%M UTC")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    let command = format!(
        "cargo run --release -- report --size {} --frames {} --volume-size {} --brick-size {}",
        args.size, args.frames, args.volume_size, args.brick_size
    );
    let write = |name: &str, text: String| -> Result<()> {
        let path = args.output_dir.join(name);
        mixvol::output::write_file_atomically(&path, text.as_bytes()).map_err(|e| {
            Error::ImageWrite {
                path,
                message: e.to_string(),
            }
        })
    };
    let md = report.to_markdown(&when, &command);
    write("accuracy-vs-time.md", md.clone())?;
    write("accuracy-vs-time.csv", report.to_csv())?;
    let chart_path = args.output_dir.join("accuracy-vs-time.png");
    mixvol::renderer::save_png(&report.chart(), &chart_path)?;
    print!("{md}");
    println!(
        "wrote {}/accuracy-vs-time.{{md,csv,png}}",
        args.output_dir.display()
    );
    Ok(())
}

/// Runs `mixvol kraus`: Kraus & Bürger's sampling experiments.
pub fn kraus(args: &KrausArgs) -> Result<()> {
    let report = mixvol_experiments::kraus::write_report(&args.output_dir, &Default::default())?;
    print!("{}", report.to_markdown());
    println!("wrote {}/kraus.{{md,csv,png}}", args.output_dir.display());
    Ok(())
}
