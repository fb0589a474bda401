//! Binds the system's libapriltag (Debian `libapriltag-dev`, the reference
//! AprilTag 3 implementation): bindgen reads the installed headers, so the
//! struct layouts are those of the library the binary links.

use std::env;
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let lib = pkg_config::Config::new()
        .atleast_version("3.1")
        .probe("apriltag")
        .unwrap_or_else(|e| {
            panic!("libapriltag not found ({e}); run `bash scripts/setup.sh` (Debian: libapriltag-dev)")
        });
    // The package installs its headers under <includedir>/apriltag and they
    // include each other as "common/...": search that folder itself.
    let mut dirs: Vec<PathBuf> = lib.include_paths.clone();
    dirs.push(PathBuf::from("/usr/include"));
    let root = dirs
        .iter()
        .map(|d| d.join("apriltag"))
        .find(|d| d.join("apriltag.h").exists())
        .or_else(|| dirs.iter().find(|d| d.join("apriltag.h").exists()).cloned())
        .expect("apriltag.h not found under the pkg-config include paths or /usr/include");
    let families = [
        "tag16h5",
        "tag25h9",
        "tag36h10",
        "tag36h11",
        "tagStandard41h12",
        "tagCircle21h7",
        "tagCustom48h12",
    ];
    let mut header = String::from("#include \"apriltag.h\"\n");
    for f in families {
        header.push_str(&format!("#include \"{f}.h\"\n"));
    }
    let mut builder = bindgen::Builder::default()
        .header_contents("gcp_tagger_apriltag.h", &header)
        .clang_arg(format!("-I{}", root.display()))
        .allowlist_function("apriltag_detector_(create|add_family_bits|destroy|detect)")
        .allowlist_function("apriltag_detections_destroy")
        .allowlist_function("apriltag_to_image")
        .allowlist_type("apriltag_detection(_t)?")
        .allowlist_type("pthread_mutex_t")
        .allowlist_type("zarray")
        .allowlist_type("image_u8")
        .opaque_type("pthread_mutex_t")
        .opaque_type("workerpool")
        .opaque_type("timeprofile")
        .derive_debug(false)
        .layout_tests(true)
        .generate_comments(false);
    for f in families {
        builder = builder.allowlist_function(format!("{f}_(create|destroy)"));
    }
    let bindings = builder
        .generate()
        .expect("bindgen could not read the libapriltag headers");
    let out = PathBuf::from(env::var("OUT_DIR").expect("OUT_DIR"));
    bindings
        .write_to_file(out.join("apriltag_sys.rs"))
        .expect("write apriltag bindings");
}
