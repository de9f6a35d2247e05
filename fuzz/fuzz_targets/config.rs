//! The configuration reader (`--config` YAML) on any text: an error or a configuration that
//! validates, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use system::SystemConfig;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(text) = std::str::from_utf8(bytes) {
        if let Ok(config) = SystemConfig::from_yaml(text) {
            let _ = config.validate();
        }
    }
});
