//! Property tests (proptest) of the parsers the service owns, over random
//! and mutated input: none may panic, and what they accept keeps their
//! invariants. Case counts are in docs/operations.md.

use gcp_tagger::jobs::isolate::ChildLine;
use gcp_tagger::jobs::params::PARAM_KEYS;
use gcp_tagger::jobs::JobParams;
use gcp_tagger::storage::header::dimensions;
use gcp_tagger::storage::s3::S3Url;
use gcp_tagger::storage::spool::sanitize_name;
use gcp_tagger::survey::parse::parse_survey;
use proptest::prelude::*;

/// Every parameter key, plus two that are not parameters.
fn keys() -> Vec<&'static str> {
    let mut keys = PARAM_KEYS.to_vec();
    keys.extend(["name", "zzz"]);
    keys
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    #[test]
    fn query_parameters_never_panic(
        pairs in prop::collection::vec((prop::sample::select(keys()), ".{0,24}"), 0..8)
    ) {
        let refs: Vec<(&str, &str)> = pairs.iter().map(|(k, v)| (*k, v.as_str())).collect();
        if let Err(e) = JobParams::from_pairs(refs) {
            prop_assert!(!e.to_string().is_empty());
        }
    }

    #[test]
    fn s3_urls_never_name_a_host_or_climb(raw in "(s3://)?[a-zA-Z0-9./:@%_-]{0,40}") {
        if let Ok(url) = S3Url::parse(&raw) {
            let bucket = url.bucket();
            prop_assert!(!bucket.contains(['/', ':', '@']) && !bucket.contains(".."));
            prop_assert!(!raw.contains("/../") && !raw.ends_with("/.."));
            prop_assert_eq!(S3Url::parse(&url.to_string()).unwrap(), url.clone());
        }
    }

    #[test]
    fn names_never_become_paths(raw in ".{0,300}") {
        if let Some(name) = sanitize_name(&raw) {
            prop_assert!(!name.contains(['/', '\\']));
            prop_assert!(!name.chars().any(char::is_control));
            prop_assert!(name.len() <= 200 && name != ".." && name != ".");
        }
    }

    #[test]
    fn worker_lines_never_panic(
        line in r#"\{("kind":"(header|tile|done|error|warning)",?)?("[a-z_]{1,8}":(-?[0-9]{1,12}|"[a-z_ ]{0,12}"),?){0,4}\}?"#
    ) {
        // Whatever parses writes back to a line that parses the same.
        if let Some(parsed) = ChildLine::parse(&line) {
            let again = serde_json::to_string(&parsed).unwrap();
            prop_assert_eq!(ChildLine::parse(&again), Some(parsed));
        }
    }

    #[test]
    fn frame_headers_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..512), magic in 0usize..4) {
        let mut data = [
            &b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR"[..],
            &[0xFF, 0xD8, 0xFF][..],
            &b"II*\0"[..],
            &b"MM\0+"[..],
        ][magic].to_vec();
        data.extend_from_slice(&bytes);
        let f = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(f.path(), &data).unwrap();
        let _ = dimensions(f.path());
    }
}

proptest! {
    // Each case builds a PROJ object for the CRS: fewer cases.
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn survey_errors_name_a_line(
        lines in prop::collection::vec("[A-Za-z0-9 ,;.#\t-]{0,40}", 0..8)
    ) {
        let text = format!("EPSG:32611\n{}", lines.join("\n"));
        match parse_survey(&text, None) {
            Ok(s) => prop_assert!(!s.points.is_empty()),
            Err(e) => prop_assert!(
                e.0.contains("line") || e.0.contains("no points") || e.0.contains("column"),
                "{}", e.0
            ),
        }
    }
}
