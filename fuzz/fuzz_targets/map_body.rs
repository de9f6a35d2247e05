//! The map reader past its checksum: the input is a map file's body, wrapped in a header with
//! its true length and CRC, so that the decoding and every check of the parts are fuzzed (a
//! random body almost never passes the CRC of `map_file`'s inputs).
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use system::map_file::{FORMAT_VERSION, MAGIC, MapFile};

fuzz_target!(|body: &[u8]| {
    let mut crc = flate2::Crc::new();
    crc.update(body);
    let mut file = Vec::with_capacity(28 + body.len());
    file.extend_from_slice(&MAGIC);
    file.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    file.extend_from_slice(&0u32.to_le_bytes());
    file.extend_from_slice(&(body.len() as u64).to_le_bytes());
    file.extend_from_slice(&crc.sum().to_le_bytes());
    file.extend_from_slice(body);
    if let Ok(map) = MapFile::from_bytes(&file, Path::new("fuzz.map")) {
        let _ = map.summary();
        let _ = map.to_bytes();
    }
});
