//! The accuracy-versus-time report: its rows behave the way the settings say they should.

#[path = "../../../tests/common/mod.rs"]
mod common;

use glam::{UVec3, Vec3};
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::scene::Camera;
use mixvol::volume::{ScalarType, SyntheticField};
use mixvol_experiments::accuracy::{accuracy_report, ReportOptions};
use std::sync::Arc;

#[test]
fn report_rows_trade_accuracy_for_time_consistently() {
    let ctx = common::validated_context();
    {
        let volume = Arc::new(
            SyntheticField::MarschnerLobb
                .generate(UVec3::splat(32), ScalarType::U8)
                .unwrap(),
        );
        let options = ReportOptions {
            size: 40,
            frames: 1,
            brick_size: 8,
            camera: Camera::perspective(Vec3::new(1.0, 1.3, 1.4), Vec3::ZERO, 35.0),
        };
        let report = accuracy_report(
            &ctx,
            volume,
            &TransferFunction::preset(TfPreset::Fire),
            &options,
        )
        .unwrap();
        assert_eq!(report.rows.len(), 10);
        let row = |s: &str| {
            report
                .rows
                .iter()
                .find(|r| r.setting.starts_with(s))
                .unwrap_or_else(|| panic!("row {s}"))
        };
        // Finer steps approach the 8-samples/voxel reference.
        assert!(row("4 samples").rmse < row("0.5 samples").rmse);
        assert!(row("2 samples").rmse < row("1 samples").rmse);
        // All bricks hi-res draws the same samples as the single-resolution renderer.
        assert!(
            (row("100%").rmse - row("1 samples").rmse).abs() < 2e-3,
            "{report:#?}"
        );
        // Fewer hi-res bricks: less memory, more error.
        assert!(row("0%").resident_bytes < row("50%").resident_bytes);
        assert!(row("50%").resident_bytes < row("100%").resident_bytes);
        assert!(row("0%").rmse > row("100%").rmse);
        assert!((row("50%").hi_fraction - 0.5).abs() < 0.05);
        let csv = report.to_csv();
        assert_eq!(csv.lines().count(), 11);
        let md = report.to_markdown("now", "cmd");
        assert!(md.contains("| LOD budget | 25% of bricks hi-res"));
        assert_eq!(report.chart().dimensions(), (640, 400));
    }
    common::finish(ctx);
}
