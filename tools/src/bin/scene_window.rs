//! Development aid: writes the 640 px window of a clutter scene that a
//! test in `tests/it/printed.rs` names, to look at what it holds.
//!
//!     cargo run --release -p gcp-tools --bin scene_window -- SEED X0 Y0 out.png

use gcp_synth::{clutter_scene, render_window, write_image, SampleFormat};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let n = |i: usize| a[i].parse::<u64>().expect("SEED X0 Y0 out.png");
    let (seed, x0, y0) = (n(1), n(2) as usize, n(3) as usize);
    let (crop, _, _) =
        render_window(&clutter_scene(2400, 1800, seed), x0, y0, 640, 640).expect("render");
    write_image(std::path::Path::new(&a[4]), &crop, SampleFormat::Png, None).expect("write");
}
