//! Hostile and broken input: every bad file of a flight fails its own job
//! with a clear code while the good frames and the server go on; a
//! decompression bomb is refused from its header at submission.

use std::io::{BufRead, Read, Write};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

use gcp_synth::{write_image, GreyImage, SampleFormat};
use serde_json::Value;

use crate::server::{problem, Server};
use crate::service::{cli_output, flight, CRS};

/// A PNG header claiming 100000 x 100000 pixels, then nothing.
fn bomb() -> Vec<u8> {
    let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
    png.extend_from_slice(&100_000u32.to_be_bytes());
    png.extend_from_slice(&100_000u32.to_be_bytes());
    png.extend_from_slice(&[8, 2, 0, 0, 0, 0, 0, 0, 0]);
    png
}

#[test]
fn each_bad_file_fails_its_own_job_and_the_rest_goes_on() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let grey = GreyImage {
        width: 800,
        height: 600,
        data: (0..800 * 600).map(|i| (i % 251) as f32).collect(),
    };
    write_image(&d.join("real.jpg"), &grey, SampleFormat::Jpeg, None).unwrap();
    let jpeg = std::fs::read(d.join("real.jpg")).unwrap();
    std::fs::write(d.join("truncated.jpg"), &jpeg[..jpeg.len() / 3]).unwrap();
    std::fs::write(d.join("empty.jpg"), b"").unwrap();
    std::fs::write(d.join("notes.jpg"), b"field notes: GCP 4 moved").unwrap();
    std::fs::write(d.join("bomb.png"), bomb()).unwrap();
    std::fs::write(d.join("corrupt.tif"), b"II*\0\xff\xff\xff\x0fjunk").unwrap();
    // Two ImageWidth entries, 30000 then 100 (libtiff reads the first).
    let mut twice = b"II*\0\x08\0\0\0".to_vec();
    twice.extend_from_slice(&3u16.to_le_bytes());
    twice.extend_from_slice(&[0, 1, 4, 0, 1, 0, 0, 0, 0x30, 0x75, 0, 0]);
    twice.extend_from_slice(&[1, 1, 4, 0, 1, 0, 0, 0, 0x30, 0x75, 0, 0]);
    twice.extend_from_slice(&[0, 1, 3, 0, 1, 0, 0, 0, 100, 0, 0, 0]);
    twice.extend_from_slice(&[0; 4]);
    std::fs::write(d.join("two_widths.tif"), &twice).unwrap();
    std::fs::write(
        d.join("vrt.tif"),
        b"<VRTDataset rasterXSize=\"1\"></VRTDataset>",
    )
    .unwrap();
    // A PNG named .tif: recognised by content and processed.
    write_image(&d.join("png_named.tif"), &grey, SampleFormat::Png, None).unwrap();
    // Unusual band counts are read, not refused: 5 bands of 16 bits.
    let status = Command::new("gdal_create")
        .args([
            "-q", "-of", "GTiff", "-outsize", "400", "300", "-bands", "5", "-ot", "UInt16",
            "-burn", "900",
        ])
        .arg(d.join("five_band.tif"))
        .status()
        .unwrap();
    assert!(status.success());

    let server = Server::start(&d.join("data"), &[]);
    let names = [
        "truncated.jpg",
        "empty.jpg",
        "notes.jpg",
        "bomb.png",
        "corrupt.tif",
        "two_widths.tif",
        "vrt.tif",
        "png_named.tif",
        "five_band.tif",
    ];
    let mut upload: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();
    let bad: Vec<std::path::PathBuf> = names.iter().map(|n| d.join(n)).collect();
    upload.extend(bad.iter().map(|p| p.as_path()));
    let r = server.post_files(&format!("/v1/flights?crs={CRS}"), &upload);
    assert_eq!(r.status(), 201);
    let v: Value = r.json().unwrap();
    // The bomb is refused from its header at submission, before decoding.
    let at_submission = |name: &str| {
        v["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|j| j["image"] == name)
            .unwrap()
            .clone()
    };
    assert_eq!(at_submission("bomb.png")["state"], "failed");
    assert_eq!(
        at_submission("bomb.png")["error"]["code"],
        "frame_too_large"
    );
    let message = at_submission("bomb.png")["error"]["message"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(message.contains("100000 x 100000"), "{message}");
    let twice = at_submission("two_widths.tif");
    assert_eq!(
        (&twice["state"], &twice["error"]["code"]),
        (&"failed".into(), &"unreadable_frame".into()),
        "{twice}"
    );
    let message = twice["error"]["message"].as_str().unwrap();
    assert!(
        message.contains("two ImageWidth entries (30000 and 100)"),
        "{message}"
    );

    let id = v["flight"]["id"].as_str().unwrap();
    server.wait_flight(id);
    let jobs = server.get_json(&format!("/v1/flights/{id}/jobs"));
    let state = |name: &str| {
        let j = jobs["items"]
            .as_array()
            .unwrap()
            .iter()
            .find(|j| j["image"] == name)
            .unwrap();
        (
            j["state"].as_str().unwrap().to_string(),
            j["error"]["code"].as_str().unwrap_or("").to_string(),
        )
    };
    let expected = [
        // Cut off at a third: the rows before the cut are searched.
        ("truncated.jpg", "succeeded", ""),
        ("empty.jpg", "failed", "empty_frame"),
        ("notes.jpg", "failed", "not_an_image"),
        ("bomb.png", "failed", "frame_too_large"),
        ("corrupt.tif", "failed", "unreadable_frame"),
        ("two_widths.tif", "failed", "unreadable_frame"),
        ("vrt.tif", "failed", "not_an_image"),
        ("png_named.tif", "succeeded", ""),
        ("five_band.tif", "succeeded", ""),
    ];
    for (name, st, code) in expected {
        assert_eq!(state(name), (st.to_string(), code.to_string()), "{name}");
    }
    // Errors name frames as the client did, never by a server path.
    for j in jobs["items"].as_array().unwrap() {
        let message = j["error"]["message"].as_str().unwrap_or("");
        assert!(
            !message.contains("/frames/") && !message.contains(&d.to_string_lossy().to_string()),
            "{message}"
        );
    }
    let truncated = jobs["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["image"] == "truncated.jpg")
        .unwrap();
    let warnings = truncated["warnings"].to_string();
    assert!(
        warnings.contains("partial: rows ")
            && warnings.contains("truncated.jpg")
            && !warnings.contains("/frames/"),
        "{warnings}"
    );
    // Refused from its header alone: no worker ever opened the bomb.
    let bomb_job = jobs["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["image"] == "bomb.png")
        .unwrap();
    assert_eq!(bomb_job["attempts"], 0, "{bomb_job}");
    let twice = jobs["items"]
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["image"] == "two_widths.tif")
        .unwrap();
    assert_eq!(twice["attempts"], 0, "{twice}");
    // The good frames' results are whole and the server is up.
    let csv = server.get_text(&format!("/v1/flights/{id}/results.csv"));
    let good: Vec<&Path> = frames.iter().map(|p| p.as_path()).collect();
    // The other good files have no targets: the same bytes as the CLI's.
    assert_eq!(csv, cli_output(&good, "csv"));
    assert_eq!(server.get("/livez").status(), 200);

    // Alone, the bomb is a 413 at once.
    let r = server
        .client
        .post(server.url("/v1/jobs?name=bomb.png"))
        .body(bomb())
        .send()
        .unwrap();
    problem(r, 413, "frame_too_large");
    // A path-like name never reaches the filesystem or GDAL.
    let r = server
        .client
        .post(server.url("/v1/jobs?name=/vsicurl/http://example.com/x.tif"))
        .body(std::fs::read(&frames[0]).unwrap())
        .send()
        .unwrap();
    assert_eq!(r.status(), 201);
    assert_eq!(r.json::<Value>().unwrap()["image"], "x.tif");
}

#[test]
fn uploads_are_refused_with_507_when_the_disk_is_short() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    // A reserve larger than any disk here: every upload is refused, while
    // reads go on.
    let server = Server::start(&dir.path().join("d"), &["--min-free-disk-mb", "999999999"]);
    let r = server.post_files(&format!("/v1/flights?crs={CRS}"), &[frames[0].as_path()]);
    let v = problem(r, 507, "insufficient_storage");
    assert!(v["detail"].as_str().unwrap().contains("MiB free"), "{v}");
    assert_eq!(server.get("/v1/flights").status(), 200);
    assert_eq!(server.get("/livez").status(), 200);
}

#[test]
fn clients_over_their_rate_get_429_and_probes_are_never_limited() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("d"), &["--rate-limit-per-minute", "5"]);
    for _ in 0..5 {
        assert_eq!(server.get("/v1/flights").status(), 200);
    }
    let r = server.get("/v1/flights");
    let retry: u64 = r.headers()["retry-after"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!((1..=60).contains(&retry), "{retry}");
    problem(r, 429, "rate_limited");
    assert_eq!(server.get("/livez").status(), 200);
    // Without keys an Authorization header names no one: varying it
    // gives no new allowance.
    let varied = server
        .client
        .get(server.url("/v1/flights"))
        .header("Authorization", "Bearer another-client-key")
        .send()
        .unwrap();
    problem(varied, 429, "rate_limited");
}

#[test]
fn the_rate_limit_counts_verified_keys_and_addresses_not_header_spellings() {
    let dir = tempfile::tempdir().unwrap();
    let (k1, k2) = ("first-client-key-0123", "second-client-key-0123");
    let server = Server::start(
        &dir.path().join("d"),
        &[
            "--rate-limit-per-minute",
            "5",
            "--api-key",
            k1,
            "--api-key",
            k2,
        ],
    );
    let get = |auth: &str| {
        server
            .client
            .get(server.url("/v1/flights"))
            .header("Authorization", auth)
            .send()
            .unwrap()
    };
    // One key, ten spellings of its header: one allowance of five.
    let statuses: Vec<u16> = (1..=10)
        .map(|spaces| {
            get(&format!("Bearer{}{k1}", " ".repeat(spaces)))
                .status()
                .as_u16()
        })
        .collect();
    assert_eq!(statuses, [200, 200, 200, 200, 200, 429, 429, 429, 429, 429]);
    // Another verified key is another client.
    assert_eq!(get(&format!("Bearer {k2}")).status(), 200);
    // Guesses are 401 and spend the address's allowance: no endless
    // guessing from one address.
    let guesses: Vec<u16> = (0..6)
        .map(|i| {
            get(&format!("Bearer wrong-guess-{i:010}"))
                .status()
                .as_u16()
        })
        .collect();
    assert_eq!(guesses, [401, 401, 401, 401, 401, 429]);
    assert_eq!(server.get("/livez").status(), 200);
}

#[test]
fn finished_flights_are_removed_after_the_retention_time() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("d");
    // 0.0005 h = 1.8 s.
    let server = Server::start(&data, &["--retention-hours", "0.0005"]);
    let r = server.post_files(&format!("/v1/flights?crs={CRS}"), &[frames[0].as_path()]);
    let id = r.json::<Value>().unwrap()["flight"]["id"]
        .as_str()
        .unwrap()
        .to_string();
    server.wait_flight(&id);
    let deadline = Instant::now() + std::time::Duration::from_secs(30);
    while server.get(&format!("/v1/flights/{id}")).status() != 404 {
        assert!(
            Instant::now() < deadline,
            "the flight outlived its retention"
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    // The records go first, then the files.
    let left = || {
        ["frames", "results"]
            .iter()
            .map(|sub| std::fs::read_dir(data.join(sub)).unwrap().count())
            .sum::<usize>()
    };
    while left() > 0 {
        assert!(Instant::now() < deadline, "files outlived their flight");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

#[test]
fn a_flight_cannot_grow_past_its_frame_limit() {
    let frames = &flight().1;
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(&dir.path().join("d"), &["--max-frames-per-flight", "2"]);
    let two: Vec<&Path> = frames[..2].iter().map(|p| p.as_path()).collect();
    let id = server.post_flight(&format!("/v1/flights?crs={CRS}"), &two);
    let r = server.post_files(&format!("/v1/flights/{id}/frames"), &[frames[2].as_path()]);
    let v = problem(r, 413, "too_many_frames");
    assert!(v["detail"].as_str().unwrap().contains("3 frames"), "{v}");
}

#[test]
fn a_request_over_the_size_limit_gets_its_413_even_if_the_client_sends_it_all() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(
        &dir.path().join("d"),
        &["--max-request-mb", "1", "--max-frame-mb", "1"],
    );
    // Declared and written in full before the answer is read, as Python
    // requests does: 8 MiB, twice on one connection.
    let addr = server.base.trim_start_matches("http://").to_string();
    let mut conn = std::net::TcpStream::connect(&addr).unwrap();
    let body = vec![0xFFu8; 8 << 20];
    let mut reader = std::io::BufReader::new(conn.try_clone().unwrap());
    for _ in 0..2 {
        let head = format!(
            "POST /v1/jobs?name=big.jpg HTTP/1.1\r\nHost: {addr}\r\nContent-Length: {}\r\n\r\n",
            body.len()
        );
        conn.write_all(head.as_bytes()).unwrap();
        conn.write_all(&body)
            .expect("the whole body taken, not a broken pipe");
        let mut status = String::new();
        reader.read_line(&mut status).unwrap();
        assert!(status.starts_with("HTTP/1.1 413"), "{status:?}");
        let mut length = 0;
        loop {
            let mut line = String::new();
            reader.read_line(&mut line).unwrap();
            if line == "\r\n" {
                break;
            }
            if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                length = v.trim().parse().unwrap();
            }
        }
        let mut doc = vec![0u8; length];
        reader.read_exact(&mut doc).unwrap();
        let v: Value = serde_json::from_slice(&doc).unwrap();
        assert_eq!(v["code"], "request_too_large", "{v}");
        assert!(v["detail"].as_str().unwrap().contains("1 MiB"), "{v}");
    }
    assert_eq!(server.get("/livez").status(), 200);
}

/// Runs gdal_translate with `args` from `src` to `dst`.
fn translate(src: &Path, dst: &Path, args: &[&str]) {
    let status = Command::new("gdal_translate")
        .arg("-q")
        .args(args)
        .arg(src)
        .arg(dst)
        .status()
        .unwrap();
    assert!(status.success(), "gdal_translate {args:?}");
}

#[test]
fn the_memory_limit_holds_for_the_whole_process_tree_whatever_the_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 8000x6000 RGB in the layouts whose decoders hold the most: a
    // progressive JPEG (every coefficient of the image), a single
    // compressed TIFF strip (the whole image), against baseline and tiled.
    let (w, h) = (8000, 6000);
    // A ground's texture: waves and grain, each colour its own grain.
    let mut x = 0x2545_F491_4F6C_DD1Du64;
    let mut bands = Vec::new();
    // The waves are a product of a column's and a row's, tabled once.
    let cols: Vec<f32> = (0..w).map(|u| (u as f32 / 97.0).sin()).collect();
    let rows: Vec<f32> = (0..h).map(|v| (v as f32 / 61.0).cos()).collect();
    for (band, gain) in [("r", 1.0f32), ("g", 0.9), ("b", 0.8)] {
        let grey = GreyImage {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    gain * (128.0 + 60.0 * cols[i % w] * rows[i / w]) + (x >> 59) as f32
                })
                .collect(),
        };
        let path = d.join(format!("{band}.tif"));
        write_image(&path, &grey, SampleFormat::GtiffRgb8, None).unwrap();
        bands.push(path);
    }
    let src = d.join("rgb.vrt");
    let status = Command::new("gdalbuildvrt")
        .args(["-q", "-separate", "-b", "1"])
        .arg(&src)
        .args(&bands)
        .status()
        .unwrap();
    assert!(status.success());
    let rgb: [&str; 0] = [];
    let frames = [
        ("baseline.jpg", &["-of", "JPEG"][..]),
        (
            "progressive.jpg",
            &["-of", "JPEG", "-co", "PROGRESSIVE=ON"][..],
        ),
        (
            "one_strip.tif",
            &["-co", "COMPRESS=DEFLATE", "-co", "BLOCKYSIZE=6000"][..],
        ),
        (
            "one_strip_lzw.tif",
            &["-co", "COMPRESS=LZW", "-co", "BLOCKYSIZE=6000"][..],
        ),
        (
            "tiled.tif",
            &["-co", "COMPRESS=DEFLATE", "-co", "TILED=YES"][..],
        ),
    ];
    let paths: Vec<std::path::PathBuf> = frames
        .iter()
        .map(|(name, args)| {
            let path = d.join(name);
            translate(&src, &path, &[&rgb[..], args].concat());
            path
        })
        .collect();

    let server = Server::start(
        &d.join("data"),
        &["--max-ram-gb", "0.5", "--min-free-disk-mb", "1"],
    );
    let stop = std::sync::atomic::AtomicBool::new(false);
    let peak = std::thread::scope(|s| {
        let sampler = s.spawn(|| {
            let mut peak = 0;
            while !stop.load(std::sync::atomic::Ordering::SeqCst) {
                peak = peak.max(server.tree_rss_kib());
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            peak
        });
        let upload: Vec<&Path> = paths.iter().map(|p| p.as_path()).collect();
        let r = server.post_files(&format!("/v1/flights?crs={CRS}"), &upload);
        assert_eq!(r.status(), 201);
        let v: Value = r.json().unwrap();
        let done = server.wait_flight(v["flight"]["id"].as_str().unwrap());
        stop.store(true, std::sync::atomic::Ordering::SeqCst);
        assert_eq!(done["jobs"]["succeeded"], 5, "{done}");
        sampler.join().unwrap()
    });
    eprintln!("server and workers peaked at {} MiB", peak / 1024);
    assert!(
        peak <= 512 * 1024,
        "server and workers peaked at {} MiB over a 512 MiB limit",
        peak / 1024
    );
}
