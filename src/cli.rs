//! The command line: `detect` runs the pipeline on files and folders,
//! `sample` renders a small set of frames with known targets to try it on.
//! Every flag can also come from a `GCP_TAGGER_*` environment variable.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;
use std::time::Duration;

use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use crate::pipeline::batch::{run_batch, BatchOptions, FrameInput, FrameOutcome};
use crate::pipeline::detect::{
    AprilTagFamily, ArucoDictionary, DetectorConfig, MarkerType, TargetDesign,
};
use crate::pipeline::frame::{default_tile_size, FrameOptions, FrameResult, DEFAULT_MAX_TARGET_PX};
use crate::pipeline::georef::{TargetCrs, Transformer};
use crate::pipeline::memory::default_max_ram_bytes;
use crate::pipeline::output::{render, Format};
use crate::survey::assign::parse_assignments;
use crate::survey::export;
use crate::survey::matching::{match_frames, point_reports, DEFAULT_PIXEL_TOLERANCE};
use crate::survey::parse::parse_survey;
use crate::survey::Survey;
use gcp_synth as synth;

/// Exit codes of `detect`, documented in docs/cli.md.
pub mod exit {
    /// Every frame was processed.
    pub const ALL_GOOD: u8 = 0;
    /// The results could not be written, or another internal failure.
    pub const INTERNAL: u8 = 1;
    /// The command line is wrong (unknown flag, CRS, marker type...).
    pub const USAGE: u8 = 2;
    /// Some frames failed; the results of the others were written.
    pub const SOME_FAILED: u8 = 3;
    /// No frame could be processed: nothing usable was written.
    pub const NOTHING_USABLE: u8 = 4;
}

/// File extensions taken from folders given as inputs.
const IMAGE_EXTENSIONS: &[&str] = &["jpg", "jpeg", "tif", "tiff", "png"];

#[derive(Parser, Debug)]
#[command(
    name = "gcp-tagger",
    version,
    about = "Finds ground control point targets in drone frames"
)]
pub struct Cli {
    /// Log filter (tracing EnvFilter syntax), e.g. "info" or "gcp_tagger=debug" (default: info for serve, warn otherwise).
    #[arg(long, global = true, env = "GCP_TAGGER_LOG")]
    pub log: Option<String>,
    /// Log as JSON lines instead of text.
    #[arg(long, global = true, env = "GCP_TAGGER_LOG_JSON")]
    pub log_json: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Detect targets in frames and write CSV or GeoJSON.
    Detect(DetectArgs),
    /// Render sample frames with known targets (and their truth as CSV).
    Sample(SampleArgs),
    /// Run the HTTP service.
    Serve(crate::config::ServeArgs),
    /// Print the service's OpenAPI document (as committed in openapi/openapi.json).
    Openapi,
    /// Check that a running service answers 200 on a route (container
    /// HEALTHCHECK; the runtime image has no curl). Exit 0 when it does.
    Probe(ProbeArgs),
    /// One job in a worker process (started by the service, not by hand).
    #[command(hide = true)]
    RunJob(crate::jobs::isolate::RunJobArgs),
}

#[derive(Args, Debug)]
pub struct ProbeArgs {
    /// host:port of the service.
    #[arg(long, default_value = "127.0.0.1:8080", env = "GCP_TAGGER_PROBE_ADDR")]
    pub addr: String,
    /// Route to ask for.
    #[arg(long, default_value = "/livez")]
    pub path: String,
    /// Give up after this many seconds.
    #[arg(long, default_value_t = 3)]
    pub timeout_secs: u64,
}

/// Runs `probe`: one HTTP/1.1 GET over a plain TCP connection.
pub fn probe(args: ProbeArgs) -> ExitCode {
    use std::io::Read;
    use std::net::{TcpStream, ToSocketAddrs};
    let timeout = std::time::Duration::from_secs(args.timeout_secs.max(1));
    let ask = || -> std::io::Result<String> {
        let addr = args
            .addr
            .to_socket_addrs()?
            .next()
            .ok_or_else(|| std::io::Error::other("address resolves to nothing"))?;
        let mut stream = TcpStream::connect_timeout(&addr, timeout)?;
        stream.set_read_timeout(Some(timeout))?;
        stream.set_write_timeout(Some(timeout))?;
        write!(
            stream,
            "GET {} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            args.path, args.addr
        )?;
        let mut head = [0u8; 64];
        let n = stream.read(&mut head)?;
        Ok(String::from_utf8_lossy(&head[..n]).into_owned())
    };
    match ask() {
        Ok(head) if head.starts_with("HTTP/1.1 200") => ExitCode::SUCCESS,
        Ok(head) => {
            let line = head.lines().next().unwrap_or("").to_string();
            eprintln!("error: {}{} answered {line:?}", args.addr, args.path);
            ExitCode::FAILURE
        }
        Err(e) => {
            eprintln!("error: {}{}: {e}", args.addr, args.path);
            ExitCode::FAILURE
        }
    }
}

#[derive(Args, Debug)]
pub struct DetectArgs {
    /// Frames (JPEG, TIFF/GeoTIFF, PNG) or folders of them.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Target types to look for, comma separated: apriltag, aruco, crosshair (white cross on black, 2x2 checker), circle (bullseyes of the common ring ratios, discs on a board).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "apriltag",
        env = "GCP_TAGGER_MARKER_TYPE"
    )]
    pub marker_type: Vec<MarkerType>,
    /// ArUco dictionary: 4X4_50 ... 7X7_1000, ARUCO_ORIGINAL.
    #[arg(long, default_value = "4X4_50", env = "GCP_TAGGER_DICTIONARY")]
    pub dictionary: ArucoDictionary,
    /// AprilTag family: 16h5, 25h9, 36h10, 36h11, Standard41h12, Circle21h7, Custom48h12.
    #[arg(long, default_value = "36h11", env = "GCP_TAGGER_APRILTAG_FAMILY")]
    pub apriltag_family: AprilTagFamily,
    /// CRS of the world coordinates: EPSG:n, WKT, PROJJSON or a PROJ string.
    #[arg(long, env = "GCP_TAGGER_CRS")]
    pub crs: String,
    /// Result file; its extension (.csv, .geojson) picks the format. "-" writes CSV to stdout.
    #[arg(long, short, env = "GCP_TAGGER_OUTPUT")]
    pub output: PathBuf,
    /// Output format, overriding the extension: csv or geojson.
    #[arg(long)]
    pub format: Option<Format>,
    /// Memory limit for the whole process, in GiB (default: half of the machine's or container's memory).
    #[arg(long, env = "GCP_TAGGER_MAX_RAM_GB")]
    pub max_ram_gb: Option<f64>,
    /// Largest corner move, in pixels, accepted from subpixel refinement; a larger move is rejected and flagged (default: 0.6 of a marker cell, at least 1.5 px).
    #[arg(long, env = "GCP_TAGGER_MAX_REFINE_SHIFT_PX")]
    pub max_refine_shift_px: Option<f64>,
    /// Survey file of ground control points (CSV with a header, or `name easting northing elevation [role]` lines); with --exports.
    #[arg(long, env = "GCP_TAGGER_SURVEY", requires = "exports")]
    pub survey: Option<PathBuf>,
    /// CRS of the survey's coordinates, when its first line does not name one.
    #[arg(long, env = "GCP_TAGGER_SURVEY_CRS", requires = "survey")]
    pub survey_crs: Option<String>,
    /// Observations named by hand, `name,image,px_x,px_y` per line: each names the detection nearest that pixel (within 10 px or half its size) as that survey point, for frames without georeference or camera pose.
    #[arg(long, env = "GCP_TAGGER_ASSIGN", requires = "survey")]
    pub assign: Option<PathBuf>,
    /// Survey matching: farthest a detection may lie from its point's expected position, in pixels (raw frames add the prediction's uncertainty).
    #[arg(long, env = "GCP_TAGGER_PIXEL_TOLERANCE", default_value_t = DEFAULT_PIXEL_TOLERANCE)]
    pub pixel_tolerance: f64,
    /// Folder for gcp_list.txt, pix4d_marks.csv, metashape_markers.xml, survey_points.geojson, observations.csv and report.json, and exports.zip holding all six.
    #[arg(long, env = "GCP_TAGGER_EXPORTS", requires = "survey")]
    pub exports: Option<PathBuf>,
    /// Folder for a picture of each target (`IMAGE.N.png`: a crop around it with its outline and centre drawn, N its place among the frame's rows of the results) and of each frame (`IMAGE.preview.jpg`, every target circled); created if missing.
    #[arg(long, env = "GCP_TAGGER_CHIPS")]
    pub chips: Option<PathBuf>,
    /// Frames processed at once (default: number of cores).
    #[arg(long, env = "GCP_TAGGER_THREADS")]
    pub threads: Option<usize>,
    /// Tile side in pixels (default: 1024 for coded targets only, 2048 when
    /// printed targets are searched).
    #[arg(long, env = "GCP_TAGGER_TILE_SIZE")]
    pub tile_size: Option<usize>,
    /// Largest target side in pixels; tiles overlap by more than this.
    #[arg(long, default_value_t = DEFAULT_MAX_TARGET_PX, env = "GCP_TAGGER_MAX_TARGET_PX")]
    pub max_target_px: usize,
    /// Smallest target side in pixels that is searched for (AprilTags under 30 px are searched at full resolution on two grey scales; from 30 px the search is decimated and once, 1.7-2.1x faster on the throughput bench's frames).
    #[arg(long, default_value_t = 16.0, env = "GCP_TAGGER_MIN_TARGET_PX")]
    pub min_target_px: f64,
    /// Physical size of printed targets in metres (square side or outer diameter); with the GSD it narrows the sizes searched to x/÷1.5 of the expected.
    #[arg(long, env = "GCP_TAGGER_TARGET_SIZE_M")]
    pub target_size_m: Option<f64>,
    /// Expected ground sample distance in cm per pixel (default: from each frame's georeference, when it has one).
    #[arg(long, env = "GCP_TAGGER_GSD_CM")]
    pub gsd_cm: Option<f64>,
    /// A printed target's design: a preset name (cross, checker, bullseye, bullseye-5, disc-black, disc-white) or a JSON file (kind, bar_width, ring_radii, board, free, size_m...); its targets are found from the description. See docs/target-designs.md.
    #[arg(long, env = "GCP_TAGGER_TARGET_DESIGN")]
    pub target_design: Option<String>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct SampleArgs {
    /// Folder to write the frames and truth.csv into.
    #[arg(long, default_value = "sample-frames")]
    pub out: PathBuf,
    /// Number of frames.
    #[arg(long, default_value_t = 4)]
    pub frames: usize,
    /// Frame width and height in pixels.
    #[arg(long, default_value_t = 4000)]
    pub width: usize,
    #[arg(long, default_value_t = 3000)]
    pub height: usize,
    /// Markers per frame.
    #[arg(long, default_value_t = 6)]
    pub markers: usize,
    /// File format: jpeg, png, gtiff or gtiff16 (16-bit R, G, B, NIR); the
    /// GeoTIFFs carry a UTM georeference.
    #[arg(long, default_value = "gtiff")]
    pub kind: synth::FileKind,
    /// Seed of the deterministic generator.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Hard cases: tags of 18-60 px, motion blur, hard shadows across tags.
    #[arg(long)]
    pub hard: bool,
}

/// Runs `detect`; returns the process exit code.
pub fn detect(args: DetectArgs) -> ExitCode {
    match detect_inner(args) {
        Ok(code) => ExitCode::from(code),
        Err((code, message)) => {
            eprintln!("error: {message}");
            ExitCode::from(code)
        }
    }
}

fn detect_inner(args: DetectArgs) -> Result<u8, (u8, String)> {
    let usage = |m: String| (exit::USAGE, m);
    // Everything the user typed is checked before any frame is read.
    let crs = TargetCrs::parse(&args.crs).map_err(|e| usage(e.to_string()))?;
    let format = match args.format {
        Some(f) => f,
        None if args.output == Path::new("-") => Format::Csv,
        None => Format::from_path(&args.output).ok_or_else(|| {
            usage(format!(
                "cannot tell the format of {:?}: use .csv or .geojson, or --format",
                args.output
            ))
        })?,
    };
    let max_ram_bytes = match args.max_ram_gb {
        Some(gb) if gb.is_finite() && gb > 0.0 => (gb * (1u64 << 30) as f64) as u64,
        Some(gb) => return Err(usage(format!("--max-ram-gb must be positive, got {gb}"))),
        None => default_max_ram_bytes(),
    };
    if !(args.pixel_tolerance.is_finite() && args.pixel_tolerance > 0.0) {
        return Err(usage(format!(
            "--pixel-tolerance must be a positive number of pixels, got {}",
            args.pixel_tolerance
        )));
    }
    let survey = match &args.survey {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| usage(format!("cannot read survey {}: {e}", path.display())))?;
            let mut survey = parse_survey(&text, args.survey_crs.as_deref())
                .map_err(|e| usage(format!("{}: {e}", path.display())))?;
            if let Some(assign) = &args.assign {
                let text = std::fs::read_to_string(assign).map_err(|e| {
                    usage(format!("cannot read assignments {}: {e}", assign.display()))
                })?;
                survey.assignments = parse_assignments(&text, &survey)
                    .map_err(|e| usage(format!("{}: {e}", assign.display())))?;
            }
            Some(survey)
        }
        None => None,
    };
    let designs = match &args.target_design {
        Some(arg) => {
            let design = TargetDesign::from_name_or_file(arg).map_err(|e| usage(e.to_string()))?;
            vec![design]
        }
        None => Vec::new(),
    };
    let inputs = collect_inputs(&args.inputs).map_err(usage)?;
    if inputs.is_empty() {
        eprintln!("error: no image files (.jpg, .tif, .png) found in the inputs");
        return Ok(exit::NOTHING_USABLE);
    }

    let mut modes = args.marker_type.clone();
    // A design names its mode: it is searched for even when --marker-type
    // does not list that mode.
    modes.extend(designs.iter().map(|d| d.marker_type()));
    modes.sort();
    modes.dedup();
    let frame = FrameOptions::new(
        DetectorConfig {
            modes,
            aruco_dictionary: args.dictionary,
            apriltag_family: args.apriltag_family,
            min_target_px: args.min_target_px,
            max_refine_shift_px: args.max_refine_shift_px,
            // The design's own size, unless the command line gives one.
            target_size_m: args
                .target_size_m
                .or(designs.first().and_then(|d| d.size_m)),
            gsd_cm: args.gsd_cm,
            designs,
        },
        args.tile_size
            .unwrap_or_else(|| default_tile_size(&args.marker_type)),
        args.max_target_px,
        crs.clone(),
    )
    .map_err(|e| usage(cli_setting_message(&e)))?;
    let options = BatchOptions {
        frame,
        threads: args
            .threads
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())),
        max_ram_bytes,
        chips: args.chips.clone(),
    };
    if let Some(dir) = &options.chips {
        std::fs::create_dir_all(dir)
            .map_err(|e| usage(format!("--chips {}: {e}", dir.display())))?;
    }

    let bar = progress_bar(inputs.len() as u64, args.quiet);
    let failures = Mutex::new(0usize);
    let on_frame = |input: &FrameInput, outcome: &FrameOutcome| {
        bar.suspend(|| match outcome {
            Ok(result) => {
                for w in &result.warnings {
                    eprintln!("warning: {}: {w}", input.name);
                }
            }
            Err(e) => {
                eprintln!("error: {}: {e}", input.name);
                *failures.lock().expect("failure count") += 1;
            }
        });
        bar.inc(1);
    };
    let outcomes = run_batch(&inputs, &options, &on_frame);
    bar.finish_and_clear();

    let mut frames: Vec<_> = outcomes.into_iter().filter_map(Result::ok).collect();
    frames.sort_by(|a, b| a.image.cmp(&b.image));
    let failed = failures.into_inner().expect("failure count");
    if frames.is_empty() {
        eprintln!(
            "error: none of the {} frames could be processed; nothing written",
            inputs.len()
        );
        return Ok(exit::NOTHING_USABLE);
    }
    let text = render(format, &frames, &crs);
    write_output(&args.output, text.as_bytes()).map_err(|e| (exit::INTERNAL, e))?;
    if let (Some(survey), Some(dir)) = (&survey, &args.exports) {
        write_exports(survey, &frames, args.pixel_tolerance, dir, args.quiet)?;
    }
    let targets: usize = frames.iter().map(|f| f.targets.len()).sum();
    if !args.quiet {
        eprintln!(
            "{} frames, {} targets, {} failed -> {}",
            frames.len() + failed,
            targets,
            failed,
            args.output.display()
        );
    }
    Ok(if failed > 0 {
        exit::SOME_FAILED
    } else {
        exit::ALL_GOOD
    })
}

/// Matches the frames' targets to the survey and writes every export file
/// into `dir`, printing the points' warnings.
fn write_exports(
    survey: &Survey,
    frames: &[FrameResult],
    tolerance: f64,
    dir: &Path,
    quiet: bool,
) -> Result<(), (u8, String)> {
    let mut transformer = Transformer::default();
    let matched = match_frames(frames, survey, tolerance, &mut transformer);
    let files = export::all(survey, &matched, tolerance, &mut transformer)
        .map_err(|e| (exit::INTERNAL, e.to_string()))?;
    std::fs::create_dir_all(dir).map_err(|e| {
        (
            exit::INTERNAL,
            format!("cannot create {}: {e}", dir.display()),
        )
    })?;
    for (name, text) in &files {
        write_output(&dir.join(name), text.as_bytes()).map_err(|e| (exit::INTERNAL, e))?;
    }
    write_output(&dir.join(export::BUNDLE), &export::bundle(&files))
        .map_err(|e| (exit::INTERNAL, e))?;
    // Frames that cannot be placed are said even when quiet: without
    // them the exports are silently empty.
    for w in &matched.warnings {
        eprintln!("warning: {w}");
    }
    if !quiet {
        for report in point_reports(survey, &matched) {
            for w in &report.warnings {
                eprintln!("warning: point {}: {w}", report.name);
            }
        }
        eprintln!(
            "{} observations of {} survey points, {} detections not used -> {}",
            matched.observations.len(),
            survey.points.len(),
            matched.unmatched.len(),
            dir.display()
        );
    }
    Ok(())
}

/// An invalid setting as the command line spells it (`--tile-size`).
fn cli_setting_message(e: &crate::pipeline::frame::InvalidSetting) -> String {
    let flag = match e.field {
        "marker_types" => "marker-type".to_string(),
        other => other.replace('_', "-"),
    };
    format!("--{flag} {}", e.message)
}

/// Files as given, and the image files inside folders (recursively, sorted),
/// each named by its path relative to the folder.
fn collect_inputs(paths: &[PathBuf]) -> Result<Vec<FrameInput>, String> {
    let mut out = Vec::new();
    for path in paths {
        if path.is_dir() {
            let mut found = Vec::new();
            walk(path, &mut found).map_err(|e| format!("cannot list {}: {e}", path.display()))?;
            found.sort();
            for file in found {
                let name = file
                    .strip_prefix(path)
                    .unwrap_or(&file)
                    .to_string_lossy()
                    .into_owned();
                out.push(FrameInput { path: file, name });
            }
        } else if path.exists() {
            let name = path
                .file_name()
                .map_or_else(|| path.to_string_lossy(), |n| n.to_string_lossy());
            out.push(FrameInput {
                path: path.clone(),
                name: name.into_owned(),
            });
        } else {
            return Err(format!("input {} does not exist", path.display()));
        }
    }
    Ok(out)
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.is_dir() {
            walk(&path, out)?;
        } else if path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
        {
            out.push(path);
        }
    }
    Ok(())
}

fn progress_bar(len: u64, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    // Hidden automatically when stderr is not a terminal.
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} frames  {per_sec}  ETA {eta}")
            .expect("valid template"),
    );
    bar.enable_steady_tick(Duration::from_millis(250));
    bar
}

/// Writes atomically: a temporary file beside the target, then a rename, so a
/// crash never leaves a half-written result that looks complete.
fn write_output(path: &Path, bytes: &[u8]) -> Result<(), String> {
    if path == Path::new("-") {
        return std::io::stdout()
            .write_all(bytes)
            .map_err(|e| format!("cannot write stdout: {e}"));
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let tmp = dir.join(format!(
        ".{}.tmp",
        path.file_name()
            .map_or("out".into(), |n| n.to_string_lossy())
    ));
    std::fs::write(&tmp, bytes)
        .and_then(|_| std::fs::rename(&tmp, path))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))
}

/// Runs `sample`.
pub fn sample(args: SampleArgs) -> ExitCode {
    let spec = synth::FlightSpec {
        frames: args.frames,
        width: args.width,
        height: args.height,
        markers: args.markers,
        kind: args.kind,
        seed: args.seed,
        hard: args.hard,
    };
    match synth::write_flight(&args.out, &spec) {
        Ok(n) => {
            eprintln!("wrote {n} frames and truth.csv to {}", args.out.display());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(exit::INTERNAL)
        }
    }
}
