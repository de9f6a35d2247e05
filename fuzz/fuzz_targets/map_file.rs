//! The map reader on any bytes: an error or a map, never a panic (`MapFile::from_bytes`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use system::map_file::MapFile;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(map) = MapFile::from_bytes(bytes, Path::new("fuzz.map")) {
        let _ = map.summary();
        let _ = map.to_bytes();
    }
});
