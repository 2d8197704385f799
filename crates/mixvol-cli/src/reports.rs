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
                junction: Some(JunctionScene::full()),
                volume_name: "Marschner-Lobb".into(),
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
    let report = mixvol_experiments::accuracy::accuracy_report(&ctx, volume.clone(), &tf, &options)
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
    let figure = mixvol_experiments::junction::figure(
        &ctx,
        &tf,
        options.junction.as_ref().unwrap_or(&JunctionScene::quick()),
    )
    .map_err(report_error)?;
    mixvol::renderer::save_png(&figure, &args.output_dir.join(JUNCTION_FIGURE))?;
    if !args.quick && args.views > 0 {
        orbit(args, &ctx, volume, &options, &when, &report_error)?;
    }
    print!("{}", report.to_markdown(&when, &command));
    println!(
        "wrote {}, {JUNCTION_FIGURE} into {}",
        REPORT_FILES.join(", "),
        args.output_dir.display()
    );
    Ok(())
}

/// The real volumes of the orbit: file name in the data folder, scene name, description.
const REAL_SCENES: [(&str, &str, &str); 2] = [
    (
        "mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz",
        "mni152",
        "MNI ICBM152 2009a T1 template",
    ),
    ("brainsmall.den", "brainsmall", "VolPack MRI head"),
];

/// The orbit over the scenes: Marschner-Lobb (the report's volume, its transfer function) and
/// the real volumes (MRI transfer function), `args.views` views each.
fn orbit(
    args: &ReportArgs,
    ctx: &GpuContext,
    volume: Arc<mixvol::volume::Volume>,
    options: &ReportOptions,
    when: &str,
    report_error: &dyn Fn(ReportError) -> Error,
) -> Result<()> {
    use mixvol_experiments::scenes::{orbit_report, write, OrbitScene, SCENE_FILES};
    let mut scenes = vec![OrbitScene {
        name: "marschner-lobb".into(),
        description: "Marschner-Lobb".into(),
        volume,
        tf: TransferFunction::preset(TfPreset::Fire),
        junction: Some(JunctionScene::full()),
    }];
    for (file, name, description) in REAL_SCENES {
        let path = args.data_dir.join(file);
        if !path.exists() {
            return Err(Error::InvalidInput(format!(
                "{}: missing (scripts/fetch-datasets.sh fetches it; --views 0 skips the orbit)",
                path.display()
            )));
        }
        let volume = Arc::new(mixvol::volume::load_volume(&path)?);
        scenes.push(OrbitScene {
            name: name.into(),
            description: description.into(),
            junction: Some(JunctionScene::in_volume(volume.clone(), args.brick_size)),
            volume,
            tf: TransferFunction::preset(TfPreset::Mri),
        });
    }
    let options = ReportOptions {
        size: args.orbit_size,
        frames: 1,
        ..options.clone()
    };
    let summaries = orbit_report(ctx, &scenes, &options, args.views).map_err(report_error)?;
    let command = format!(
        "cargo run --release -- report --views {} --orbit-size {} --brick-size {}",
        args.views, args.orbit_size, args.brick_size
    );
    write(&summaries, &args.output_dir, when, &command).map_err(report_error)?;
    println!(
        "wrote {}, scene-NAME.{{png,svg}} and scene-NAME-seams.{{png,svg}} into {}",
        SCENE_FILES.join(", "),
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
