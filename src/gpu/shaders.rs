//! GLSL sources (embedded at build time from `glsl/`) compiled to SPIR-V through shaderc.
//!
//! `#include "..."` resolves against the embedded tree, so the binary needs no source files at run
//! time. Rust constants reach GLSL as macros (defined once, in Rust: [`super::shared_defs`], added
//! to every compile of an embedded shader). A compile error names the file (the include file
//! where the error sits) and the line.

use crate::error::{Error, Result};

/// One embedded GLSL file: its path relative to `glsl/` and its text.
struct Source {
    path: &'static str,
    text: &'static str,
}

macro_rules! glsl_sources {
    ($($path:literal),* $(,)?) => {
        &[$(Source { path: $path, text: include_str!(concat!("../../glsl/", $path)) }),*]
    };
}

/// Every GLSL file of the crate.
static SOURCES: &[Source] = glsl_sources!(
    "raycast.vert",
    "raycast.frag",
    "fixup.comp",
    "skeleton_fixup.comp",
    "probe.comp",
    "include/params.glsl",
    "include/neighbours.glsl",
    "include/mixed.glsl",
    "include/camera.glsl",
    "include/optics.glsl",
    "include/sampling.glsl",
    "include/modes.glsl",
);

/// The pipeline stage a source is for.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum ShaderStage {
    /// Vertex shader.
    Vertex,
    /// Fragment shader.
    Fragment,
    /// Compute shader.
    Compute,
}

impl ShaderStage {
    fn kind(self) -> shaderc::ShaderKind {
        match self {
            ShaderStage::Vertex => shaderc::ShaderKind::Vertex,
            ShaderStage::Fragment => shaderc::ShaderKind::Fragment,
            ShaderStage::Compute => shaderc::ShaderKind::Compute,
        }
    }
}

/// Looks up an embedded source by its path relative to `glsl/`.
fn embedded(path: &str) -> Option<&'static str> {
    SOURCES.iter().find(|s| s.path == path).map(|s| s.text)
}

/// Every embedded GLSL file: (path relative to `glsl/`, text).
#[cfg(test)]
pub(crate) fn embedded_sources() -> impl Iterator<Item = (&'static str, &'static str)> {
    SOURCES.iter().map(|s| (s.path, s.text))
}

/// The shared definitions ([`super::shared_defs::defines`]) followed by `defines`; a name given
/// in `defines` replaces the shared value.
fn with_shared_defines<'a>(defines: &[(&'a str, String)]) -> Vec<(&'a str, String)> {
    let mut all: Vec<(&'a str, String)> = super::shared_defs::defines()
        .into_iter()
        .filter(|(name, _)| !defines.iter().any(|(n, _)| n == name))
        .collect();
    all.extend(defines.iter().cloned());
    all
}

/// Joins an include name to the directory of the including file and removes `.` and `..`.
fn resolve_include(requested: &str, including: &str) -> String {
    let mut parts: Vec<&str> = including.split('/').collect();
    parts.pop();
    for part in requested.split('/') {
        match part {
            "." | "" => {}
            ".." => {
                parts.pop();
            }
            p => parts.push(p),
        }
    }
    parts.join("/")
}

/// Splits glslang's first error line (`file:line: error: ...`) into file and line.
fn locate_error(message: &str) -> (String, u32) {
    for line in message.lines() {
        let mut fields = line.splitn(3, ':');
        if let (Some(file), Some(num), Some(_)) = (fields.next(), fields.next(), fields.next()) {
            if let Ok(num) = num.trim().parse::<u32>() {
                return (file.trim().to_string(), num);
            }
        }
    }
    (String::new(), 0)
}

/// Compiles GLSL text named `file_name` with includes resolved by `lookup`.
pub(crate) fn compile_with(
    file_name: &str,
    text: &str,
    stage: ShaderStage,
    defines: &[(&str, String)],
    lookup: &dyn Fn(&str) -> Option<&'static str>,
) -> Result<Vec<u32>> {
    let compiler = shaderc::Compiler::new().map_err(|e| Error::ShaderCompile {
        file: file_name.into(),
        line: 0,
        message: format!("cannot start shaderc: {e}"),
    })?;
    let mut options = shaderc::CompileOptions::new().map_err(|e| Error::ShaderCompile {
        file: file_name.into(),
        line: 0,
        message: format!("cannot create shaderc options: {e}"),
    })?;
    options.set_target_env(
        shaderc::TargetEnv::Vulkan,
        shaderc::EnvVersion::Vulkan1_3 as u32,
    );
    options.set_optimization_level(shaderc::OptimizationLevel::Performance);
    options.set_warnings_as_errors();
    for (name, value) in defines {
        options.add_macro_definition(name, Some(value));
    }
    options.set_include_callback(|requested, _kind, including, _depth| {
        let path = resolve_include(requested, including);
        lookup(&path)
            .map(|content| shaderc::ResolvedInclude {
                resolved_name: path.clone(),
                content: content.to_string(),
            })
            .ok_or_else(|| format!("no GLSL file '{path}' (included from {including})"))
    });
    let artifact = compiler
        .compile_into_spirv(text, stage.kind(), file_name, "main", Some(&options))
        .map_err(|e| {
            let message = e.to_string();
            let (file, line) = locate_error(&message);
            Error::ShaderCompile {
                file: if file.is_empty() {
                    file_name.to_string()
                } else {
                    file
                },
                line,
                message,
            }
        })?;
    Ok(artifact.as_binary().to_vec())
}

/// Compiles the embedded GLSL file `path` (relative to `glsl/`) with the shared definitions
/// ([`super::shared_defs::defines`]) and the given macros (which win over a shared one of the same
/// name).
pub fn compile(path: &str, stage: ShaderStage, defines: &[(&str, String)]) -> Result<Vec<u32>> {
    let text = embedded(path).ok_or_else(|| Error::ShaderCompile {
        file: path.into(),
        line: 0,
        message: format!("no embedded GLSL file '{path}'"),
    })?;
    compile_with(path, text, stage, &with_shared_defines(defines), &embedded)
}

/// Compiles caller-supplied GLSL `text` as if it were the file `file_name` inside `glsl/`; its
/// includes resolve against the embedded tree. Used to check error reporting and by hosts that
/// extend the shaders. Only `defines` are defined: a source that includes the crate's files
/// passes [`super::shared_defs::defines`] too.
pub fn compile_source(
    file_name: &str,
    text: &str,
    stage: ShaderStage,
    defines: &[(&str, String)],
) -> Result<Vec<u32>> {
    compile_with(file_name, text, stage, defines, &embedded)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn include_paths_resolve_relative_to_the_including_file() {
        assert_eq!(
            resolve_include("include/a.glsl", "raycast.frag"),
            "include/a.glsl"
        );
        assert_eq!(
            resolve_include("params.glsl", "include/camera.glsl"),
            "include/params.glsl"
        );
        assert_eq!(
            resolve_include("../x.glsl", "include/camera.glsl"),
            "x.glsl"
        );
    }

    #[test]
    fn error_location_is_parsed_from_glslang_output() {
        let msg = "include/optics.glsl:12: error: 'foo' : undeclared identifier\n1 error";
        assert_eq!(locate_error(msg), ("include/optics.glsl".into(), 12));
        assert_eq!(locate_error("no location here"), (String::new(), 0));
    }
}
