//! `mixvol report` and `mixvol kraus`: the experiment reports of `mixvol-experiments`, written
//! as files and printed.

use crate::args::{KrausArgs, ReportArgs};
use glam::UVec3;
use mixvol::gpu::{ContextDesc, GpuContext};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::volume::{ScalarType, SyntheticField};
use mixvol::{Error, Result};
use mixvol_experiments::accuracy::{
    report_camera, ReportError, ReportOptions, QUICK_VOLUME_SIZE, REPORT_FILES,
};
use mixvol_experiments::junction::{JunctionScene, JUNCTION_FIGURE};
use std::sync::Arc;

/// Runs `mixvol report`: the accuracy-versus-time report of the default scene.
pub fn accuracy(args: &ReportArgs) -> Result<()> {
    let (options, volume_size, command) = if args.quick {
        (
            ReportOptions::quick(),
            QUICK_VOLUME_SIZE,
            "cargo run --release -- report --quick".to_string(),
        )
    } else {
        (
            ReportOptions {
                size: args.size,
                frames: args.frames,
                brick_size: args.brick_size,
                camera: report_camera(),
                junction: JunctionScene::full(),
            },
            args.volume_size,
            format!(
                "cargo run --release -- report --size {} --frames {} --volume-size {} --brick-size {}",
                args.size, args.frames, args.volume_size, args.brick_size
            ),
        )
    };
    let volume = Arc::new(
        SyntheticField::MarschnerLobb.generate(UVec3::splat(volume_size), ScalarType::U8)?,
    );
    let ctx = GpuContext::new(&ContextDesc {
        validation: args.validation,
        device_name: None,
    })?;
    let tf = TransferFunction::preset(TfPreset::Fire);
    let report_error = |e: ReportError| match e {
        ReportError::Render(e) => e,
        other => Error::ImageWrite {
            path: args.output_dir.clone(),
            message: other.to_string(),
        },
    };
    let report = mixvol_experiments::accuracy::accuracy_report(&ctx, volume, &tf, &options)
        .map_err(report_error)?;
    let when = std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d %H:%M UTC")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default();
    report
        .write(&args.output_dir, &when, &command)
        .map_err(report_error)?;
    let figure =
        mixvol_experiments::junction::figure(&ctx, &tf, &options.junction).map_err(report_error)?;
    mixvol::renderer::save_png(&figure, &args.output_dir.join(JUNCTION_FIGURE))?;
    print!("{}", report.to_markdown(&when, &command));
    println!(
        "wrote {}, {JUNCTION_FIGURE} into {}",
        REPORT_FILES.join(", "),
        args.output_dir.display()
    );
    Ok(())
}

/// Runs `mixvol kraus`: Kraus & Bürger's sampling experiments.
pub fn kraus(args: &KrausArgs) -> Result<()> {
    let report = mixvol_experiments::kraus::write_report(&args.output_dir, &Default::default())?;
    print!("{}", report.to_markdown());
    println!(
        "wrote {}/kraus.{{md,csv,png,svg}}",
        args.output_dir.display()
    );
    Ok(())
}
