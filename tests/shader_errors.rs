//! A GLSL compile error names the file (the include file where the error sits) and the line.

use mixvol::gpu::shaders::{compile, compile_source};
use mixvol::gpu::ShaderStage;
use mixvol::Error;

#[test]
fn error_in_the_main_file_names_file_and_line() {
    let src = "#version 460\nlayout(location = 0) out vec4 c;\nvoid main() {\n  c = vec4(undefined_name);\n}\n";
    match compile_source("broken.frag", src, ShaderStage::Fragment, &[]) {
        Err(Error::ShaderCompile {
            file,
            line,
            message,
        }) => {
            assert_eq!(file, "broken.frag", "{message}");
            assert_eq!(line, 4, "{message}");
            assert!(message.contains("undefined_name"), "{message}");
        }
        other => panic!("expected a compile error, got {other:?}"),
    }
}

#[test]
fn error_inside_an_include_names_the_include_file() {
    // optics.glsl needs the TF_SIZE macro; without it the error sits in the include.
    let src = "#version 460\n#include \"include/optics.glsl\"\nvoid main() {}\n";
    match compile_source("host.frag", src, ShaderStage::Fragment, &[]) {
        Err(Error::ShaderCompile {
            file,
            line,
            message,
        }) => {
            assert_eq!(file, "include/optics.glsl", "{message}");
            assert!(line > 0, "{message}");
            assert!(message.contains("TF_SIZE"), "{message}");
        }
        other => panic!("expected a compile error, got {other:?}"),
    }
}

#[test]
fn missing_include_is_reported_at_the_include_line() {
    let src = "#version 460\n\n#include \"include/nope.glsl\"\nvoid main() {}\n";
    match compile_source("host.frag", src, ShaderStage::Fragment, &[]) {
        Err(Error::ShaderCompile {
            file,
            line,
            message,
        }) => {
            assert_eq!((file.as_str(), line), ("host.frag", 3), "{message}");
            assert!(message.contains("nope.glsl"), "{message}");
        }
        other => panic!("expected a compile error, got {other:?}"),
    }
}

#[test]
fn the_shipped_shaders_compile() {
    let defines = [
        ("TF_SIZE", "256".to_string()),
        ("RAY_DIR_EPSILON", "1e-20".to_string()),
    ];
    let frag = compile("raycast.frag", ShaderStage::Fragment, &defines).unwrap();
    assert_eq!(frag[0], 0x0723_0203, "SPIR-V magic number");
    assert!(compile("no-such.frag", ShaderStage::Fragment, &defines).is_err());
    let mut mixed = defines.to_vec();
    mixed.push(("MIXED_RESOLUTION", "1".to_string()));
    compile("raycast.frag", ShaderStage::Fragment, &mixed).unwrap();
    mixed.push(("SMOOTH_TRANSITIONS", "1".to_string()));
    compile("raycast.frag", ShaderStage::Fragment, &mixed).unwrap();
    for format in ["r8", "r16", "r32f"] {
        let d = [("CACHE_IMAGE_FORMAT", format.to_string())];
        compile("fixup.comp", ShaderStage::Compute, &d).unwrap();
        compile("skeleton_fixup.comp", ShaderStage::Compute, &d).unwrap();
        let three_level = [d[0].clone(), ("SLOT_BORDER", "2".to_string())];
        compile("fixup.comp", ShaderStage::Compute, &three_level).unwrap();
    }
}
