//! Compiles the gpu method's GLSL shaders (src/cull/gpu/shaders) to SPIR-V
//! with naga, so that no binary blob is committed and a shader error fails
//! the build with its line.

use std::path::Path;

use naga::ShaderStage;

const SHADERS: [(&str, ShaderStage); 6] = [
    ("erode.frag", ShaderStage::Fragment),
    ("scene.vert", ShaderStage::Vertex),
    ("box.vert", ShaderStage::Vertex),
    ("screen.vert", ShaderStage::Vertex),
    ("nothing.frag", ShaderStage::Fragment),
    ("mask.frag", ShaderStage::Fragment),
];

fn main() {
    let out = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    for (name, stage) in SHADERS {
        let path = Path::new("src/cull/gpu/shaders").join(name);
        println!("cargo:rerun-if-changed={}", path.display());
        let source =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let module = naga::front::glsl::Frontend::default()
            .parse(&naga::front::glsl::Options::from(stage), &source)
            .unwrap_or_else(|e| panic!("{}: {}", path.display(), e.emit_to_string(&source)));
        let info = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{}: {}", path.display(), e.emit_to_string(&source)));
        let words = naga::back::spv::write_vec(
            &module,
            &info,
            &naga::back::spv::Options::default(),
            Some(&naga::back::spv::PipelineOptions {
                shader_stage: stage,
                entry_point: "main".into(),
            }),
        )
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        std::fs::write(Path::new(&out).join(format!("{name}.spv")), bytes)
            .expect("OUT_DIR is writable");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
