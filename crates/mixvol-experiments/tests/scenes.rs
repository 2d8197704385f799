//! The orbit over scenes: its cameras circle the volume, and each setting's summary is the mean
//! and the worst of the per-view reports.

#[path = "../../../tests/common/mod.rs"]
mod common;

use glam::UVec3;
use mixvol::optics::{TfPreset, TransferFunction};
use mixvol::volume::{ScalarType, SyntheticField};
use mixvol_experiments::accuracy::{report_camera, ReportOptions, FAMILIES};
use mixvol_experiments::scenes::{
    orbit_cameras, summarise, view_reports, write, OrbitScene, SCENE_FILES,
};
use std::sync::Arc;

#[test]
fn orbit_cameras_circle_the_volume() {
    let base = report_camera();
    let cams = orbit_cameras(4);
    assert_eq!(cams.len(), 4);
    assert!((cams[0].eye - base.eye).length() < 1e-6);
    for c in &cams {
        assert!((c.eye.length() - base.eye.length()).abs() < 1e-5, "{c:?}");
        assert!((c.eye.y - base.eye.y).abs() < 1e-6);
        assert_eq!(c.target, base.target);
    }
    // Half a turn mirrors x and z.
    let half = glam::Vec3::new(-base.eye.x, base.eye.y, -base.eye.z);
    assert!((cams[2].eye - half).length() < 1e-5, "{:?}", cams[2]);
    assert_eq!(orbit_cameras(0).len(), 1);
}

#[test]
fn orbit_summary_is_mean_and_worst_of_the_views() {
    let ctx = common::validated_context();
    {
        let volume = Arc::new(
            SyntheticField::MarschnerLobb
                .generate(UVec3::splat(16), ScalarType::U8)
                .unwrap(),
        );
        let tf = TransferFunction::preset(TfPreset::Fire);
        let options = ReportOptions {
            size: 24,
            ..ReportOptions::quick()
        };
        let scene = OrbitScene {
            name: "ml".into(),
            description: "Marschner-Lobb".into(),
            volume,
            tf,
        };
        // The per-view reports, and their summary (what orbit_report writes per scene).
        let per_view = view_reports(&ctx, &scene, &options, 2).unwrap();
        assert_eq!(per_view.len(), 2);
        let summaries = vec![summarise(&scene.name, &per_view)];
        let s = &summaries[0];
        assert_eq!(s.views, 2);
        // Every row of the report but the transition rows (measured on their close-up).
        assert_eq!(s.rows.len(), 35 - 4);
        assert!(s
            .rows
            .iter()
            .all(|r| r.family != FAMILIES[1] && r.family != FAMILIES[2]));
        assert_eq!(summarise("none", &[]).views, 0);
        for (i, r) in s.rows.iter().enumerate() {
            let (a, b) = (&per_view[0].rows[i], &per_view[1].rows[i]);
            assert_eq!(r.setting, a.setting);
            assert!((r.rmse.0 - 0.5 * (a.rmse + b.rmse)).abs() < 1e-9, "{r:?}");
            assert_eq!(r.rmse.1, a.rmse.max(b.rmse));
            assert_eq!(r.ssim.1, a.ssim.min(b.ssim));
            assert_eq!(r.seam_max.1, a.seam.max_excess.max(b.seam.max_excess));
        }
        // The two views differ (the orbit sees the volume from elsewhere).
        assert!(per_view[0].rows[0].rmse != per_view[1].rows[0].rmse);
        let dir = std::env::temp_dir().join(format!("mixvol-scenes-{}", std::process::id()));
        write(&summaries, &dir, "now", "cmd").unwrap();
        for name in SCENE_FILES {
            let len = std::fs::metadata(dir.join(name)).unwrap().len();
            assert!(len > 200, "{name}: {len} bytes");
        }
        let csv = std::fs::read_to_string(dir.join("scenes.csv")).unwrap();
        assert_eq!(csv.lines().count(), 1 + 31);
        let chart = image::open(dir.join("scene-ml.png")).unwrap();
        assert!(chart.width() > 1000, "{}", chart.width());
        assert!(dir.join("scene-ml.svg").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
    common::finish(ctx);
}
