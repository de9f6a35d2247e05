//! The camera-file reader (dwslam YAML and ORB-SLAM3 settings) on any text: an error or a
//! camera, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(text) = std::str::from_utf8(bytes) {
        if let Ok(file) = data::camera_file::parse_camera_file(text, Path::new("fuzz.yaml")) {
            let _ = format!("{file:?}");
        }
    }
});
